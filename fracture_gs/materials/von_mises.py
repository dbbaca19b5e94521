"""``model: von_mises``: J2 (von Mises) plasticity with linear isotropic hardening - ductile metals.

Hencky elasticity; where the Kirchhoff deviator's norm exceeds √(2/3) (σ_y + H ε_p) the deviatoric
strain shrinks radially back onto the yield surface (volume kept) and the equivalent plastic strain
ε_p (the state) grows; a particle counts as fractured once ε_p reaches ``failure_strain``. The update
dissipates the elastic energy the projection removes. Formulas: docs/formulas.md, "Von Mises
plasticity"; the kernels' law: ``csrc/common/materials/von_mises.h``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from fracture_gs import bounds, keys
from fracture_gs.materials.hencky import (ELASTIC_KEYS, compose, energy_density_reference, hencky_strain,
                                          kirchhoff_from_strain, proper_svd, require)
from fracture_gs.materials.model import MaterialModel, parameter

_KEYS = ("yield_stress", "hardening", "failure_strain")
HARDENING_RANGE = (0.0, 1.0e13)     # Pa (>= 0; the yield stress's slope over the plastic strain)
FAILURE_STRAIN_RANGE = (0.0, 1.0e3)  # (> 0)
SQRT_2_3 = math.sqrt(2.0 / 3.0)


def von_mises_update_reference(F_trial: torch.Tensor, plastic: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor,
                               yield_stress: torch.Tensor, hardening: torch.Tensor
                               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The J2 return map on F: (F_trial, ε_p, parameters per row) -> (F_E, ε_p', τ(F_E), dissipated
    energy per unit rest volume μ (|dev ε|² − |dev ε'|²))."""
    U, sigma, V = proper_svd(F_trial)
    strain = hencky_strain(sigma)
    e = strain.sum(-1, keepdim=True)
    deviatoric = strain - e / 3.0
    norm = deviatoric.norm(dim=-1)
    trial = 2.0 * mu * norm
    f = trial - SQRT_2_3 * (yield_stress + hardening * plastic)
    yields = f > 0
    dgamma = torch.where(yields, f / (2.0 * mu + (2.0 / 3.0) * hardening), torch.zeros_like(f))
    scale = torch.where(yields, 1.0 - 2.0 * mu * dgamma / trial.clamp_min(torch.finfo(trial.dtype).tiny),
                        torch.ones_like(f))
    strain_new = e / 3.0 + scale[..., None] * deviatoric
    F_E = torch.where(yields[..., None, None], compose(U, torch.exp(strain_new), V), F_trial)
    tau = kirchhoff_from_strain(U, strain_new, mu, lam)
    dissipated = mu * (1.0 - scale * scale) * norm * norm
    return F_E, plastic + SQRT_2_3 * dgamma, tau, dissipated


@dataclass(frozen=True)
class VonMisesMaterial(MaterialModel):
    """J2 plasticity with linear isotropic hardening: ``yield_stress`` σ_y (Pa), ``hardening`` H (Pa,
    the yield stress grows by H per unit equivalent plastic strain), ``failure_strain`` (ε_p from which a
    particle counts as fractured; inf: never)."""

    yield_stress: float
    hardening: float = 0.0
    failure_strain: float = math.inf

    name: ClassVar[str] = "von_mises"
    code: ClassVar[int] = 3
    yaml_keys: ClassVar[tuple[str, ...]] = ("part", "model") + ELASTIC_KEYS + _KEYS
    parameter_columns: ClassVar[tuple[str, ...]] = ("yield_stress", "hardening", "")
    state_fields: ClassVar[tuple[str, ...]] = ("plastic_strain",)
    dissipates: ClassVar[bool] = True

    def __post_init__(self) -> None:
        owner = type(self).__name__
        self._validate_elasticity()
        require(owner, "yield_stress", self.yield_stress, self.yield_stress > 0, "> 0")
        require(owner, "hardening", self.hardening, self.hardening >= 0, ">= 0")
        if not (isinstance(self.failure_strain, (int, float)) and self.failure_strain > 0):   # inf: never
            raise ValueError(f"{owner}.failure_strain: {self.failure_strain!r} is not > 0")

    @classmethod
    def from_yaml(cls, data: Any, path: str) -> "VonMisesMaterial":
        """The material of a scene's material mapping (``part`` and ``model`` are the scene's)."""
        keys.check_keys(data, path, cls.yaml_keys, required=ELASTIC_KEYS + ("yield_stress",))
        return cls(**cls.elasticity_from_yaml(data, path),
                   yield_stress=keys.number(data, "yield_stress", path, gt=0.0, within=bounds.STRESS),
                   hardening=keys.number(data, "hardening", path, 0.0, ge=0.0, within=HARDENING_RANGE),
                   failure_strain=keys.number(data, "failure_strain", path, math.inf, gt=0.0,
                                              within=FAILURE_STRAIN_RANGE))

    def to_yaml(self) -> dict[str, Any]:
        """The resolved keys (``model`` included; ``failure_strain`` only where it is finite)."""
        resolved = {"model": self.name, "E": self.E, "nu": self.nu, "density": self.density,
                    "yield_stress": self.yield_stress, "hardening": self.hardening}
        if math.isfinite(self.failure_strain):
            resolved["failure_strain"] = self.failure_strain
        return resolved

    def parameters(self, cell_size: float | None) -> tuple[float, ...]:
        """σ_y, H (``parameter_columns``)."""
        return (self.yield_stress, self.hardening, 0.0)

    @property
    def fracture_threshold(self) -> float:
        """ε_p from which a particle counts as fractured (the flag latches)."""
        return self.failure_strain

    @classmethod
    def update_rows(cls, F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: (F_E, state with ε_p', τ,
        dissipated)."""
        F_E, plastic, tau, dissipated = von_mises_update_reference(
            F_trial, state[:, 0], rows[:, 1], rows[:, 2], parameter(rows, cls, "yield_stress"),
            parameter(rows, cls, "hardening"))
        state_new = state.clone()
        state_new[:, 0] = plastic
        return F_E, state_new, tau, dissipated

    @staticmethod
    def energy_rows(F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density ψ for particles of this model."""
        return energy_density_reference(F_E, rows[:, 1], rows[:, 2])
