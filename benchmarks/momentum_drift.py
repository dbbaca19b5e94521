"""Momentum of a body in free flight through the float32 transfers (prints JSON).

An elastic sphere (radius 0.1 m, grid 64, 8 particles per cell, E 20 MPa) translates at a constant
velocity with no gravity, walls or other body, so its momentum must not change. Per run (each
--velocities entry, each backend, particle masses equal or jittered by 1 %) the JSON gives the
change of the total momentum per substep over --steps substeps, relative to its size: the
rounding of the float32 P2G and G2P, which should average out and does not quite.

    python benchmarks/momentum_drift.py [--steps 400] [--backends cpp reference]
"""
from __future__ import annotations

import argparse
import dataclasses
import json

import torch

from fracture_gs._backend import compiled_module
from fracture_gs.materials import ElasticMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import ContactSettings, Domain
from fracture_gs.testing.lattice import LatticeBody, lattice_sphere, particle_set

MATERIAL = ElasticMaterial(E=2e7, nu=0.3, density=1000.0)


def sphere(velocity: tuple[float, float, float], jitter: bool, backend: str) -> CollisionMPM:
    """The sphere at (0.5, 0.5, 0.7) in the unit cube, moving at ``velocity``."""
    domain = Domain((0, 0, 0), (1, 1, 1), 64)
    spacing = domain.dx / 2
    particles = particle_set([LatticeBody(lattice_sphere((0.5, 0.5, 0.7), 0.1, spacing), velocity, 0, spacing)],
                             [MATERIAL.density])
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    if jitter:
        generator = torch.Generator().manual_seed(0)
        scale = 1.0 + 0.01 * torch.rand(len(particles.mass), generator=generator)
        particles = dataclasses.replace(particles, mass=particles.mass * scale)
    return CollisionMPM(particles, [MATERIAL], domain, contact=ContactSettings(mode="collision"), boundaries=[],
                        gravity=(0, 0, 0), cfl=0.3, backend=backend)


def run(velocity: tuple[float, float, float], jitter: bool, backend: str, steps: int) -> dict:
    solver = sphere(velocity, jitter, backend)
    mass = solver.particles.mass.double()[:, None]
    start = (mass * solver.state.v.double()).sum(0)
    for _ in range(steps):
        solver.step(solver.stable_dt())
    end = (mass * solver.state.v.double()).sum(0)
    change = (end - start) / float(torch.linalg.vector_norm(start)) / steps
    along = float(change @ (start / torch.linalg.vector_norm(start)))
    return {"velocity": list(velocity), "masses": "jittered 1 %" if jitter else "equal", "backend": backend,
            "particles": len(solver.particles), "steps": steps,
            "relative_change_per_step": [float(c) for c in change],
            "relative_change_along_motion_per_step": along}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--backends", nargs="+", default=["cpp", "reference"], choices=["cpp", "reference"])
    parser.add_argument("--velocities", type=float, nargs="+", default=[0, 0, -10, 0, 0, 10, 7, 0, -7],
                        help="velocities as x y z triples (m/s)")
    args = parser.parse_args()
    if len(args.velocities) % 3 or args.steps < 1:
        parser.error("--velocities takes x y z triples and --steps must be >= 1")
    if "cpp" in args.backends and compiled_module() is None:
        parser.error("the compiled extension fracture_gs._C is not built (bash install.sh)")
    torch.set_grad_enabled(False)
    velocities = [tuple(args.velocities[i:i + 3]) for i in range(0, len(args.velocities), 3)]
    runs = [run(velocity, jitter, backend, args.steps)
            for backend in args.backends for jitter in (False, True) for velocity in velocities]
    print(json.dumps({"benchmark": "momentum_drift", "grid": 64, "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
