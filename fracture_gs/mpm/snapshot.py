"""The arrays a simulation folder stores (:mod:`fracture_gs.folders.sim_writer`), taken from the
solver's particles and state."""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch

from fracture_gs.io.sim_layout import FRAME_ARRAYS
from fracture_gs.mpm.types import ParticleSet, SimState


def frame_arrays(state: SimState, fragment_id: torch.Tensor | None = None,
                 fields: Mapping[str, torch.Tensor] | None = None) -> dict[str, np.ndarray]:
    """The per-frame arrays from a solver state (float32, fractured bool), plus ``fragment_id``
    (int32 connected piece of every particle) and the material state ``fields`` (float32 (N,) each,
    e.g. ``damage``: :meth:`fracture_gs.materials.MaterialTable.frame_fields`) when given."""
    def array(t: torch.Tensor, dtype: Any) -> np.ndarray:
        return np.ascontiguousarray(t.detach().cpu().numpy().astype(dtype, copy=False))

    arrays = {name: array(getattr(state, name), np.bool_ if name == "fractured" else np.float32)
              for name in FRAME_ARRAYS}
    if fragment_id is not None:
        arrays["fragment_id"] = array(fragment_id, np.int32)
    for name, values in (fields or {}).items():
        arrays[name] = array(values, np.float32)
    return arrays


def particle_arrays(particles: ParticleSet) -> dict[str, np.ndarray]:
    """The constant per-particle arrays of ``particles.npz``."""
    def array(t: torch.Tensor) -> np.ndarray:
        return t.detach().cpu().numpy()

    return {"mass": array(particles.mass), "rest_volume": array(particles.rest_volume),
            "obj_id": array(particles.obj_id), "part_id": array(particles.part_id),
            "material_id": array(particles.material_id),
            "is_surface": array(particles.is_surface), "rest_x": array(particles.x),
            "gaussian_index": array(particles.gaussian_index)}
