"""A body in free flight through the float32 transfers, shared by ``benchmarks/momentum_drift.py`` and
the tests: only gravity (if any) acts on it, so its momentum must change by gravity's impulse alone,
to the rounding of P2G, the grid update and G2P.

An elastic sphere (radius 0.1 m at (0.5, 0.5, 0.7) in the unit cube, grid 64, 8 particles per cell,
E 20 MPa) moves with no walls or other body.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from fracture_gs.materials import ElasticMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import ContactSettings, Domain
from fracture_gs.testing.lattice import LatticeBody, lattice_sphere, particle_set

MATERIAL = ElasticMaterial(E=2e7, nu=0.3, density=1000.0)
GRID = 64


def flying_sphere(velocity: tuple[float, float, float], jitter: bool, backend: str,
                  gravity: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> CollisionMPM:
    """The sphere moving at ``velocity`` (m/s) under ``gravity`` (m/s²); ``jitter`` scales its particle
    masses by up to 1 %."""
    domain = Domain((0, 0, 0), (1, 1, 1), GRID)
    spacing = domain.dx / 2
    particles = particle_set([LatticeBody(lattice_sphere((0.5, 0.5, 0.7), 0.1, spacing), velocity, 0, spacing)],
                             [MATERIAL.density])
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    if jitter:
        generator = torch.Generator().manual_seed(0)
        scale = 1.0 + 0.01 * torch.rand(len(particles.mass), generator=generator)
        particles = dataclasses.replace(particles, mass=particles.mass * scale)
    return CollisionMPM(particles, [MATERIAL], domain, contact=ContactSettings(mode="collision"), boundaries=[],
                        gravity=gravity, cfl=0.3, backend=backend)


def momentum_change(solver: CollisionMPM, steps: int) -> torch.Tensor:
    """Advance ``steps`` substeps; the change of the total momentum less the external impulse (gravity's:
    the sphere touches no boundary) over those substeps, float64 (3,), over the momentum's norm at the
    start, from the solver's own diagnostics."""
    start = solver.diagnostics()
    for _ in range(steps):
        solver.step(solver.stable_dt())
    end = solver.diagnostics()
    change = (end["momentum"] - start["momentum"]) - (np.asarray(end["external_impulse"])
                                                      - np.asarray(start["external_impulse"]))
    return torch.from_numpy(change / np.linalg.norm(start["momentum"]))
