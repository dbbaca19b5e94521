"""Particle order for cache-friendly transfers.

P2G visits the particles of one grid block after another (csrc/mpm/mpm_cpu.cpp) and G2P walks
the particles in memory order. When the particles of a block also sit next to each other in
memory, P2G reads its inputs as streams instead of scattered rows and G2P reads neighbouring
grid nodes one after another. `spatial_order` gives that order: by object, then by the
4×4×4-node block of the particle's stencil base, then by its cell inside the block. Particles
keep moving, but bodies move mostly as a whole, so the order stays useful for a whole run.
"""
from __future__ import annotations

import torch

from fracture_gs.mpm.types import BLOCK, Domain, grid_resolution


def spatial_order(x: torch.Tensor, obj_id: torch.Tensor, domain: Domain) -> torch.Tensor:
    """Permutation (int64, stable) that sorts particles by object, grid block and cell.

    x: (N,3) positions; obj_id: (N,) object index; domain: the simulation box. Positions outside
    the box are clamped for the ordering only (they are rejected elsewhere).
    """
    if x.ndim != 2 or x.shape[1] != 3 or obj_id.shape != x.shape[:1]:
        raise ValueError(f"spatial_order: x must be (N,3) and obj_id (N,), got {tuple(x.shape)}, "
                         f"{tuple(obj_id.shape)}")
    resolution = torch.tensor(grid_resolution(domain), device=x.device)
    lower = torch.tensor(domain.lower, dtype=x.dtype, device=x.device)
    # The stencil base node, as the kernels compute it: floor((x - lower) / dx - 1/2).
    base = torch.floor((x - lower) * (1.0 / domain.dx) - 0.5).long()
    base = torch.minimum(base.clamp(min=0), resolution - 1)
    block, cell = base // BLOCK, base % BLOCK
    blocks = resolution // BLOCK
    block_index = (block[:, 0] * blocks[1] + block[:, 1]) * blocks[2] + block[:, 2]
    cell_index = (cell[:, 0] * BLOCK + cell[:, 1]) * BLOCK + cell[:, 2]
    key = (obj_id.long() * int(blocks.prod()) + block_index) * BLOCK ** 3 + cell_index
    return torch.argsort(key, stable=True)


def inverse_permutation(order: torch.Tensor) -> torch.Tensor:
    """``where`` with ``where[order[i]] = i``: for the solver's ``input_index`` (input row of each
    current row), the current row of each input row."""
    where = torch.empty_like(order)
    where[order] = torch.arange(len(order), device=order.device, dtype=order.dtype)
    return where
