"""Real spherical harmonics (degree 0-3, 3DGS constants) evaluated in PyTorch.

The same basis as ``csrc/common/sh.h``: colour = max(0, sum_k Y_k(dir) sh_k + 0.5).
"""
from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(directions: torch.Tensor, degree: int) -> torch.Tensor:
    """Basis values (N, (degree+1)²) at unit directions (N, 3)."""
    x, y, z = directions.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy),
                  SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        basis += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z,
                  SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
                  SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
                  SH_C3[6] * x * (xx - 3 * yy)]
    return torch.stack(basis, -1)


def sh_to_color(sh: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
    """RGB (N, 3) of SH coefficients (N, K, 3) seen along unit directions (N, 3)."""
    degree = {1: 0, 4: 1, 9: 2, 16: 3}[sh.shape[1]]
    basis = sh_basis(directions, degree)
    return torch.clamp(torch.einsum("nk,nkc->nc", basis, sh) + 0.5, min=0.0)


def view_directions(means: torch.Tensor, camera_center: torch.Tensor,
                    view_rotations: torch.Tensor | None = None) -> torch.Tensor:
    """Unit directions camera→Gaussian (N, 3); with per-Gaussian R (N,3,3) they become Rᵀ·dir."""
    offset = means - camera_center
    unit = offset / offset.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if view_rotations is not None:
        unit = torch.einsum("nmk,nm->nk", view_rotations, unit)
    return unit
