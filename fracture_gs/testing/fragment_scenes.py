"""Lattice scenes of the crack-opening checks (docs/simulation.md), shared by tests and benchmarks.

* :func:`block_drop` — a NACC (or elastic) cube dropped onto the ground;
* :func:`precracked_bar` — a bar whose middle slab of particles is fractured from the start
  (α0 above the fracture threshold), its halves pulled apart;
* :func:`colliding_spheres` — two NACC spheres colliding without gravity or walls.

Sizes are parameters so that the tests run a small version and ``benchmarks/bench_fragments.py``
the full one.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from fracture_gs.config.scene import PrimitiveConfig

from fracture_gs.materials import MaterialModel, model_by_name
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.scene import sample_primitive
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import SPLIT_GRADIENT_CELLS, ContactSettings, Domain, GroundBoundary
from fracture_gs.testing.lattice import LatticeBody, lattice_box, lattice_sphere, particle_set

GROUND_HEIGHT = 0.1


def jittered_box(centre: Sequence[float], size: float, dx: float, seed: int) -> torch.Tensor:
    """A cube of edge ``size`` sampled as a YAML scene's box primitive with 8 particles per cell
    is (:func:`fracture_gs.mpm.scene.sample_primitive`: one particle at a uniform random place in
    each sub-cell of edge dx/2; the random stream of object 0 of a scene with ``seed``)."""
    primitive = PrimitiveConfig(shape="box", size=(size, size, size), particles_per_cell=8)
    local = sample_primitive(primitive, dx, 1.0, np.random.default_rng([seed, 0]))
    return torch.from_numpy(local.x + np.asarray(centre, np.float64)).float()


def soil(E: float, density: float, alpha0: float, beta: float) -> MaterialModel:
    """The NACC material of these scenes (ν 0.3, ξ 1, M 2.36); α0 may lie beyond a scene file's range
    (the precracked bar's strong halves)."""
    return model_by_name()["nacc"](E=E, nu=0.3, density=density, alpha0=alpha0, beta=beta, xi=1.0, M=2.36)


def block_drop(speed: float, *, E: float, density: float, alpha0: float | None, beta: float = 0.5,
               grid: int = 64, size: float = 0.2, fragments: bool = True, ground_friction: float = 0.3,
               backend: str = "auto", jitter_seed: int | None = None,
               split_gradient: float = SPLIT_GRADIENT_CELLS) -> CollisionMPM:
    """A cube of edge ``size`` (8 particles per cell) falling at ``speed`` onto the ground (its
    bottom face half a spacing above it), under gravity. ``alpha0=None``: an elastic block. The
    particles form a lattice, or with ``jitter_seed`` are sampled as a YAML scene with that
    ``seed`` samples a box primitive (:func:`jittered_box`). ``split_gradient``: the partition's
    split threshold (``ContactSettings.split_gradient``, 1/cells)."""
    domain = Domain((0, 0, 0), (1, 1, 1), grid)
    spacing = domain.dx / 2
    centre = (0.5, 0.5, GROUND_HEIGHT + size / 2 + spacing / 2)
    block = (lattice_box(centre, (size, size, size), spacing) if jitter_seed is None else
             jittered_box(centre, size, domain.dx, jitter_seed))
    material = (soil(E, density, alpha0, beta) if alpha0 is not None else
                model_by_name()["elastic"](E=E, nu=0.3, density=density))
    particles = particle_set([LatticeBody(block, (0.0, 0.0, -speed), 0, spacing)], [material.density])
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    return CollisionMPM(particles, [material], domain,
                        contact=ContactSettings(fragments=fragments, split_gradient=split_gradient),
                        boundaries=[GroundBoundary(height=GROUND_HEIGHT, friction=ground_friction)],
                        gravity=(0.0, 0.0, -9.8), backend=backend)


def precracked_bar(*, grid: int = 64, length: float = 0.4, width: float = 0.1, speed: float = 1.0,
                   fragments: bool = True, backend: str = "auto") -> tuple[CollisionMPM, torch.Tensor]:
    """A bar along x whose middle slab (one particle layer) starts fractured (α0 = 0.5 > 0, the
    threshold); the rest is strong NACC (α0 = −5). Halves move apart at ±speed, no gravity, no
    walls. Returns the solver and each particle's half (−1 left, +1 right, 0 the slab), in the
    solver's initial particle order. The length is rounded to an odd number of particle spacings,
    so that a lattice plane lies exactly on the bar's centre for every grid."""
    domain = Domain((0, 0, 0), (1, 1, 1), grid)
    spacing = domain.dx / 2
    centre = 0.5 + spacing / 2
    layers = 2 * max(1, round((length / spacing - 1) / 2)) + 1  # odd: the middle layer is the slab
    bar = lattice_box((centre, 0.5, 0.5), (layers * spacing, width, width), spacing)
    offset = bar[:, 0] - centre
    half = torch.where(offset.abs() < 0.25 * spacing, 0, torch.where(offset < 0, -1, 1)).to(torch.int32)
    strong = soil(1e5, 1e3, -5.0, 0.3)
    cracked = soil(1e5, 1e3, 0.5, 0.3)
    particles = particle_set([LatticeBody(bar, (0.0, 0.0, 0.0), 0, spacing)], [strong.density])
    velocity = torch.zeros_like(particles.v)
    velocity[:, 0] = speed * half.float()
    particles = dataclasses.replace(particles, v=velocity.contiguous(),
                                    material_id=(half == 0).to(torch.int32).contiguous())
    solver = CollisionMPM(particles, [strong, cracked], domain, contact=ContactSettings(fragments=fragments),
                          boundaries=[], gravity=(0.0, 0.0, 0.0), backend=backend, reorder_every=0)
    return solver, half


def colliding_spheres(*, grid: int = 32, radius: float = 0.12, fragments: bool = True,
                      backend: str = "auto") -> CollisionMPM:
    """Two weak NACC spheres (α0 = −0.01) colliding off-centre at 3 m/s relative, no gravity or walls."""
    domain = Domain((0, 0, 0), (1, 1, 1), grid)
    spacing = domain.dx / 2
    material = soil(2e4, 2.0, -0.01, 0.5)
    bodies = [LatticeBody(lattice_sphere((0.5 - radius - spacing, 0.5, 0.5), radius, spacing), (2.0, 0.0, 0.3), 0,
                          spacing),
              LatticeBody(lattice_sphere((0.5 + radius + spacing, 0.52, 0.5), radius, spacing), (-1.0, 0.2, 0.0), 0,
                          spacing)]
    return CollisionMPM(particle_set(bodies, [material.density]), [material], domain,
                        contact=ContactSettings(fragments=fragments), boundaries=[], gravity=(0.0, 0.0, 0.0),
                        backend=backend)
