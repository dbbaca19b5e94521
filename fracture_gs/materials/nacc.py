"""``model: nacc``: non-associated Cam-clay plasticity (Wolper et al. 2019) in Hencky strain.

NACC hardens in compression and loses cohesion in tension: dough, clay, sand and crumbling soil.
The state is the hardening variable α (α0 = ln J_p0, more negative = stronger); a particle counts
as fractured once α >= ``alpha_threshold``. Formulas: docs/formulas.md, "NACC plasticity"; the
kernels' law: ``csrc/common/materials/nacc.h``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

import numpy as np

from fracture_gs import keys
from fracture_gs.materials.hencky import (ELASTIC_KEYS, as_float_tensor, compose, energy_density_reference,
                                          hencky_strain, kirchhoff_from_strain, proper_svd, require)
from fracture_gs.materials.model import MaterialModel, parameter

P0_FLOOR = 1e-5             # p0 = K (1e-5 + sinh(ξ max(-α, 0)))
# Project when y > 1e-6 M² p0²: relative to the ellipse's own size, so a cohesionless particle
# (p0 at its floor) is still projected and hardened (docs/design_mpm.md, "NACC tolerances").
YIELD_TOLERANCE = 1e-6
DEFAULT_BETA = 0.5
DEFAULT_XI = 1.0
DEFAULT_M = 2.36
# Ranges of the keys (fracture_gs/bounds.py holds those every model shares).
ALPHA0_RANGE = (-2.3, 2.3)           # α0 = ln Jp0
JP0_RANGE = (0.1, 10.0)              # Jp0 = exp(α0)
BETA_RANGE = (0.0, 10.0)             # cohesion share β
XI_RANGE = (0.0, 10.0)               # hardening ξ
M_RANGE = (0.0, 10.0)                # critical-state slope (> 0; M = 3 at a friction angle of 90°)


def friction_angle_to_M(phi_degrees: float) -> float:
    """Slope M of the critical state line for a friction angle φ: M = 6 sinφ / (3 − sinφ)."""
    if not 0.0 < phi_degrees < 90.0:
        raise ValueError(f"friction_angle: {phi_degrees} is not in (0, 90) degrees")
    s = math.sin(math.radians(phi_degrees))
    return 6.0 * s / (3.0 - s)


@dataclass
class ReturnMapResult:
    """Outcome of the NACC return map in principal strains."""

    strain: torch.Tensor      # (N,3) returned Hencky strain ε'
    alpha: torch.Tensor       # (N,) updated α
    projected: torch.Tensor   # (N,) bool, False where F stays exactly F_trial
    tip: torch.Tensor         # (N,) bool, projected to the compression or tension tip


def nacc_return_map_strain(strain: torch.Tensor, alpha: torch.Tensor, mu: torch.Tensor,
                           bulk: torch.Tensor, beta: torch.Tensor, xi: torch.Tensor,
                           M: torch.Tensor) -> ReturnMapResult:
    """NACC return map on principal Hencky strains (N,3); parameters (N,) or scalars."""
    e = strain.sum(-1)
    deviatoric = strain - e[..., None] / 3.0
    q = math.sqrt(1.5) * 2.0 * mu * deviatoric.norm(dim=-1)
    p0 = bulk * (P0_FLOOR + torch.sinh(xi * (-alpha).clamp_min(0.0)))
    p = -bulk * e

    compression_tip = p > p0
    tension_tip = ~compression_tip & (p < -beta * p0)
    tip = compression_tip | tension_tip
    e_tip = torch.where(compression_tip, -p0 / bulk, beta * p0 / bulk)

    y = (1.0 + 2.0 * beta) * q**2 + M**2 * (p + beta * p0) * (p - p0)
    yielding = ~tip & (y > YIELD_TOLERANCE * (M * p0) ** 2)
    q_new = M * torch.sqrt(((p + beta * p0) * (p0 - p) / (1.0 + 2.0 * beta)).clamp_min(0.0))
    shrink = torch.where(q > 0, q_new / q.clamp_min(torch.finfo(q.dtype).tiny), 0.0)
    strain_projected = e[..., None] / 3.0 + shrink[..., None] * deviatoric  # keeps tr ε

    # CD-MPM hardening: α moves as if p went toward the ellipse centre along the ray. The gate is
    # relative to p0 only (p strictly between the tips); p0 >= 1e-5 K keeps the ray well defined.
    hardening = yielding & (-beta * p0 < p) & (p < p0)
    centre = 0.5 * (1.0 - beta) * p0
    half_axis = 0.5 * (1.0 + beta) * p0
    t = M * half_axis / torch.sqrt((1.0 + 2.0 * beta) * q**2 + M**2 * (p - centre) ** 2)
    p_final = centre + t * (p - centre)

    zero = torch.zeros_like(alpha)
    alpha_new = (alpha + torch.where(tip, e - e_tip, zero)
                 + torch.where(hardening, (p_final - p) / bulk, zero))
    strain_new = torch.where(tip[..., None], (e_tip / 3.0)[..., None].expand_as(strain),
                             torch.where(yielding[..., None], strain_projected, strain))
    return ReturnMapResult(strain_new, alpha_new, tip | yielding, tip)


def nacc_update_reference(F_trial: torch.Tensor, alpha: torch.Tensor, mu: torch.Tensor,
                          lam: torch.Tensor, bulk: torch.Tensor, beta: torch.Tensor,
                          xi: torch.Tensor, M: torch.Tensor
                          ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """NACC return map on F: (F_trial, α) -> (F_E, α', τ(F_E)); F unchanged where not projected."""
    U, sigma, V = proper_svd(F_trial)
    result = nacc_return_map_strain(hencky_strain(sigma), alpha, mu, bulk, beta, xi, M)
    F_projected = compose(U, torch.exp(result.strain), V)
    F_E = torch.where(result.projected[..., None, None], F_projected, F_trial)
    tau = kirchhoff_from_strain(U, result.strain, mu, lam)
    return F_E, result.alpha, tau


_NACC_KEYS = ("alpha0", "Jp0", "beta", "xi", "M", "friction_angle", "alpha_threshold")


@dataclass(frozen=True)
class NACCMaterial(MaterialModel):
    """Non-associated Cam-Clay plasticity (Wolper et al. 2019) in Hencky strain.

    ``alpha0`` is the initial hardening state ln(J_p0) (more negative = stronger);
    a particle counts as fractured once α >= ``alpha_threshold``.
    """

    alpha0: float
    beta: float
    xi: float
    M: float
    alpha_threshold: float = 0.0

    name: ClassVar[str] = "nacc"
    code: ClassVar[int] = 1
    yaml_keys: ClassVar[tuple[str, ...]] = ("part", "model") + ELASTIC_KEYS + _NACC_KEYS
    parameter_columns: ClassVar[tuple[str, ...]] = ("beta", "xi", "M")
    state_fields: ClassVar[tuple[str, ...]] = ("alpha",)

    def __post_init__(self) -> None:
        owner = type(self).__name__
        self._validate_elasticity()
        require(owner, "alpha0", self.alpha0, True, "a finite number")
        require(owner, "beta", self.beta, self.beta >= 0, ">= 0")
        require(owner, "xi", self.xi, self.xi >= 0, ">= 0")
        require(owner, "M", self.M, self.M > 0, "> 0")
        require(owner, "alpha_threshold", self.alpha_threshold, True, "a finite number")

    @classmethod
    def from_jp0(cls, E: float, nu: float, density: float, Jp0: float, beta: float, xi: float,
                 M: float, alpha_threshold: float = 0.0) -> "NACCMaterial":
        """Build from the initial plastic volume ratio J_p0 (the paper's Table 1 'α'): α0 = ln J_p0."""
        require(cls.__name__, "Jp0", Jp0, Jp0 > 0, "> 0")
        return cls(E, nu, density, math.log(Jp0), beta, xi, M, alpha_threshold)

    @classmethod
    def from_friction_angle(cls, E: float, nu: float, density: float, alpha0: float,
                            beta: float, xi: float, friction_angle: float,
                            alpha_threshold: float = 0.0) -> "NACCMaterial":
        """Build with M = 6 sinφ/(3 − sinφ) from a friction angle φ in degrees."""
        return cls(E, nu, density, alpha0, beta, xi, friction_angle_to_M(friction_angle),
                   alpha_threshold)

    @classmethod
    def from_yaml(cls, data: Any, path: str) -> "NACCMaterial":
        """The material of a scene's material mapping. α0 may be given as ``alpha0`` or as the paper's
        ``Jp0`` (α0 = ln Jp0), M as ``M`` or as ``friction_angle`` φ in degrees."""
        keys.check_keys(data, path, cls.yaml_keys, required=ELASTIC_KEYS)
        elasticity = cls.elasticity_from_yaml(data, path)
        if "alpha0" in data and "Jp0" in data:
            raise keys.SceneError(f"{path}.Jp0", "give only one of 'alpha0' and 'Jp0' (both given)")
        if "alpha0" not in data and "Jp0" not in data:
            raise keys.SceneError(f"{path}.alpha0", "required key is missing (give 'alpha0' or 'Jp0')")
        if "alpha0" in data:
            alpha0 = keys.number(data, "alpha0", path, within=ALPHA0_RANGE)
        else:
            alpha0 = math.log(keys.number(data, "Jp0", path, gt=0.0, within=JP0_RANGE))
        if "M" in data and "friction_angle" in data:
            raise keys.SceneError(f"{path}.M", "give at most one of 'M' and 'friction_angle' (both given)")
        if "friction_angle" in data:
            M = friction_angle_to_M(keys.number(data, "friction_angle", path, gt=0.0, lt=90.0))
        else:
            M = keys.number(data, "M", path, DEFAULT_M, gt=0.0, within=M_RANGE)
        return cls(**elasticity, alpha0=alpha0,
                   beta=keys.number(data, "beta", path, DEFAULT_BETA, ge=0.0, within=BETA_RANGE),
                   xi=keys.number(data, "xi", path, DEFAULT_XI, ge=0.0, within=XI_RANGE), M=M,
                   alpha_threshold=keys.number(data, "alpha_threshold", path, 0.0))

    def to_yaml(self) -> dict[str, Any]:
        """The resolved keys (``model`` included; α0 and M whatever form the scene gave)."""
        return {"model": self.name, "E": self.E, "nu": self.nu, "density": self.density, "alpha0": self.alpha0,
                "beta": self.beta, "xi": self.xi, "M": self.M, "alpha_threshold": self.alpha_threshold}

    def parameters(self, cell_size: float | None) -> tuple[float, ...]:
        """β, ξ, M (``parameter_columns``)."""
        return (self.beta, self.xi, self.M)

    @property
    def fracture_threshold(self) -> float:
        """α from which a particle counts as fractured (the flag latches)."""
        return self.alpha_threshold

    def initial_state(self, index: np.ndarray, rest_volume: np.ndarray, seed: int) -> np.ndarray:
        """α0 for every particle."""
        return np.full((len(index), 1), self.alpha0, dtype=np.float64)

    def partition_threshold(self, damage_dilation: float) -> float:
        """α from which the fragment partition treats a particle as damaged: cohesion gone
        (α >= ``alpha_threshold``) and the material opened by ``damage_dilation`` of its volume."""
        return self.alpha_threshold + damage_dilation

    def return_map(self, F_trial: torch.Tensor, alpha: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """NACC return map: (F_trial (N,3,3), α (N,)) -> (F_E, α')."""
        F_E, alpha_new, _ = nacc_update_reference(
            F_trial, alpha, *(as_float_tensor(F_trial, v) for v in
                              (self.mu, self.lam, self.bulk, self.beta, self.xi, self.M)))
        return F_E, alpha_new

    @classmethod
    def update_rows(cls, F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: (F_E, state with α', τ, 0)."""
        F_E, alpha, tau = nacc_update_reference(F_trial, state[:, 0], rows[:, 1], rows[:, 2], rows[:, 3],
                                                *(parameter(rows, cls, name) for name in cls.parameter_columns))
        state_new = state.clone()
        state_new[:, 0] = alpha
        return F_E, state_new, tau, torch.zeros(len(F_trial), dtype=F_trial.dtype, device=F_trial.device)

    @staticmethod
    def energy_rows(F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density ψ for particles of this model."""
        return energy_density_reference(F_E, rows[:, 1], rows[:, 2])
