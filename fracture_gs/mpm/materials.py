"""Constitutive models of the MPM solver (SPEC §5.3) and their PyTorch twins.

Two models share St. Venant-Kirchhoff elasticity on the Hencky strain:

* :class:`ElasticMaterial` - no plasticity, F and α never change.
* :class:`NACCMaterial` - the NACC return map of Wolper et al. (2019) with CD-MPM hardening.

The compiled kernels (``csrc/common/constitutive.h``) read a float32 *material table*,
one row of 8 numbers per material (``TABLE_COLUMNS``); :class:`MaterialTable` builds it and
:func:`constitutive_update_reference` is the vectorised torch twin of the compiled op
``fracture_gs._C.constitutive_update`` (mixed materials handled with one mask per model).

Inverted elements (det F < 0): the signed SVD puts the sign on σ₃, and the Hencky strain
uses ε = ln max(|σ|, 1e-4), i.e. an inverted F is treated as its mirror image. Then
τ = (∂ψ/∂F) Fᵀ still holds, and a projection of the return map returns det F_E > 0.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import ClassVar, Iterable, Sequence, Union

import torch

from fracture_gs import _backend

MODEL_ELASTIC = 0
MODEL_NACC = 1
TABLE_COLUMNS = ("model", "mu", "lambda", "bulk", "beta", "xi", "M", "alpha_threshold")
COLUMN = {name: index for index, name in enumerate(TABLE_COLUMNS)}

MIN_SINGULAR_VALUE = 1e-4   # σ clamp of the Hencky strain
P0_FLOOR = 1e-5             # p0 = K (1e-5 + sinh(ξ max(-α, 0)))
# Project when y > 1e-6 M² p0²: relative to the ellipse's own size, so a cohesionless particle
# (p0 at its floor) is still projected and hardened (SPEC §5.3 wrote 1e-8 K² and gated hardening
# on p0 > 1e-4 K: both absolute, and shear failure then stopped short of α = 0).
YIELD_TOLERANCE = 1e-6


# ----------------------------------------------------------------------------- parameters

def lame_parameters(E: float, nu: float) -> tuple[float, float]:
    """Lamé (μ, λ) from Young's modulus E and Poisson ratio ν."""
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def friction_angle_to_M(phi_degrees: float) -> float:
    """Slope M of the critical state line for a friction angle φ: M = 6 sinφ / (3 − sinφ)."""
    if not 0.0 < phi_degrees < 90.0:
        raise ValueError(f"friction_angle: {phi_degrees} is not in (0, 90) degrees")
    s = math.sin(math.radians(phi_degrees))
    return 6.0 * s / (3.0 - s)


def _require(owner: str, name: str, value: float, ok: bool, rule: str) -> None:
    if not (isinstance(value, numbers.Real) and math.isfinite(value) and ok):
        raise ValueError(f"{owner}.{name}: {value!r} is not {rule}")


def _validate_elasticity(owner: str, E: float, nu: float, density: float) -> None:
    _require(owner, "E", E, E > 0, "> 0")
    _require(owner, "nu", nu, 0.0 <= nu, ">= 0")
    _require(owner, "nu", nu, nu < 0.5, "< 0.5")
    _require(owner, "density", density, density > 0, "> 0")


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
    """NACC return map of SPEC §5.3 on principal Hencky strains (N,3); parameters (N,) or scalars."""
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


# ----------------------------------------------------------------------------- materials

def _as_float_tensor(F: torch.Tensor, value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=F.dtype, device=F.device)


@dataclass(frozen=True)
class _HenckyElasticity:
    """Shared elastic part: Lamé parameters, wave speed, stress and energy."""

    E: float
    nu: float
    density: float

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

    def kirchhoff_stress(self, F_E: torch.Tensor) -> torch.Tensor:
        """Kirchhoff stress τ of F_E (N,3,3)."""
        return kirchhoff_stress_reference(F_E, self.mu, self.lam)

    def energy_density(self, F_E: torch.Tensor) -> torch.Tensor:
        """Elastic energy per unit rest volume ψ(F_E), (N,)."""
        return energy_density_reference(F_E, self.mu, self.lam)


@dataclass(frozen=True)
class ElasticMaterial(_HenckyElasticity):
    """St. Venant-Kirchhoff on the Hencky strain, no plasticity (unbreakable parts)."""

    model_code: ClassVar[int] = MODEL_ELASTIC
    alpha0: ClassVar[float] = 0.0                 # α is carried but never changes
    alpha_threshold: ClassVar[float] = math.inf   # never flagged as fractured

    def __post_init__(self) -> None:
        _validate_elasticity(type(self).__name__, self.E, self.nu, self.density)

    def pack(self) -> list[float]:
        """One row of the material table (see TABLE_COLUMNS)."""
        return [float(MODEL_ELASTIC), self.mu, self.lam, self.bulk, 0.0, 0.0, 0.0,
                self.alpha_threshold]

    def return_map(self, F_trial: torch.Tensor, alpha: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """No plasticity: (F_E, α) = (F_trial, α) (copies)."""
        return F_trial.clone(), alpha.clone()


@dataclass(frozen=True)
class NACCMaterial(_HenckyElasticity):
    """Non-associated Cam-Clay plasticity (Wolper et al. 2019) in Hencky strain (SPEC §5.3).

    ``alpha0`` is the initial hardening state ln(J_p0) (more negative = stronger);
    a particle counts as fractured once α >= ``alpha_threshold``.
    """

    alpha0: float
    beta: float
    xi: float
    M: float
    alpha_threshold: float = 0.0

    model_code: ClassVar[int] = MODEL_NACC

    def __post_init__(self) -> None:
        owner = type(self).__name__
        _validate_elasticity(owner, self.E, self.nu, self.density)
        _require(owner, "alpha0", self.alpha0, True, "a finite number")
        _require(owner, "beta", self.beta, self.beta >= 0, ">= 0")
        _require(owner, "xi", self.xi, self.xi >= 0, ">= 0")
        _require(owner, "M", self.M, self.M > 0, "> 0")
        _require(owner, "alpha_threshold", self.alpha_threshold, True, "a finite number")

    @classmethod
    def from_jp0(cls, E: float, nu: float, density: float, Jp0: float, beta: float, xi: float,
                 M: float, alpha_threshold: float = 0.0) -> "NACCMaterial":
        """Build from the initial plastic volume ratio J_p0 (the paper's Table 1 'α'): α0 = ln J_p0."""
        _require(cls.__name__, "Jp0", Jp0, Jp0 > 0, "> 0")
        return cls(E, nu, density, math.log(Jp0), beta, xi, M, alpha_threshold)

    @classmethod
    def from_friction_angle(cls, E: float, nu: float, density: float, alpha0: float,
                            beta: float, xi: float, friction_angle: float,
                            alpha_threshold: float = 0.0) -> "NACCMaterial":
        """Build with M = 6 sinφ/(3 − sinφ) from a friction angle φ in degrees."""
        return cls(E, nu, density, alpha0, beta, xi, friction_angle_to_M(friction_angle),
                   alpha_threshold)

    def pack(self) -> list[float]:
        """One row of the material table (see TABLE_COLUMNS)."""
        return [float(MODEL_NACC), self.mu, self.lam, self.bulk, self.beta, self.xi, self.M,
                self.alpha_threshold]

    def return_map(self, F_trial: torch.Tensor, alpha: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """NACC return map: (F_trial (N,3,3), α (N,)) -> (F_E, α')."""
        F_E, alpha_new, _ = nacc_update_reference(
            F_trial, alpha, *(_as_float_tensor(F_trial, v) for v in
                              (self.mu, self.lam, self.bulk, self.beta, self.xi, self.M)))
        return F_E, alpha_new


Material = Union[ElasticMaterial, NACCMaterial]


class MaterialTable:
    """The materials of a scene in table order; row i is material_id i."""

    def __init__(self, materials: Sequence[Material]) -> None:
        if len(materials) == 0:
            raise ValueError("MaterialTable: materials is empty")
        for index, material in enumerate(materials):
            if not isinstance(material, (ElasticMaterial, NACCMaterial)):
                raise ValueError(f"MaterialTable: materials[{index}] is a "
                                 f"{type(material).__name__}, not a material")
        self.materials = list(materials)

    def __len__(self) -> int:
        return len(self.materials)

    def table(self, device: torch.device | str | None = None) -> torch.Tensor:
        """(M, 8) float32 tensor of packed rows, on ``device``."""
        return torch.tensor([m.pack() for m in self.materials], dtype=torch.float32, device=device)

    @property
    def max_wave_speed(self) -> float:
        """Largest P-wave speed over all materials (for the CFL time step)."""
        return max(m.wave_speed for m in self.materials)

    def initial_alpha(self, material_id: torch.Tensor) -> torch.Tensor:
        """α0 of every particle (float32, on material_id's device)."""
        alpha0 = torch.tensor([m.alpha0 for m in self.materials], dtype=torch.float32,
                              device=material_id.device)
        return alpha0[material_id.long()]


TableLike = Union[torch.Tensor, MaterialTable, Iterable[Material]]


def _table_tensor(materials: TableLike, like: torch.Tensor) -> torch.Tensor:
    """The material table as a tensor with ``like``'s device and dtype."""
    if isinstance(materials, torch.Tensor):
        table = materials
    else:
        table_obj = materials if isinstance(materials, MaterialTable) else MaterialTable(list(materials))
        table = table_obj.table(like.device)
    if table.ndim != 2 or table.shape[1] != len(TABLE_COLUMNS):
        raise ValueError(f"material_table must have shape (M, {len(TABLE_COLUMNS)}), "
                         f"got {tuple(table.shape)}")
    return table.to(device=like.device, dtype=like.dtype)


def _rows_per_particle(table: torch.Tensor, material_id: torch.Tensor) -> torch.Tensor:
    """Gather the table row of every particle, (N, 8); ValueError on out-of-range ids."""
    if material_id.numel() > 0:
        low, high = int(material_id.min()), int(material_id.max())
        if low < 0 or high >= table.shape[0]:
            raise ValueError(f"material_id: ids must be in [0, {table.shape[0]}), "
                             f"got range [{low}, {high}]")
    return table[material_id.long()]


def constitutive_update_reference(material_table_or_materials: TableLike,
                                  material_id: torch.Tensor, F_trial: torch.Tensor,
                                  alpha: torch.Tensor
                                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Torch twin of ``_C.constitutive_update``: (F_E, α', τ) for mixed materials.

    Computes in F_trial's dtype (pass float64 for a reference of the float32 kernels).
    Rows with an unknown model code give NaN, like the compiled kernels.
    """
    table = _table_tensor(material_table_or_materials, F_trial)
    rows = _rows_per_particle(table, material_id)
    alpha = alpha.to(F_trial.dtype)
    column = {name: rows[:, index] for name, index in COLUMN.items()}
    model = column["model"]
    is_elastic = model == MODEL_ELASTIC
    is_nacc = model == MODEL_NACC

    F_E = F_trial.clone()
    alpha_new = alpha.clone()
    tau = torch.full_like(F_trial, math.nan)
    if bool(is_elastic.any()):
        tau[is_elastic] = kirchhoff_stress_reference(
            F_trial[is_elastic], column["mu"][is_elastic], column["lambda"][is_elastic])
    if bool(is_nacc.any()):
        F_nacc, alpha_nacc, tau_nacc = nacc_update_reference(
            F_trial[is_nacc], alpha[is_nacc],
            *(column[name][is_nacc] for name in ("mu", "lambda", "bulk", "beta", "xi", "M")))
        F_E[is_nacc] = F_nacc
        alpha_new[is_nacc] = alpha_nacc
        tau[is_nacc] = tau_nacc
    # Like the kernels: unknown models and non-finite inputs give NaN, never a finite projection.
    unknown = ~(is_elastic | is_nacc) | ~torch.isfinite(F_trial).flatten(1).all(1) | ~torch.isfinite(alpha)
    tau[unknown] = math.nan
    F_E[unknown] = math.nan
    alpha_new[unknown] = math.nan
    return F_E, alpha_new, tau


def elastic_energy_reference(material_table_or_materials: TableLike, material_id: torch.Tensor,
                             F_E: torch.Tensor) -> torch.Tensor:
    """Torch twin of ``_C.elastic_energy``: ψ(F_E) per unit rest volume, (N,)."""
    table = _table_tensor(material_table_or_materials, F_E)
    rows = _rows_per_particle(table, material_id)
    return energy_density_reference(F_E, rows[:, COLUMN["mu"]], rows[:, COLUMN["lambda"]])


def constitutive_update(F_trial: torch.Tensor, alpha: torch.Tensor, material_table: torch.Tensor,
                        material_id: torch.Tensor, backend: str = "auto"
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(F_E, α', τ) per particle, compiled kernel or torch reference (``_backend.use_compiled``)."""
    if _backend.use_compiled(F_trial.device, backend):
        return _backend.compiled_module().constitutive_update(F_trial, alpha, material_table,
                                                              material_id)
    F_E, alpha_new, tau = constitutive_update_reference(material_table, material_id, F_trial, alpha)
    return F_E, alpha_new.to(alpha.dtype), tau


def elastic_energy(F_E: torch.Tensor, material_table: torch.Tensor, material_id: torch.Tensor,
                   backend: str = "auto") -> torch.Tensor:
    """ψ(F_E) per unit rest volume, compiled kernel or torch reference."""
    if _backend.use_compiled(F_E.device, backend):
        return _backend.compiled_module().elastic_energy(F_E, material_table, material_id)
    return elastic_energy_reference(material_table, material_id, F_E)
