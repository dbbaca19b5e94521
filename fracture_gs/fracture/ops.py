"""The per-frame Gaussian ops: the compiled kernel when available, otherwise its torch twin.

``backend`` is ``auto`` | ``cpp`` | ``reference`` (see :func:`fracture_gs._backend.use_compiled`).
Float inputs are converted to contiguous float32 (the kernels' type).
"""
from __future__ import annotations

from typing import NamedTuple

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.fracture import reference


class DeformedGaussians(NamedTuple):
    """Gaussians at one frame: means (M,3), covariances (M,3,3), view_rotations (M,3,3)."""

    means: torch.Tensor
    covariances: torch.Tensor
    view_rotations: torch.Tensor


class LensEllipsoids(NamedTuple):
    """FPGO ellipsoids of sphere pairs: centre (P,3), scales (P,3) along the columns of
    rotation (P,3,3) = [u v w], covariance (P,3,3), valid (P,) (False: no overlap)."""

    centre: torch.Tensor
    scales: torch.Tensor
    rotation: torch.Tensor
    covariance: torch.Tensor
    valid: torch.Tensor


def _f32(tensor: torch.Tensor) -> torch.Tensor:
    return tensor.to(torch.float32).contiguous()


def deform_gaussians(x: torch.Tensor, F_E: torch.Tensor, driver: torch.Tensor,
                     rest_offset: torch.Tensor, rest_covariance: torch.Tensor,
                     object_rotation: torch.Tensor, gaussian_object: torch.Tensor,
                     backend: str = "auto") -> DeformedGaussians:
    """Gaussians that follow their particles (docs/formulas.md §12).

    Gaussian g is driven by particle ``driver[g]`` with elastic deformation gradient F:
    mean ``x_p + F · rest_offset[g]``, covariance ``F Σ0 Fᵀ`` (Σ0 = ``rest_covariance[g]``,
    world frame at rest) and view rotation ``R_F · object_rotation[gaussian_object[g]]``, R_F
    the polar rotation of F (det +1), so that SH stored in the model frame are looked up at
    ``(R_F R_obj)ᵀ · direction``.
    """
    args = (_f32(x), _f32(F_E), driver.to(torch.int64).contiguous(), _f32(rest_offset),
            _f32(rest_covariance), _f32(object_rotation), gaussian_object.to(torch.int32).contiguous())
    if use_compiled(x.device, backend):
        return DeformedGaussians(*compiled_module().fracture_deform_gaussians(*args))
    return DeformedGaussians(*reference.deform_gaussians(*args))


def lens_ellipsoids(centre_i: torch.Tensor, radius_i: torch.Tensor, centre_j: torch.Tensor,
                    radius_j: torch.Tensor, k_sigma: float = 2.0,
                    backend: str = "auto") -> LensEllipsoids:
    """FPGO's lenses (docs/formulas.md §13 step 4, paper App. A.4) for P sphere pairs (C_i, r_i), (C_j, r_j).

    Intersecting spheres (|r_i − r_j| < d < r_i + r_j) give the ellipsoid centred at
    C_i + r_i/(r_i + r_j)(C_j − C_i) with semi-axis (r_i + r_j − d)/2 along u = (C_j − C_i)/d
    and the radius of the intersection circle across it; a sphere inside the other gives the
    smaller sphere; tangent or disjoint spheres give ``valid = False``. Gaussian scales are
    the semi-axes / ``k_sigma``.
    """
    if k_sigma <= 0:
        raise ValueError(f"k_sigma must be > 0, got {k_sigma}")
    args = (_f32(centre_i), _f32(radius_i), _f32(centre_j), _f32(radius_j))
    if use_compiled(centre_i.device, backend):
        return LensEllipsoids(*compiled_module().fracture_lens_ellipsoids(*args, float(k_sigma)))
    return LensEllipsoids(*reference.lens_ellipsoids(*args, float(k_sigma)))
