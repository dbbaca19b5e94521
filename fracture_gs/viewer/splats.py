"""A frame's Gaussians (:class:`~fracture_gs.render.frame_gaussians.FrameGaussians`) in the form
viser's ``add_gaussian_splats`` draws: per object, centres (N,3), covariances (N,3,3), RGB (N,3)
and opacities (N,1), float32 numpy.

What changes on the way:

* colour: viser stores one RGB per Gaussian, no spherical harmonics. We use the DC band,
  ``SH_C0·sh₀ + 0.5`` clamped to [0, 1] — the SH colour averaged over all view directions
  (the higher bands integrate to zero over the sphere), so it does not depend on the view
  rotations of the frame;
* units: viser sends covariances as float16. Gaussians of millimetres in a metre-sized scene
  (σ² ≈ 1e-6) would fall into float16's subnormal range and lose their shape, so the splats are
  sent in *viewer units* — world coordinates times :attr:`SplatFrame.unit_scale`, chosen so that
  the scene's bounding box diagonal is 100 units (σ = 0.05 % of the scene stays a normal
  float16, a Gaussian as large as the scene stays below float16's maximum) — and the scene
  node is scaled back by ``1 / unit_scale``;
* FPGO's ``exclusive`` flag (only the nearest lens Gaussian blends at a pixel) has no
  counterpart in viser's renderer: lens Gaussians blend like all others there.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fracture_gs.render.frame_gaussians import FrameGaussians
from fracture_gs.render.sh import SH_C0

VIEWER_EXTENT = 100.0                      # the scene's bounding box diagonal in viewer units
HIGHLIGHT_RGB = (1.0, 0.05, 0.75)          # fractured particles' Gaussians, on request


@dataclass(frozen=True)
class ObjectSplats:
    """One object's splats of a frame, in viewer units (see the module docstring)."""

    centers: np.ndarray      # (N,3) float32
    covariances: np.ndarray  # (N,3,3) float32
    rgbs: np.ndarray         # (N,3) float32 in [0,1]
    opacities: np.ndarray    # (N,1) float32 in [0,1]
    fractured: np.ndarray    # (N,) bool: the Gaussian follows a fractured particle or is FPGO's

    def __len__(self) -> int:
        return int(self.centers.shape[0])

    def colours(self, highlight_fractured: bool) -> np.ndarray:
        """RGB to draw: the Gaussians' own, or :data:`HIGHLIGHT_RGB` where fractured."""
        if not highlight_fractured or not self.fractured.any():
            return self.rgbs
        rgbs = self.rgbs.copy()
        rgbs[self.fractured] = HIGHLIGHT_RGB
        return rgbs


@dataclass(frozen=True)
class SplatFrame:
    """All objects' splats of one frame plus what the GUI shows about it."""

    index: int
    objects: list[ObjectSplats]          # one per object, in scene order (possibly empty)
    unit_scale: float                    # viewer units per world unit
    gaussians: int                       # Gaussians drawn (all objects)
    fpgo_gaussians: int                  # of which FPGO made
    fractured_particles: int             # particles with the latched fracture flag
    prepare_ms: float = 0.0              # frame Gaussians + conversion, in the background


def unit_scale_for(lower: np.ndarray, upper: np.ndarray) -> float:
    """Viewer units per world unit for a scene whose bounds are ``lower``..``upper``."""
    diagonal = float(np.linalg.norm(np.asarray(upper, np.float64) - np.asarray(lower, np.float64)))
    return VIEWER_EXTENT / diagonal if diagonal > 0 else 1.0


def dc_colours(sh: torch.Tensor) -> torch.Tensor:
    """RGB (N,3) of the SH DC band (N,K,3): the colour averaged over view directions."""
    return (SH_C0 * sh[:, 0, :] + 0.5).clamp(0.0, 1.0)


def object_splats(gaussians: FrameGaussians, object_count: int, unit_scale: float,
                  fractured_particles: torch.Tensor | None = None) -> list[ObjectSplats]:
    """Split ``gaussians`` by object and convert them (see the module docstring).

    ``fractured_particles`` (bool per particle) marks the Gaussians that follow a fractured
    particle; FPGO's own Gaussians always count as fractured.
    """
    with torch.no_grad():
        fractured = gaussians.is_fpgo.clone()
        if fractured_particles is not None and len(gaussians):
            following = gaussians.particle
            valid = following >= 0
            fractured[valid] |= fractured_particles.to(following.device)[following[valid]]
        columns = {
            "centers": (gaussians.means.float() * unit_scale),
            "covariances": (gaussians.covariances.float() * (unit_scale * unit_scale)),
            "rgbs": dc_colours(gaussians.sh.float()),
            "opacities": gaussians.opacities.float().clamp(0.0, 1.0)[:, None],
            "fractured": fractured,
        }
        columns = {name: value.detach().cpu().numpy() for name, value in columns.items()}
        object_id = gaussians.object_id.detach().cpu().numpy()
    order = np.argsort(object_id, kind="stable")
    bounds = np.searchsorted(object_id[order], np.arange(object_count + 1))
    result = []
    for index in range(object_count):
        rows = order[bounds[index]:bounds[index + 1]]
        result.append(ObjectSplats(**{name: np.ascontiguousarray(value[rows])
                                      for name, value in columns.items()}))
    return result


__all__ = ["HIGHLIGHT_RGB", "ObjectSplats", "SplatFrame", "VIEWER_EXTENT", "dc_colours",
           "object_splats", "unit_scale_for"]
