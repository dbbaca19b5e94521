"""The cameras a ``--views`` spec names for a simulation (render.py, evaluate.py, view.py and
the benchmarks frame a run the same way)."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fracture_gs.folders.sim_reader import Simulation
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.render.views import (View, ViewSpecError, bounds_sphere, cameras_from_json,
                                      dataset_views, orbit_views)

DEFAULT_ORBIT_SIZE = (800, 800)


def resolve_views(spec: str, sim: Simulation, frames: Sequence[int],
                  size: tuple[int, int] | None) -> list[View]:
    """The cameras named by ``--views`` for this simulation (ViewSpecError naming the spec)."""
    if spec.startswith("orbit:"):
        count_text = spec[len("orbit:"):]
        if not count_text.isdigit() or int(count_text) < 1:
            raise ViewSpecError(f"--views {spec}: orbit:N needs a whole number N >= 1")
        points = [sim.particles.rest_x, sim.load_frame(frames[-1]).x.numpy()]
        centre, radius = bounds_sphere(np.concatenate(points))
        gravity = np.asarray(sim.scene.gravity, dtype=np.float64)
        up = -gravity / np.linalg.norm(gravity) if np.linalg.norm(gravity) > 0 else (0, 0, 1)
        width, height = size if size is not None else DEFAULT_ORBIT_SIZE
        return orbit_views(int(count_text), centre, radius, width, height, up=up)
    if spec in ("train", "test"):
        trained = [obj for obj in sim.scene.objects if obj.model is not None and obj.model.is_dir()]
        if not trained:
            raise ViewSpecError(f"--views {spec}: no object of {SimLayout(sim.root).scene_path} "
                                "has a trained model folder")
        from fracture_gs.mpm.scene import rotation_matrix_xyz

        obj = trained[0]
        return dataset_views(obj.model, spec, rotation_matrix_xyz(obj.transform.rotate_deg),
                             obj.transform.scale, obj.transform.translate, size)
    path = Path(spec)
    if path.suffix.lower() == ".json" or path.exists():
        return cameras_from_json(path, size)
    raise ViewSpecError(f"--views {spec}: unknown view spec (orbit:N, train, test or a "
                        "cameras.json)")
