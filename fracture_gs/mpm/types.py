"""Plain data types of the Collision-MPM solver (docs/formulas.md §2–§10): particles, state, domain, settings."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

# The solver's settings are the scene schema's (validated where they are made).
from fracture_gs.config.scene import (CONTACT_GAP_CELLS, DAMAGE_DILATION, SPLIT_GRADIENT_CELLS,  # noqa: F401
                                      Boundary, BoxBoundary, ContactSettings, Domain, GroundBoundary)

BLOCK = 4  # grid block edge in nodes; grids are padded to a multiple of it
# A body whose mass centre seen from a node lies closer than this to it (in cells) gives no contact
# normal there: the node sits inside its mass, e.g. in a one-layer sheet (docs/design_mpm.md).
CONTACT_INSIDE_CELLS = 0.4


def grid_resolution(domain: Domain) -> tuple[int, int, int]:
    """Nodes per axis of the solver's grids over ``domain``, padded up to a multiple of the block size."""
    cells = [math.ceil((hi - lo) / domain.dx - 1e-6) for lo, hi in zip(domain.lower, domain.upper)]
    return tuple(int(math.ceil((c + 1) / BLOCK) * BLOCK) for c in cells)  # type: ignore[return-value]


class SimulationBlowUp(RuntimeError):
    """The simulation produced NaN/Inf or an impossible velocity; the state was not committed."""


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
