"""``model: brittle``: elastic pieces that crack - porcelain, glass, ceramic, stone.

The same Hencky elasticity as every material, no plasticity, and a per-particle damage d in [0, 1]
that never decreases (state field 0; frames store it as ``damage``), the particle's own strength
and the normal of its crack plane (the rest of its state). Formulas (docs/formulas.md, "Brittle
damage"; the kernels' law is ``csrc/common/materials/brittle.h``):

* Rankine driving stress s: the largest principal value of the undegraded Cauchy stress τ₀ / J.
* Crack band (Bažant & Oh 1983): in a band of width h the stress falls linearly from the
  strength σ_F to zero, so the band dissipates G_f per unit crack area whatever the grid. In
  undegraded-stress terms the softening line ends at s_f = σ_F r, r = r0 = B / σ_F² with
  B = 2 E G_f / (h c_t) while r0 <= 3; above, the particles beside the band soften too and r < r0
  keeps the band and them at G_f (``softening_ratio``). Along the line
  g_target(s) = σ_F (s_f − s) / ((s_f − σ_F) s), and d solves g(d) = g_target. A band too coarse
  for the softening (s_f <= σ_F, i.e. h >= 2 E G_f / (c_t σ_F²)) breaks at once.
  d = max(d_old, d_target).
* Degradation g(d) = (1 − d)² (1 − k) + k of the tensile part only (Miehe's spectral split: a
  crack closed by compression carries the compression, and volumetric compression is never
  degraded): ψ = g ψ⁺ + ψ⁻, ψ⁺ = μ Σ⟨ε_i⟩₊² + (λ/2)⟨tr ε⟩₊², ψ⁻ = μ Σ⟨ε_i⟩₋² + (λ/2)⟨tr ε⟩₋²,
  τ_i = 2μ g_i ε_i + λ g_e tr ε (g_i = g where ε_i > 0, else 1).
* Weibull strength: σ_F,p = σ_F (V_ref ln R_p / (V_p ln 0.5))^(1/m), R_p a hash of the particle's
  index and the scene's seed (so runs, resumes, CPU and CUDA agree), V_ref the mean rest volume.
* The crack band width h is the grid's cell size (``BAND_CELLS`` cells; docs/materials.md says why).
* Crack plane: when a particle's damage becomes complete, the normal of its crack is the direction of
  its largest principal stretch (of its largest principal stress, Rankine); afterwards the normal is
  carried with the material like the normal of a material plane, n ← (I − Δt Cᵀ) n, normalised, and
  oriented so that its dot product with ``CRACK_ORIENTATION`` is positive (the particles of one crack
  plane share one orientation, whatever their order). The fragment partition splits the nodes around
  it along that plane (``split_direction``; docs/design_mpm.md, "Fragments").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from fracture_gs import bounds, keys
from fracture_gs.materials.hencky import ELASTIC_KEYS, compose, hencky_strain, proper_svd, require
from fracture_gs.materials.model import MaterialModel, SubstepView, field, parameter
from fracture_gs.materials.split_directions import advance_split_directions

BAND_CELLS = 1.0           # crack band width h in grid cells
DEFAULT_WEIBULL_M = 0.0    # 0: every particle has the material's strength
DEFAULT_RESIDUAL = 1e-3
DEFAULT_FRACTURE_DAMAGE = 0.5
# The partition (crack opening) splits material whose damage is complete.
COMPLETE_DAMAGE = 1.0
_BRITTLE_KEYS = ("strength", "fracture_energy", "weibull_m", "residual", "fracture_damage")
# Ranges of the keys beside fracture_gs/bounds.py's (strength: bounds.STRESS).
FRACTURE_ENERGY_RANGE = (0.0, 1.0e7)   # J/m² (> 0; glass ~5, tough steels ~1e5)
WEIBULL_M_RANGE = (1.0, 100.0)         # Weibull modulus (chalk ~3, glass ~10, steels ~50); or 0: no scatter
# Crack normals point to this side (a unit vector in no symmetry plane of the grid).
CRACK_ORIENTATION = (0.2672612419124244, 0.5345224838248488, 0.8017837257372732)


def degradation(damage: torch.Tensor, residual: torch.Tensor | float) -> torch.Tensor:
    """g(d) = (1 − d)² (1 − k) + k."""
    return (1.0 - damage) ** 2 * (1.0 - residual) + residual


def softening_ratio(uniform_ratio: torch.Tensor | float) -> torch.Tensor:
    """s_f / σ_F, where the softening line ends, for r0 = B / σ_F² (``uniform_ratio``): r0 while
    r0 <= 3, else the larger root of 4 r² − (6 + 3 r0) r + 3 r0 = 0. The quadratic B-spline spreads
    a crack over four particle layers (at the cells' quarter points), the outer pair strained a third
    as much as the inner pair; above r0 = 3 the outer pair softens too, and r < r0 keeps the two
    pairs together at G_f per unit crack area (docs/formulas.md, "Brittle damage")."""
    r0 = torch.as_tensor(uniform_ratio, dtype=torch.float64)
    b = 6.0 + 3.0 * r0
    spread = 0.125 * (b + torch.sqrt(b * b - 48.0 * r0))
    return torch.where(r0 > 3.0, spread, r0)


def damage_target(driving: torch.Tensor, strength: torch.Tensor, crack_band: torch.Tensor,
                  residual: torch.Tensor) -> torch.Tensor:
    """Damage the crack-band law reaches at driving stress s (0 while s <= σ_F); ``crack_band`` is
    B = 2 E G_f / (h c_t), so the softening line ends at s_f = σ_F softening_ratio(B / σ_F²)."""
    s_f = strength * softening_ratio(crack_band / (strength * strength)).to(driving.dtype)
    softens = s_f > strength
    span = torch.where(softens, (s_f - strength) * driving, torch.ones_like(driving))
    g_target = torch.where(softens, strength * (s_f - driving) / span, torch.zeros_like(driving))
    share = ((g_target - residual) / (1.0 - residual)).clamp(0.0, 1.0)
    return torch.where(driving > strength, 1.0 - torch.sqrt(share), torch.zeros_like(driving))


def spectral_split(strain: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """(ψ⁺, ψ⁻) of principal Hencky strains (Miehe's spectral split): ψ⁺ = μ Σ⟨ε_i⟩₊² + (λ/2)⟨tr ε⟩₊²
    takes the tensile principal strains, ψ⁻ the compressive ones; ψ⁺ + ψ⁻ is the Hencky energy."""
    e = strain.sum(-1)
    positive = strain.clamp_min(0.0)
    negative = strain.clamp_max(0.0)
    tensile = mu * (positive * positive).sum(-1) + 0.5 * lam * e.clamp_min(0.0) ** 2
    compressive = mu * (negative * negative).sum(-1) + 0.5 * lam * e.clamp_max(0.0) ** 2
    return tensile, compressive


def brittle_update_reference(F_trial: torch.Tensor, damage: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor,
                             bulk: torch.Tensor, strength: torch.Tensor, crack_band: torch.Tensor,
                             residual: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The brittle update: (F_trial, d, parameters per row) -> (F_E = F_trial, d', τ). The principal
    Kirchhoff stress is τ_i = 2μ g_i ε_i + λ g_e tr ε, g_i = g(d) where ε_i > 0 (else 1), g_e likewise."""
    U, sigma, _ = proper_svd(F_trial)
    strain = hencky_strain(sigma)
    e = strain.sum(-1)
    deviatoric_max = strain.max(-1).values - e / 3.0
    driving = (2.0 * mu * deviatoric_max + bulk * e) * torch.exp(-e)
    damage_new = torch.maximum(damage.to(F_trial.dtype), damage_target(driving, strength, crack_band, residual))
    g = degradation(damage_new, residual)
    g_principal = torch.where(strain > 0, g[..., None], torch.ones_like(strain))
    g_volume = torch.where(e > 0, g, torch.ones_like(e))
    principal = 2.0 * mu[..., None] * g_principal * strain + (lam * g_volume * e)[..., None]
    return F_trial.clone(), damage_new, compose(U, principal, U)


def brittle_energy_reference(F_E: torch.Tensor, damage: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor,
                             residual: torch.Tensor) -> torch.Tensor:
    """ψ = g(d) ψ⁺ + ψ⁻ per unit rest volume."""
    tensile, compressive = spectral_split(hencky_strain(torch.linalg.svdvals(F_E)), mu, lam)
    return degradation(damage.to(F_E.dtype), residual) * tensile + compressive


def tensile_energy_reference(F_E: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """ψ⁺, the part of the energy that damage degrades (per unit rest volume)."""
    return spectral_split(hencky_strain(torch.linalg.svdvals(F_E)), mu, lam)[0]


@dataclass(frozen=True)
class BrittleMaterial(MaterialModel):
    """Rankine damage with crack-band softening, Weibull strength and tension-only degradation.

    ``strength`` σ_F (Pa; the median when ``weibull_m`` > 0), ``fracture_energy`` G_f (J/m²),
    ``weibull_m`` (0: every particle has σ_F), ``residual`` k (share of the tensile stiffness left
    at d = 1), ``fracture_damage`` (d from which a particle counts as fractured).
    """

    strength: float
    fracture_energy: float
    weibull_m: float = DEFAULT_WEIBULL_M
    residual: float = DEFAULT_RESIDUAL
    fracture_damage: float = DEFAULT_FRACTURE_DAMAGE

    name: ClassVar[str] = "brittle"
    code: ClassVar[int] = 2
    yaml_keys: ClassVar[tuple[str, ...]] = ("part", "model") + ELASTIC_KEYS + _BRITTLE_KEYS
    parameter_columns: ClassVar[tuple[str, ...]] = ("strength", "crack_band", "residual")
    state_fields: ClassVar[tuple[str, ...]] = ("damage", "strength", "normal_x", "normal_y", "normal_z")
    frame_fields: ClassVar[tuple[str, ...]] = ("damage",)
    split_direction: ClassVar[str | None] = "normal_x"
    dissipates: ClassVar[bool] = True

    def __post_init__(self) -> None:
        owner = type(self).__name__
        self._validate_elasticity()
        require(owner, "strength", self.strength, self.strength > 0, "> 0")
        require(owner, "fracture_energy", self.fracture_energy, self.fracture_energy > 0, "> 0")
        require(owner, "weibull_m", self.weibull_m, self.weibull_m == 0 or self.weibull_m >= WEIBULL_M_RANGE[0],
                f"0 or >= {WEIBULL_M_RANGE[0]:g}")
        require(owner, "residual", self.residual, 0.0 <= self.residual < 1.0, "in [0, 1)")
        require(owner, "fracture_damage", self.fracture_damage, 0.0 < self.fracture_damage <= 1.0, "in (0, 1]")

    @classmethod
    def from_yaml(cls, data: Any, path: str) -> "BrittleMaterial":
        """The material of a scene's material mapping (``part`` and ``model`` are the scene's)."""
        keys.check_keys(data, path, cls.yaml_keys,
                        required=ELASTIC_KEYS + ("strength", "fracture_energy"))
        return cls(**cls.elasticity_from_yaml(data, path),
                   strength=keys.number(data, "strength", path, gt=0.0, within=bounds.STRESS),
                   fracture_energy=keys.number(data, "fracture_energy", path, gt=0.0, within=FRACTURE_ENERGY_RANGE),
                   weibull_m=keys.number(data, "weibull_m", path, DEFAULT_WEIBULL_M, ge=0.0, within=WEIBULL_M_RANGE,
                                         off=0.0),
                   residual=keys.number(data, "residual", path, DEFAULT_RESIDUAL, ge=0.0, lt=1.0),
                   fracture_damage=keys.number(data, "fracture_damage", path, DEFAULT_FRACTURE_DAMAGE, gt=0.0,
                                               le=1.0))

    def to_yaml(self) -> dict[str, Any]:
        """The resolved keys (``model`` included)."""
        return {"model": self.name, "E": self.E, "nu": self.nu, "density": self.density, "strength": self.strength,
                "fracture_energy": self.fracture_energy, "weibull_m": self.weibull_m, "residual": self.residual,
                "fracture_damage": self.fracture_damage}

    @property
    def fracture_threshold(self) -> float:
        """Damage from which a particle counts as fractured (the flag latches)."""
        return self.fracture_damage

    def partition_threshold(self, damage_dilation: float) -> float:
        """Damage from which the fragment partition treats a particle as damaged: complete damage."""
        return COMPLETE_DAMAGE

    @property
    def piece_threshold(self) -> float:
        """A particle with complete damage is a piece of its own when pieces are counted."""
        return COMPLETE_DAMAGE

    def initial_state(self, index: np.ndarray, rest_volume: np.ndarray, seed: int) -> np.ndarray:
        """Damage 0, each particle's strength (``strengths``), no crack normal."""
        state = np.zeros((len(index), len(self.state_fields)), dtype=np.float64)
        state[:, self.state_fields.index("strength")] = self.strengths(index, rest_volume, seed)
        return state

    @property
    def characteristic_length(self) -> float:
        """Hillerborg's characteristic length E G_f / σ_F² (m)."""
        return self.E * self.fracture_energy / self.strength ** 2

    @property
    def tensile_share(self) -> float:
        """ψ⁺ / ψ in uniaxial tension, 1 − 2ν² / (1 + ν): the lateral contraction's energy is never
        degraded, so the softening line is steepened by this share to spend G_f in a uniaxial band."""
        return 1.0 - 2.0 * self.nu ** 2 / (1.0 + self.nu)

    def band_width(self, cell_size: float) -> float:
        """Crack band width h (m) on a grid of the given cell size."""
        return BAND_CELLS * cell_size

    def crack_band(self, cell_size: float) -> float:
        """B = 2 E G_f / (h · tensile_share) (Pa²): a band of uniform strain whose softening line
        ended at B / σ_F would spend G_f per unit crack area in uniaxial tension (``softening_end``
        says where it ends)."""
        return 2.0 * self.E * self.fracture_energy / (self.band_width(cell_size) * self.tensile_share)

    def softening_end(self, cell_size: float, strength: float | None = None) -> float:
        """s_f (Pa): the undegraded stress at which the softening line of a particle of the given
        strength (default σ_F) ends, σ_F softening_ratio(B / σ_F²)."""
        sigma = self.strength if strength is None else strength
        return sigma * float(softening_ratio(self.crack_band(cell_size) / sigma ** 2))

    def snaps(self, cell_size: float) -> bool:
        """True where the grid is too coarse for the softening (B <= σ_F²): the band breaks at once and
        spends more than G_f per unit crack area (``band_energy_ratio``)."""
        return self.crack_band(cell_size) <= self.strength ** 2

    def band_energy_ratio(self, cell_size: float) -> float:
        """Energy a band in uniaxial tension (with the particles beside it, docs/formulas.md) spends per
        unit crack area over G_f: 1 while it softens, σ_F² / B > 1 when it breaks at once."""
        return max(1.0, self.strength ** 2 / self.crack_band(cell_size))

    def parameters(self, cell_size: float | None) -> tuple[float, ...]:
        """σ_F, B and k (``parameter_columns``); the crack band needs the grid's cell size."""
        if cell_size is None or not cell_size > 0:
            raise ValueError("BrittleMaterial.pack: the crack band needs the grid's cell size (cell_size > 0)")
        return (self.strength, self.crack_band(cell_size), self.residual)

    def strengths(self, index: np.ndarray, rest_volume: np.ndarray, seed: int) -> np.ndarray:
        """Weibull-distributed strength σ_F,p (float64) of the particles with the given indices and rest
        volumes; V_ref is their mean rest volume."""
        if self.weibull_m == 0 or len(index) == 0:
            return np.full(len(index), self.strength, dtype=np.float64)
        uniform = hash_uniform(index, seed)
        volume = rest_volume.astype(np.float64)
        ratio = volume.mean() * np.log(uniform) / (volume * math.log(0.5))
        return self.strength * ratio ** (1.0 / self.weibull_m)

    @classmethod
    def update_rows(cls, F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: (F_E = F_trial, state with
        d', τ, (g(d) − g(d')) ψ⁺)."""
        damage, residual = field(state, cls, "damage"), parameter(rows, cls, "residual")
        F_E, damage_new, tau = brittle_update_reference(
            F_trial, damage, rows[:, 1], rows[:, 2], rows[:, 3], field(state, cls, "strength").to(F_trial.dtype),
            parameter(rows, cls, "crack_band"), residual)
        state_new = state.clone()
        state_new[:, cls.state_fields.index("damage")] = damage_new
        taken = ((degradation(damage.to(F_trial.dtype), residual) - degradation(damage_new, residual))
                 * tensile_energy_reference(F_E, rows[:, 1], rows[:, 2]))
        return F_E, state_new, tau, taken

    @classmethod
    def energy_rows(cls, F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density g(d) ψ⁺ + ψ⁻ for particles of this model."""
        return brittle_energy_reference(F_E, field(state, cls, "damage"), rows[:, 1], rows[:, 2],
                                        parameter(rows, cls, "residual"))

    @classmethod
    def after_substep(cls, view: SubstepView) -> None:
        """Crack planes: carries the normals of cracked particles with the material and gives the
        particles whose damage became complete in this substep the normal of their crack
        (:mod:`fracture_gs.materials.split_directions`)."""
        damage = cls.state_fields.index("damage")
        advance_split_directions(view.state, view.state_old[:, damage], view.C, view.F_E, view.mine,
                                 first=cls.state_fields.index(cls.split_direction or ""), trigger=damage,
                                 start=COMPLETE_DAMAGE, dt=view.dt, orientation=CRACK_ORIENTATION,
                                 backend=view.backend)


def hash_uniform(index: np.ndarray, seed: int) -> np.ndarray:
    """R in (0, 1) per integer index: splitmix64 of (seed << 32) + index, top 53 bits."""
    with np.errstate(over="ignore"):
        z = (np.asarray(index, dtype=np.uint64) + (np.uint64(seed) << np.uint64(32))
             + np.uint64(0x9E3779B97F4A7C15))
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return ((z >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0 ** -53
