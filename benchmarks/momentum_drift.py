"""Momentum of a body in free flight through the float32 transfers (prints JSON).

An elastic sphere (radius 0.1 m, grid 64, 8 particles per cell, E 20 MPa) moves with no walls or
other body, without gravity and falling (g = 9.8 m/s² along -z), so its momentum must change by
gravity's impulse alone. Per run (each --velocities entry, each backend, particle masses equal or
jittered by 1 %, gravity off and on) the JSON gives the change of the total momentum less gravity's
impulse per substep over --steps substeps, relative to the momentum's size: the rounding of the
float32 P2G, grid update and G2P, which should average out.

    python benchmarks/momentum_drift.py [--steps 400] [--backends cpp reference]
"""
from __future__ import annotations

import argparse
import json

import torch

from fracture_gs._backend import compiled_module
from fracture_gs.testing.free_flight import GRID, flying_sphere, momentum_change


def run(velocity: tuple[float, float, float], jitter: bool, backend: str, steps: int, gravity: float) -> dict:
    solver = flying_sphere(velocity, jitter, backend, gravity=(0.0, 0.0, -gravity))
    start = solver.state.v[0].double()  # every particle starts at the same velocity
    change = momentum_change(solver, steps) / steps
    along = float(change @ (start / torch.linalg.vector_norm(start)))
    return {"velocity": list(velocity), "gravity": [0.0, 0.0, -gravity],
            "masses": "jittered 1 %" if jitter else "equal", "backend": backend,
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
    runs = [run(velocity, jitter, backend, args.steps, gravity)
            for backend in args.backends for gravity in (0.0, 9.8) for jitter in (False, True) for velocity in velocities]
    print(json.dumps({"benchmark": "momentum_drift", "grid": GRID, "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
