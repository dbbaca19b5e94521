"""Plain data types of the Collision-MPM solver (docs/formulas.md §2–§10): particles, state, domain, settings."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

import torch

from fracture_gs.config.scene import DEFAULT_FRAGMENTS

BLOCK = 4  # grid block edge in nodes; grids are padded to a multiple of it
CONTACT_GAP_CELLS = 0.9  # default ContactSettings.max_gap (see docs/design_mpm.md, contact detection)
# A body whose mass centre seen from a node lies closer than this to it (in cells) gives no contact
# normal there: the node sits inside its mass, e.g. in a one-layer sheet (docs/design_mpm.md).
CONTACT_INSIDE_CELLS = 0.4
# Default ContactSettings.split_gradient: a node is split into two crack sides where the largest
# particle damage gradient reaching it is at least this, in 1/cells (docs/design_mpm.md, fragments).
SPLIT_GRADIENT_CELLS = 0.25
DAMAGE_DILATION = 0.005


class SimulationBlowUp(RuntimeError):
    """The simulation produced NaN/Inf or an impossible velocity; the state was not committed."""


@dataclass
class Domain:
    """Axis-aligned simulation box with cubic cells: dx = (max - min)[0] / grid."""

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    grid: int

    @property
    def dx(self) -> float:
        return (self.upper[0] - self.lower[0]) / self.grid

    @property
    def resolution(self) -> tuple[int, int, int]:
        """Nodes per axis, padded up to a multiple of the block size."""
        cells = [math.ceil((hi - lo) / self.dx - 1e-6) for lo, hi in zip(self.lower, self.upper)]
        return tuple(int(math.ceil((c + 1) / BLOCK) * BLOCK) for c in cells)  # type: ignore[return-value]

    @property
    def size(self) -> float:
        """Largest edge length of the box."""
        return max(hi - lo for lo, hi in zip(self.lower, self.upper))


@dataclass
class ContactSettings:
    """How objects touch: per-object grids + contact impulse, or one shared grid (baseline)."""

    mode: Literal["collision", "mls"] = "collision"
    strength: float = 1.0   # the paper's μ scaling of the normal impulse, 0 <= s <= 2
    friction: float = 0.0   # Coulomb coefficient between objects (tangential cap μ_f · s · j_n)
    # Contact detection, in cells: a node is a contact only where the two bodies' mass centres seen
    # from it are closer than this along the normal (touching solid bodies: 0.81-0.9 dx; touching
    # one-layer sheets: their particle spacing). math.inf: every node where both bodies have mass
    # (no detection test, which acts across a gap; kept to measure that).
    max_gap: float = CONTACT_GAP_CELLS
    # Crack opening inside an object (docs/formulas.md §8): each object grid is split into two fields along
    # the damage gradient, which meet through the same contact impulse. False: one field per
    # object (the paper's behaviour, kept for the ablation).
    fragments: bool = DEFAULT_FRAGMENTS
    split_gradient: float = SPLIT_GRADIENT_CELLS  # in 1/cells (|grad D| dx at which a node splits)
    # A particle is damaged for the partition (D_p = 1) while its current α exceeds its material's
    # fracture threshold by at least this much: cohesion lost and the material opened by that
    # plastic volume dilation (α grows by log J_p). Compaction lowers α again and NACC's cohesion
    # returns with it, so the state, not the latched fracture flag, says where a crack is open.
    damage_dilation: float = DAMAGE_DILATION

    def __post_init__(self) -> None:
        if self.mode not in ("collision", "mls"):
            raise ValueError(f"contact mode must be 'collision' or 'mls', got {self.mode!r}")
        # The impulse leaves (1 - s) of the normal approach speed: beyond 2 it would add energy.
        if not 0.0 <= float(self.strength) <= 2.0:
            raise ValueError(f"contact strength must satisfy 0 <= s <= 2, got {self.strength}")
        if not 0.0 <= float(self.friction) < math.inf:
            raise ValueError(f"contact friction must be a finite number >= 0, got {self.friction}")
        if not float(self.max_gap) > 0.0:
            raise ValueError(f"contact max_gap must be > 0 (in cells), got {self.max_gap}")
        if not 0.0 < float(self.split_gradient) < math.inf:
            raise ValueError(f"contact split_gradient must be a finite number > 0 (1/cells), got {self.split_gradient}")
        if not 0.0 <= float(self.damage_dilation) < math.inf:
            raise ValueError(f"contact damage_dilation must be a finite number >= 0, got {self.damage_dilation}")


@dataclass
class GroundBoundary:
    """Half-space z >= height with Coulomb friction."""

    height: float
    friction: float = 0.5


@dataclass
class BoxBoundary:
    """Domain walls, 3 cells thick: slip, sticky or separate."""

    condition: Literal["slip", "sticky", "separate"] = "slip"


Boundary = GroundBoundary | BoxBoundary


@dataclass
class ParticleSet:
    """Per-particle constant data and initial kinematics (all rows aligned, N particles)."""

    x: torch.Tensor              # (N,3) float32 positions
    v: torch.Tensor              # (N,3) float32 velocities
    mass: torch.Tensor           # (N,) float32
    rest_volume: torch.Tensor    # (N,) float32
    obj_id: torch.Tensor         # (N,) int32, index into the scene's objects
    part_id: torch.Tensor        # (N,) int32, part inside its object
    material_id: torch.Tensor    # (N,) int32, row of the material table
    is_surface: torch.Tensor     # (N,) bool
    gaussian_index: torch.Tensor  # (N,) int64, -1 for particles without a trained Gaussian

    def __post_init__(self) -> None:
        n = self.x.shape[0]
        for f in fields(self):
            value = getattr(self, f.name)
            if value.shape[0] != n:
                raise ValueError(f"ParticleSet.{f.name} has {value.shape[0]} rows, x has {n}")
        if self.x.ndim != 2 or self.x.shape[1] != 3:
            raise ValueError(f"ParticleSet.x must be (N,3), got {tuple(self.x.shape)}")

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def to(self, device: torch.device) -> "ParticleSet":
        return ParticleSet(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    def take(self, index: torch.Tensor) -> "ParticleSet":
        """The particles at ``index`` (a permutation reorders the set), every column alike."""
        return ParticleSet(**{f.name: torch.index_select(getattr(self, f.name), 0, index) for f in fields(self)})


@dataclass
class SimState:
    """Evolving per-particle state plus the clock."""

    x: torch.Tensor               # (N,3)
    v: torch.Tensor               # (N,3)
    C: torch.Tensor               # (N,3,3) APIC affine velocity
    F_E: torch.Tensor             # (N,3,3) elastic deformation gradient
    material_state: torch.Tensor  # (N,S) the material models' state (fracture_gs.materials.model)
    fractured: torch.Tensor       # (N,) bool, latched
    time: float = 0.0
    step: int = 0

    @property
    def alpha(self) -> torch.Tensor:
        """(N,) state field 0 of every particle: NACC's α, the brittle damage (the frames' ``alpha``)."""
        return self.material_state[:, 0]

    def take(self, index: torch.Tensor) -> "SimState":
        """The particles at ``index`` (a permutation reorders them), same clock."""
        def rows(t: torch.Tensor) -> torch.Tensor:
            return torch.index_select(t, 0, index)
        return SimState(x=rows(self.x), v=rows(self.v), C=rows(self.C), F_E=rows(self.F_E),
                        material_state=rows(self.material_state), fractured=rows(self.fractured), time=self.time,
                        step=self.step)


@dataclass
class StepStats:
    """What one call of ``advance`` did."""

    steps: int
    dt_min: float
    clamped: int   # particles whose position had to be clamped into the domain
