"""Rotating spherical-harmonic colour coefficients (degree 0-3, the 3DGS basis).

The rasterizer can evaluate SH at a rotated view direction (``view_rotations``: colour of
Gaussian g at direction d is SH_g(R_gᵀ d)). Files in the 3DGS layout have no such rotation, so
for export the coefficients themselves are rotated: c' with Σ c'_k Y_k(d) = Σ c_k Y_k(Rᵀ d) for
every direction d. Rotations keep each SH band, so sampling the rotated function at a fixed
set of directions and solving the least-squares system with the basis there is exact (up to
rounding) once the set has at least (degree + 1)² well-spread directions.
"""
from __future__ import annotations

import math

import torch

from fracture_gs.render.sh import sh_basis

_SAMPLES = 48  # Fibonacci-sphere directions, well above the 16 coefficients of degree 3
_CHUNK = 16384


def _fibonacci_directions(count: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    index = torch.arange(count, dtype=dtype, device=device) + 0.5
    z = 1.0 - 2.0 * index / count
    radius = torch.sqrt(torch.clamp(1.0 - z * z, min=0.0))
    angle = index * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([radius * torch.cos(angle), radius * torch.sin(angle), z], dim=1)


def rotate_sh(sh: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """Coefficients (N, K, 3) that render at direction d like ``sh`` at Rᵀ d (R = rotations,
    (N, 3, 3)). Computed in float64, returned in ``sh``'s dtype."""
    count, coefficients = sh.shape[0], sh.shape[1]
    degree = math.isqrt(coefficients) - 1
    if (degree + 1) ** 2 != coefficients or degree > 3:
        raise ValueError(f"rotate_sh: K = {coefficients} is not (d+1)² for d in 0..3")
    if degree == 0 or count == 0:
        return sh.clone()
    directions = _fibonacci_directions(_SAMPLES, torch.float64, sh.device)
    solve = torch.linalg.pinv(sh_basis(directions, degree))  # (K, S)
    out = torch.empty_like(sh)
    for start in range(0, count, _CHUNK):
        stop = min(start + _CHUNK, count)
        rotated = directions @ rotations[start:stop].double()         # rows: (Rᵀ s)ᵀ = sᵀ R
        values = torch.einsum("nsk,nkc->nsc", sh_basis(rotated, degree), sh[start:stop].double())
        out[start:stop] = torch.einsum("ks,nsc->nkc", solve, values).to(sh.dtype)
    return out
