"""How densely an object's particles fill the scene's grid cells, and the warning where they are
denser than the solver is built for.

The solver is built for about ``DESIGN_PARTICLES_PER_CELL`` particles per cell (two per cell along
each axis): the brittle crack band is calibrated for that spacing (docs/formulas.md, "Why the band
spends G_f"), and the grid resolves nothing finer, so more particles only cost time (every substep
is linear in the particle count). A trained object's sampling does not know the scene's grid: the
same model on a coarse grid can put hundreds of particles in a cell.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fracture_gs.config.scene import Domain, ObjectConfig

DESIGN_PARTICLES_PER_CELL = 8
# Above this many particles per cell (four per cell along each axis) simulate.py warns.
MAX_PARTICLES_PER_CELL = 64


def particles_per_cell(x: np.ndarray, lower: Sequence[float], dx: float) -> float:
    """How many particles the typical particle of ``x`` (n, 3) shares its grid cell with (itself
    included): the particle-weighted mean of the occupied cells' counts, Σ c² / Σ c. Unlike the
    plain mean over occupied cells it is not lowered by the sparse cells along the surface."""
    if len(x) == 0:
        return 0.0
    cell = np.floor((np.asarray(x, np.float64) - np.asarray(lower, np.float64)) / dx).astype(np.int64)
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    key = (cell[:, 0] * span[1] + cell[:, 1]) * span[2] + cell[:, 2]
    counts = np.unique(key, return_counts=True)[1].astype(np.float64)
    return float((counts * counts).sum() / counts.sum())


def grid_for_density(grid: int, per_cell: float, target: float) -> int:
    """The grid (cells along the domain's x) at which ``per_cell`` particles per cell of a grid of
    ``grid`` cells become about ``target``: a count per cell scales with the cell volume."""
    return int(math.ceil(grid * (per_cell / target) ** (1.0 / 3.0)))


def density_warning(name: str, per_cell: float, grid: int, is_primitive: bool) -> str | None:
    """The warning line for an object with ``per_cell`` particles per cell on a grid of ``grid``
    cells, with the remedies; None within ``MAX_PARTICLES_PER_CELL``."""
    if per_cell <= MAX_PARTICLES_PER_CELL:
        return None
    fewer = ("a smaller particles_per_cell" if is_primitive else
             "a coarser sampling (train.py --particle-res, --nv or --n-surface)")
    return (f"object '{name}' puts {per_cell:.0f} particles in a cell of this {grid}-cell grid; the "
            f"solver is built for about {DESIGN_PARTICLES_PER_CELL} (at most {MAX_PARTICLES_PER_CELL}): "
            f"more cost time without resolving more, and brittle cracks spend a fracture energy "
            f"calibrated for {DESIGN_PARTICLES_PER_CELL} per cell. Use a finer grid (domain.grid >= "
            f"{grid_for_density(grid, per_cell, MAX_PARTICLES_PER_CELL)}) or {fewer}")


def density_warnings(objects: Sequence[ObjectConfig], positions: Sequence[np.ndarray], domain: Domain) -> list[str]:
    """One warning line per object (``positions``: its world-frame particles) denser than
    ``MAX_PARTICLES_PER_CELL`` on the cells of ``domain``."""
    lines = []
    for obj, x in zip(objects, positions):
        line = density_warning(obj.name, particles_per_cell(x, domain.lower, domain.dx), domain.grid,
                               obj.primitive is not None)
        if line is not None:
            lines.append(line)
    return lines
