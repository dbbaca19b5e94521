"""Regular-lattice particle bodies for physics tests and benchmarks.

A body is a set of particles on a cubic lattice (spacing ``dx / ppc_edge``) inside a box or a
sphere; every particle gets the same rest volume (spacing³). Scenes built from YAML use the
jittered sampler of :mod:`fracture_gs.mpm.scene`; these exact lattices make tests repeatable and
geometric facts (gaps, contact planes) exact.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from fracture_gs.mpm.types import ParticleSet


@dataclass
class LatticeBody:
    """One object: particle positions, its velocity and the index of its material."""

    positions: torch.Tensor   # (n,3)
    velocity: tuple[float, float, float]
    material_index: int
    spacing: float


def lattice_box(center: Sequence[float], size: Sequence[float], spacing: float) -> torch.Tensor:
    """Lattice points filling an axis-aligned box (cell-centred, so the box is covered evenly)."""
    axes = []
    for c, s in zip(center, size):
        count = max(1, int(round(s / spacing)))
        axes.append(c - 0.5 * s + spacing * (torch.arange(count, dtype=torch.float64) + 0.5))
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return grid.float()


def lattice_sphere(center: Sequence[float], radius: float, spacing: float) -> torch.Tensor:
    """Lattice points inside a ball."""
    box = lattice_box(center, [2 * radius] * 3, spacing)
    inside = (box.double() - torch.tensor(center, dtype=torch.float64)).norm(dim=1) <= radius
    return box[inside]


def particle_set(bodies: Sequence[LatticeBody], densities: Sequence[float]) -> ParticleSet:
    """Concatenate bodies into a ParticleSet (object id = body index, mass = density · spacing³)."""
    xs, vs, masses, volumes, obj, mat = [], [], [], [], [], []
    for index, body in enumerate(bodies):
        n = body.positions.shape[0]
        volume = body.spacing ** 3
        xs.append(body.positions)
        vs.append(torch.tensor(body.velocity, dtype=torch.float32).expand(n, 3))
        volumes.append(torch.full((n,), volume))
        masses.append(torch.full((n,), densities[body.material_index] * volume))
        obj.append(torch.full((n,), index, dtype=torch.int32))
        mat.append(torch.full((n,), body.material_index, dtype=torch.int32))
    n_total = sum(b.positions.shape[0] for b in bodies)
    return ParticleSet(
        x=torch.cat(xs).contiguous(), v=torch.cat(vs).contiguous(), mass=torch.cat(masses),
        rest_volume=torch.cat(volumes), obj_id=torch.cat(obj), part_id=torch.zeros(n_total, dtype=torch.int32),
        material_id=torch.cat(mat), is_surface=torch.zeros(n_total, dtype=torch.bool),
        gaussian_index=torch.full((n_total,), -1, dtype=torch.int64))
