"""External impulse on the particles: gravity and the boundary conditions (walls, ground).

Inside the solver momentum is conserved (P2G, internal forces, the contact impulses and G2P all
conserve it; docs/formulas.md §9), so total momentum may change only through gravity and the boundaries.
Summing what those two give every substep turns "momentum is constant" — true only without
gravity and boundary contact — into a check that holds in every scene:

    p(t) − p(0) = J(t),   J = Σ_substeps (M g dt + Σ_nodes m_i (v_i after − v_i before)),

the second sum taken over the nodes the boundary pass may change. Those nodes lie in a few
grid blocks (the 3-cell walls, the ground band); :class:`ExternalImpulse` finds these blocks once
and per substep reads only the touched ones among them, so scenes whose objects stay away from
the boundaries pay a mask lookup and nothing else.
"""
from __future__ import annotations

from typing import Callable

import torch

from fracture_gs.mpm.grid import BLOCK, WALL_CELLS, GridFields, GridGeometry, node_coords


def boundary_blocks(geometry: GridGeometry, wall_condition: str, ground_height: float | None,
                    device: torch.device) -> torch.Tensor:
    """(n_blocks,) bool: blocks holding a node the boundary pass can change (csrc apply_boundary:
    the wall band ``ijk < 3`` or ``ijk > cells − 3`` when there are walls, ``z <= ground``)."""
    ijk = node_coords(geometry, device)
    affected = torch.zeros(ijk.shape[0], dtype=torch.bool, device=device)
    if wall_condition != "none":
        cells = torch.tensor(geometry.cells, device=device)
        affected |= ((ijk < WALL_CELLS) | (ijk > cells - WALL_CELLS)).any(-1)
    if ground_height is not None:
        z = geometry.lower[2] + ijk[:, 2].double() * geometry.dx
        affected |= z <= ground_height + 0.5 * geometry.dx  # a superset: float32 z in the kernel
    return affected.view(geometry.n_blocks, BLOCK ** 3).any(-1)


class ExternalImpulse:
    """Running sum J of the impulse gravity and the boundaries gave the particles (float64)."""

    def __init__(self, geometry: GridGeometry, wall_condition: str, ground_height: float | None,
                 gravity: tuple[float, float, float], total_mass: float, device: torch.device) -> None:
        self.n_blocks = geometry.n_blocks
        self.nodes_per_grid = geometry.nodes_per_grid
        self.blocks = boundary_blocks(geometry, wall_condition, ground_height, device)
        self.any_blocks = bool(self.blocks.any())
        self.local = torch.arange(BLOCK ** 3, device=device)
        # kept on the solver's device: no host transfer per substep, only in state()
        self.gravity_per_second = torch.tensor(gravity, dtype=torch.float64, device=device) * float(total_mass)
        self.total = torch.zeros(3, dtype=torch.float64, device=device)

    def step(self, touched: torch.Tensor, grid: GridFields, dt: float,
             apply_boundaries: Callable[[], None]) -> None:
        """Runs ``apply_boundaries()`` (the substep's boundary pass on ``grid``) and adds this
        substep's gravity impulse M g dt and the momentum the boundary pass changed."""
        self.total += self.gravity_per_second * dt
        nodes = self._boundary_nodes(touched) if self.any_blocks else None
        if nodes is None:
            apply_boundaries()
            return
        mass = grid.mass.reshape(-1).index_select(0, nodes).double()
        velocity = grid.velocity.reshape(-1, 3)
        before = velocity.index_select(0, nodes).double()
        apply_boundaries()
        change = velocity.index_select(0, nodes).double() - before
        self.total += (mass[:, None] * change).sum(0)

    def add(self, impulse: torch.Tensor) -> None:
        """Adds an impulse given outside the grid's boundary pass (a rigid body's ground contact)."""
        self.total += impulse.to(self.total)

    def _boundary_nodes(self, touched: torch.Tensor) -> torch.Tensor | None:
        """Storage indices of the nodes of the touched blocks that hold boundary nodes."""
        touched = touched.long()
        blocks = touched[self.blocks[touched % self.n_blocks]]
        if blocks.numel() == 0:
            return None
        first = (blocks // self.n_blocks) * self.nodes_per_grid + (blocks % self.n_blocks) * BLOCK ** 3
        return (first[:, None] + self.local[None, :]).reshape(-1)

    def state(self) -> list[float]:
        return [float(v) for v in self.total.cpu()]

    def load(self, values: list[float] | None) -> None:
        self.total = torch.tensor(values if values is not None else [0.0, 0.0, 0.0],
                                  dtype=torch.float64, device=self.total.device)
