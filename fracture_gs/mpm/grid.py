"""Grid geometry, grid fields and particle bins shared by the MPM kernels and their twins.

Nodes are stored block-major (4x4x4 nodes per block, blocks x-major), exactly as in
``csrc/common/mpm_math.h``; :func:`node_index` is the torch version of that layout.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from fracture_gs.mpm.types import BLOCK, Domain, grid_resolution

WALL_CELLS = 3  # thickness of the domain walls, in cells


@dataclass(frozen=True)
class GridGeometry:
    """Where the grid is and how its nodes are laid out."""

    lower: tuple[float, float, float]
    dx: float
    blocks: tuple[int, int, int]   # blocks per axis
    cells: tuple[int, int, int]    # cells per axis of the domain (nodes 0..cells)
    n_grids: int

    @staticmethod
    def from_domain(domain: Domain, n_grids: int) -> "GridGeometry":
        cells = tuple(math.ceil((hi - lo) / domain.dx - 1e-6) for lo, hi in zip(domain.lower, domain.upper))
        blocks = tuple(r // BLOCK for r in grid_resolution(domain))
        return GridGeometry(tuple(float(v) for v in domain.lower), float(domain.dx),
                            blocks, cells, int(n_grids))  # type: ignore[arg-type]

    @property
    def nodes_per_grid(self) -> int:
        return self.blocks[0] * self.blocks[1] * self.blocks[2] * BLOCK ** 3

    @property
    def n_blocks(self) -> int:
        return self.blocks[0] * self.blocks[1] * self.blocks[2]

    def clamp_bounds(self) -> tuple[list[float], list[float]]:
        """Particles are kept inside the domain, outside the 3-cell walls."""
        lower = [lo + WALL_CELLS * self.dx for lo in self.lower]
        upper = [lo + (c - WALL_CELLS) * self.dx for lo, c in zip(self.lower, self.cells)]
        return lower, upper

    def args(self) -> tuple[list[float], float, list[int], int]:
        """(lower, dx, blocks, n_grids) as the compiled kernels take them."""
        return list(self.lower), self.dx, list(self.blocks), self.n_grids


def node_index(ijk: torch.Tensor, geometry: GridGeometry) -> torch.Tensor:
    """Linear node index of integer node coordinates (..., 3) in the block-major layout."""
    by, bz = geometry.blocks[1], geometry.blocks[2]
    i, j, k = ijk.unbind(-1)
    block = ((i // BLOCK) * by + (j // BLOCK)) * bz + (k // BLOCK)
    local = (i % BLOCK) * BLOCK * BLOCK + (j % BLOCK) * BLOCK + (k % BLOCK)
    return block * BLOCK ** 3 + local


def node_coords(geometry: GridGeometry, device: torch.device) -> torch.Tensor:
    """Integer coordinates (nodes_per_grid, 3) of every node, in storage order."""
    index = torch.arange(geometry.nodes_per_grid, device=device)
    by, bz = geometry.blocks[1], geometry.blocks[2]
    block, local = index // BLOCK ** 3, index % BLOCK ** 3
    bk, bj, bi = block % bz, (block // bz) % by, block // (by * bz)
    return torch.stack([bi * BLOCK + local // (BLOCK * BLOCK),
                        bj * BLOCK + (local // BLOCK) % BLOCK,
                        bk * BLOCK + local % BLOCK], -1)


@dataclass
class GridFields:
    """Per-grid node fields, flattened: (n_grids, nodes) and (n_grids, nodes, 3)."""

    mass: torch.Tensor
    momentum: torch.Tensor
    velocity: torch.Tensor
    # With contact only. The contact pass reads them on contact blocks (block ids touched by two
    # grids) only, and the compiled CPU P2G sums them there only (zero elsewhere).
    mass_gradient: torch.Tensor | None    # Σ m_p ∇w: contact normals
    position_moment: torch.Tensor | None  # Σ w m_p (x_p − x_i): mass centre seen from the node, × mass
    # With fragments only (docs/formulas.md §8; the grids are then 2K: fields A of the K object grids, then
    # their fields B). Only the first K grids are used.
    damage: torch.Tensor | None = None     # Σ w m_p D_p (divided by mass: the node's damage)
    reference: torch.Tensor | None = None  # int64 reference key (|∇D_p|² bits << 32 | p), 0 = none

    @staticmethod
    def zeros(geometry: GridGeometry, device: torch.device, with_contact: bool,
              with_fragments: bool = False) -> "GridFields":
        shape = (geometry.n_grids, geometry.nodes_per_grid)
        return GridFields(
            mass=torch.zeros(shape, device=device),
            momentum=torch.zeros(shape + (3,), device=device),
            velocity=torch.zeros(shape + (3,), device=device),
            mass_gradient=torch.zeros(shape + (3,), device=device) if with_contact or with_fragments else None,
            position_moment=torch.zeros(shape + (3,), device=device) if with_contact or with_fragments else None,
            damage=torch.zeros(shape, device=device) if with_fragments else None,
            reference=torch.zeros(shape, device=device, dtype=torch.int64) if with_fragments else None)


@dataclass
class FragmentFields:
    """What G2P needs to read each split node's field (fragments, docs/formulas.md §8)."""

    damage_gradient: torch.Tensor  # (N, 3) ∇D_p
    reference: torch.Tensor        # (2K, nodes) int64 reference keys (first K grids)
    split_particle: torch.Tensor   # (N,) uint8: the stencil reaches a split node
    split_gradient: float          # |∇D| (1/length) at which a node splits
    # (N,) int32 from the partition: bit 9a + 3b + c set where the particle is on side B at its
    # stencil node (a, b, c); None: G2P finds the sides from the reference keys again.
    side_mask: torch.Tensor | None = None

    def as_list(self) -> list[torch.Tensor]:
        tensors = [self.damage_gradient, self.reference, self.split_particle]
        return tensors + [self.side_mask] if self.side_mask is not None else tensors


@dataclass
class G2PStats:
    """Health of the particles after G2P."""

    clamped: int          # positions clamped into the domain
    first_nonfinite: int  # smallest particle index with a non-finite x, v or F_E; -1 if none
    max_speed: float      # largest |v| among the finite particles


@dataclass
class ParticleBins:
    """Particles sorted by (grid, block) and the blocks the kernels must visit (int32 tensors)."""

    order: torch.Tensor           # (N,) particle indices, stable-sorted by key
    cell_start: torch.Tensor      # (P+1,) ranges of non-empty (grid, block) cells in order
    cell_key: torch.Tensor        # (P,) grid * n_blocks + block
    color_cells: torch.Tensor     # (P,) cells grouped by block parity colour
    color_start: torch.Tensor     # (9,)
    touched: torch.Tensor         # (T,) grid * n_blocks + block reached by some stencil, ascending
    contact_blocks: torch.Tensor  # (Q,) block ids touched by two or more grids, ascending

    def as_list(self) -> list[torch.Tensor]:
        return [self.order, self.cell_start, self.cell_key, self.color_cells, self.color_start,
                self.touched, self.contact_blocks]
