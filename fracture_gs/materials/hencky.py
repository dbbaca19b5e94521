"""St. Venant-Kirchhoff elasticity on the Hencky strain, shared by every material (torch twins).

F_E = U diag(σ) Vᵀ, ε = ln max(|σ|, 1e-4), τ = U diag(2μ ε + λ (Σε) 1) Uᵀ,
ψ = μ‖ε‖² + (λ/2)(Σε)² = μ‖dev ε‖² + (K/2)(Σε)², K = λ + 2μ/3.

Inverted elements (det F < 0): the signed SVD puts the sign on σ₃, and the Hencky strain uses
|σ|, i.e. an inverted F is treated as its mirror image. Then τ = (∂ψ/∂F) Fᵀ still holds.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import torch

from fracture_gs import bounds, keys

MIN_SINGULAR_VALUE = 1e-4   # σ clamp of the Hencky strain
ELASTIC_KEYS = ("E", "nu", "density")


def lame_parameters(E: float, nu: float) -> tuple[float, float]:
    """Lamé (μ, λ) from Young's modulus E and Poisson ratio ν."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def require(owner: str, name: str, value: float, ok: bool, rule: str) -> None:
    """ValueError ``owner.name: value is not rule`` unless ``value`` is a finite real and ``ok``."""
    if not (isinstance(value, numbers.Real) and math.isfinite(value) and ok):
        raise ValueError(f"{owner}.{name}: {value!r} is not {rule}")


# ----------------------------------------------------------------------------- torch math

def proper_svd(F: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Batched F = U diag(σ) Vᵀ with det U = det V = +1 (σ₃ < 0 iff det F < 0).

    Returns U (...,3,3), σ (...,3) in decreasing order of magnitude, V (...,3,3). Like the
    compiled kernels, a matrix with a NaN or Inf entry gives NaN factors (LAPACK would refuse).
    """
    finite = torch.isfinite(F).flatten(-2).all(-1)
    eye = torch.eye(3, dtype=F.dtype, device=F.device)
    U, sigma, Vh = torch.linalg.svd(torch.where(finite[..., None, None], F, eye))
    nan = torch.tensor(float("nan"), dtype=F.dtype, device=F.device)
    U = torch.where(finite[..., None, None], U, nan)
    sigma = torch.where(finite[..., None], sigma, nan)
    Vh = torch.where(finite[..., None, None], Vh, nan)
    V = Vh.mT
    flip_u = torch.linalg.det(U) < 0
    flip_v = torch.linalg.det(V) < 0
    last_sign_u = torch.where(flip_u, -1.0, 1.0).to(F.dtype)
    last_sign_v = torch.where(flip_v, -1.0, 1.0).to(F.dtype)
    ones = torch.ones_like(last_sign_u)
    U = U * torch.stack([ones, ones, last_sign_u], dim=-1).unsqueeze(-2)
    V = V * torch.stack([ones, ones, last_sign_v], dim=-1).unsqueeze(-2)
    sigma = sigma * torch.stack([ones, ones, last_sign_u * last_sign_v], dim=-1)
    return U, sigma, V


def hencky_strain(sigma: torch.Tensor) -> torch.Tensor:
    """Principal Hencky strain ε = ln max(|σ|, 1e-4)."""
    return torch.log(sigma.abs().clamp_min(MIN_SINGULAR_VALUE))


def compose(U: torch.Tensor, diagonal: torch.Tensor, V: torch.Tensor) -> torch.Tensor:
    """U diag(d) Vᵀ, batched."""
    return (U * diagonal.unsqueeze(-2)) @ V.mT


def kirchhoff_from_strain(U: torch.Tensor, strain: torch.Tensor, mu: torch.Tensor | float,
                          lam: torch.Tensor | float) -> torch.Tensor:
    """τ = U diag(2μ ε + λ tr(ε) 1) Uᵀ; μ, λ scalars or per-row tensors (N,)."""
    mu = torch.as_tensor(mu, dtype=strain.dtype, device=strain.device)
    lam = torch.as_tensor(lam, dtype=strain.dtype, device=strain.device)
    principal = 2.0 * mu[..., None] * strain + (lam * strain.sum(-1))[..., None]
    return compose(U, principal, U)


def hencky_energy(strain: torch.Tensor, mu: torch.Tensor | float,
                  lam: torch.Tensor | float) -> torch.Tensor:
    """ψ = μ‖ε‖² + (λ/2)(Σε)² per unit rest volume."""
    return mu * (strain * strain).sum(-1) + 0.5 * lam * strain.sum(-1) ** 2


def kirchhoff_stress_reference(F: torch.Tensor, mu: torch.Tensor | float,
                               lam: torch.Tensor | float) -> torch.Tensor:
    """Kirchhoff stress τ(F) of the Hencky StVK model (batched (N,3,3))."""
    U, sigma, _ = proper_svd(F)
    return kirchhoff_from_strain(U, hencky_strain(sigma), mu, lam)


def energy_density_reference(F: torch.Tensor, mu: torch.Tensor | float,
                             lam: torch.Tensor | float) -> torch.Tensor:
    """Elastic energy density ψ(F) per unit rest volume (batched (N,3,3) -> (N,))."""
    sigma = torch.linalg.svdvals(F)  # |σ|: the sign of σ₃ does not enter ε
    return hencky_energy(hencky_strain(sigma), mu, lam)


def as_float_tensor(like: torch.Tensor, value: float) -> torch.Tensor:
    """A scalar tensor with ``like``'s dtype and device."""
    return torch.tensor(value, dtype=like.dtype, device=like.device)


# ----------------------------------------------------------------------------- the shared part

@dataclass(frozen=True)
class HenckyElasticity:
    """Shared elastic part of every material: Lamé parameters, wave speed, stress and energy."""

    E: float
    nu: float
    density: float

    def _validate_elasticity(self) -> None:
        owner = type(self).__name__
        require(owner, "E", self.E, self.E > 0, "> 0")
        require(owner, "nu", self.nu, 0.0 <= self.nu, ">= 0")
        require(owner, "nu", self.nu, self.nu < 0.5, "< 0.5")
        require(owner, "density", self.density, self.density > 0, "> 0")

    @staticmethod
    def elasticity_from_yaml(data: Any, path: str) -> dict[str, float]:
        """E, nu and density of a material mapping (key-path errors)."""
        return {"E": keys.number(data, "E", path, gt=0.0, within=bounds.YOUNGS_MODULUS),
                "nu": keys.number(data, "nu", path, ge=0.0, lt=0.5),
                "density": keys.number(data, "density", path, gt=0.0, within=bounds.DENSITY)}

    @property
    def mu(self) -> float:
        return lame_parameters(self.E, self.nu)[0]

    @property
    def lam(self) -> float:
        return lame_parameters(self.E, self.nu)[1]

    @property
    def bulk(self) -> float:
        """Bulk modulus K = λ + 2μ/3."""
        return self.lam + 2.0 * self.mu / 3.0

    @property
    def wave_speed(self) -> float:
        """P-wave speed sqrt((λ + 2μ)/ρ), used by the CFL time step."""
        return math.sqrt((self.lam + 2.0 * self.mu) / self.density)

    def elastic_row(self, model_code: int) -> list[float]:
        """The first four columns of a table row: model, μ, λ, K."""
        return [float(model_code), self.mu, self.lam, self.bulk]

    def kirchhoff_stress(self, F_E: torch.Tensor) -> torch.Tensor:
        """Kirchhoff stress τ of the undamaged material at F_E (N,3,3)."""
        return kirchhoff_stress_reference(F_E, self.mu, self.lam)

    def energy_density(self, F_E: torch.Tensor) -> torch.Tensor:
        """Elastic energy per unit rest volume ψ(F_E) of the undamaged material, (N,)."""
        return energy_density_reference(F_E, self.mu, self.lam)
