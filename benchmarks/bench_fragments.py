"""Block drops and bars with crack opening inside objects (docs/simulation.md), printed as JSON.

    python benchmarks/bench_fragments.py [--duration 0.3] [--grid 64] [--only block_weak_6 ...]

1. Block drops (0.2 m cube, 8 particles per cell, on the ground): a weak block
   (E = 1e4, ρ = 100, α0 = −0.01) at 6 and 12 m/s and the tests' setting (E = 1e5, ρ = 1000,
   β = 0.3, 3.5 m/s), each with ``fragments`` true and false; the tests' block with E and ρ divided
   by 10 (same E/ρ, same dynamics), the weak block with α0 = −5 and an elastic block, with fragments. Reported: fractured share, the pieces (connected components
   linking particles closer than 1.5 x their spacing) with >= 2 % of the particles and their
   sizes, the largest pieces, the energy peak relative to the start, and the pieces (>= 2 %) that
   the never-fractured particles form when linked only to each other (one such piece: unbroken
   material spans the block).
2. Momentum: two NACC spheres colliding without gravity or walls, fragments on.
3. A pre-cracked bar (α0 = 0.5 on the middle slab) pulled apart at ±1 m/s: the gap between the
   halves, fragments true and false.

``--speed-factors 0.98 0.99 1 1.01 1.02`` runs the chosen block scenes (``--only``) at these
multiples of their drop speed instead, fragments on, to show how much the piece count depends on
the exact speed (the weak block's small corner pieces at 6 m/s sit near the 2 % line).
``--speeds 3.5 3.9 4.0 4.2`` runs the chosen block scenes at these speeds (m/s) with each of their
``fragments`` settings, to find the speed from which a block breaks apart with and without the
partition. ``--jitter-seeds 0 1 2`` samples the blocks as a YAML scene's box primitive is sampled
(jittered, 16,751 particles at grid 64) with each seed, instead of as a
lattice; ``--ground-friction 0.5`` sets the ground's friction (a YAML ground's default).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from fracture_gs.mpm.fragments import fragment_ids, fragment_sizes
from fracture_gs.mpm.types import SPLIT_GRADIENT_CELLS
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root
from fracture_gs.testing.fragment_scenes import block_drop, colliding_spheres, precracked_bar  # noqa: E402

PIECE_SHARE = 0.02  # pieces of >= 2 % of the particles count

BLOCKS = {  # name: (speed, E, density, alpha0 (None: elastic), beta, fragments settings)
    "block_weak_6": (6.0, 1e4, 100.0, -0.01, 0.5, (True, False)),
    "block_weak_12": (12.0, 1e4, 100.0, -0.01, 0.5, (True, False)),
    "block_test_3.5": (3.5, 1e5, 1000.0, -0.01, 0.3, (True, False)),
    # The tests' block with E and ρ both divided by 10 (the weak block's E and ρ): the same E/ρ, so
    # the same dynamics up to rounding; it shows the tests' block is the weak block with β = 0.3.
    "block_test_tenth_3.5": (3.5, 1e4, 100.0, -0.01, 0.3, (True,)),
    "block_strong_6": (6.0, 1e4, 100.0, -5.0, 0.5, (True,)),
    "block_elastic_6": (6.0, 1e4, 100.0, None, 0.5, (True,)),
}


def run(solver, duration: float, samples: int = 30) -> dict:
    """Advance ``duration`` in ``samples`` pieces; energy peak, wall time, split particle-steps."""
    start_energy = solver.diagnostics()["total_energy"]
    peak, split, steps = start_energy, 0, 0
    tick = time.perf_counter()
    for _ in range(samples):
        end = solver.state.time + duration / samples
        while end - solver.state.time > 1e-12:
            solver.step(min(solver.stable_dt(), end - solver.state.time))
            split += solver.last_split_particles
            steps += 1
        peak = max(peak, solver.diagnostics()["total_energy"])
    return {"seconds": round(time.perf_counter() - tick, 1), "steps": steps,
            "energy_peak_over_start": round(peak / start_energy, 5),
            "split_particle_steps": split}


def block_result(name: str, fragments: bool, grid: int, duration: float, speed_factor: float = 1.0,
                 jitter_seed: int | None = None, ground_friction: float = 0.3,
                 split_gradient: float = SPLIT_GRADIENT_CELLS) -> dict:
    """One block drop of scene ``name`` at ``speed_factor`` times its speed (a lattice block, or
    sampled as a YAML box primitive with ``jitter_seed``), the partition splitting nodes from
    ``split_gradient`` (1/cells)."""
    scene_speed, E, density, alpha0, beta, _ = BLOCKS[name]
    speed = speed_factor * scene_speed
    solver = block_drop(speed, E=E, density=density, alpha0=alpha0, beta=beta, grid=grid, fragments=fragments,
                        jitter_seed=jitter_seed, ground_friction=ground_friction, split_gradient=split_gradient)
    out = run(solver, duration)
    sizes = fragment_sizes(solver.fragment_ids())
    n = len(solver.particles)
    pieces = [s for s in sizes if s >= PIECE_SHARE * n]
    # The never-fractured particles, linked only to each other: if they alone form one piece,
    # unbroken material spans the block and no crack opening can free a piece of it.
    state = solver.state_in_input_order()
    intact = ~state.fractured
    intact_sizes = fragment_sizes(fragment_ids(state.x[intact], solver.input_particles.obj_id[intact],
                                               solver.fragment_radius)) if bool(intact.any()) else []
    out.update(scene=name, fragments=fragments, particles=n,
               sampling="lattice" if jitter_seed is None else f"jittered, seed {jitter_seed}",
               ground_friction=ground_friction, split_gradient=split_gradient, speed=round(speed, 6), E=E,
               density=density, alpha0=alpha0, beta=beta,
               fractured=round(float(solver.state.fractured.float().mean()), 4),
               pieces_2pct=len(pieces), piece_sizes_2pct=pieces, largest_pieces=sizes[:8],
               components=len(sizes), fragments_1pct=int(solver.diagnostics()["fragments"]),
               intact_pieces_2pct=[s for s in intact_sizes if s >= PIECE_SHARE * n])
    return out


def momentum_result(duration: float) -> dict:
    solver = colliding_spheres(grid=32, fragments=True)
    p0 = solver.diagnostics()["momentum"]
    out = run(solver, duration)
    drift = float(np.linalg.norm(solver.diagnostics()["momentum"] - p0) / np.linalg.norm(p0))
    out.update(scene="two_nacc_spheres_no_gravity", fragments=True, relative_momentum_drift=drift,
               fractured=round(float(solver.state.fractured.float().mean()), 4))
    return out


def bar_result(fragments: bool, grid: int, duration: float) -> dict:
    solver, half = precracked_bar(grid=grid, fragments=fragments)
    out = run(solver, duration)
    x = solver.state_in_input_order().x.numpy()
    gap = float(cKDTree(x[half.numpy() > 0]).query(x[half.numpy() < 0])[0].min())
    out.update(scene="precracked_bar", fragments=fragments, gap_dx=round(gap / solver.geometry.dx, 3),
               particles=len(solver.particles))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.15, help="simulated seconds of each block drop")
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--only", nargs="*", default=None,
                        help="scene names to run (block names, 'momentum', 'bar'); default all")
    parser.add_argument("--speed-factors", type=float, nargs="+", default=None,
                        help="run the block scenes of --only at these multiples of their speed, fragments on")
    parser.add_argument("--speeds", type=float, nargs="+", default=None,
                        help="run the block scenes of --only at these speeds (m/s), fragments true and false")
    parser.add_argument("--jitter-seeds", type=int, nargs="+", default=None,
                        help="sample the blocks as a YAML scene's box primitive (jittered) with each of these "
                             "seeds instead of as a lattice")
    parser.add_argument("--ground-friction", type=float, default=0.3,
                        help="friction of the ground under the blocks (the scenes' 0.3; a YAML ground's default is 0.5)")
    parser.add_argument("--split-gradient", type=float, default=SPLIT_GRADIENT_CELLS,
                        help=f"the blocks' split threshold, ContactSettings.split_gradient in 1/cells "
                             f"(default {SPLIT_GRADIENT_CELLS})")
    args = parser.parse_args()
    if args.speed_factors and args.speeds:
        parser.error("give --speed-factors or --speeds, not both")
    if any(v <= 0 for v in (args.speed_factors or []) + (args.speeds or [])):
        parser.error("speeds and speed factors must be > 0")
    if any(seed < 0 for seed in args.jitter_seeds or []):
        parser.error("--jitter-seeds must be >= 0")
    if not args.ground_friction >= 0:
        parser.error("--ground-friction must be >= 0")
    if not 0 < args.split_gradient < float("inf"):
        parser.error("--split-gradient must be a finite number > 0")
    seeds = args.jitter_seeds if args.jitter_seeds else [None]
    torch.set_num_threads(max(1, torch.get_num_threads()))
    wanted = set(args.only) if args.only else set(BLOCKS) | {"momentum", "bar"}
    results = []

    def record(result: dict) -> None:  # one line per finished run, so a long sweep shows progress
        results.append(result)
        print(json.dumps(result), file=sys.stderr, flush=True)

    for name, (*_, settings) in BLOCKS.items():
        if name not in wanted:
            continue
        if args.speed_factors:  # (fragments, speed factor) of each run
            runs = [(True, factor) for factor in args.speed_factors]
        elif args.speeds:
            runs = [(fragments, speed / BLOCKS[name][0]) for speed in args.speeds for fragments in settings]
        else:
            runs = [(fragments, 1.0) for fragments in settings]
        for seed in seeds:
            for fragments, factor in runs:
                record(block_result(name, fragments, args.grid, args.duration, factor, seed, args.ground_friction,
                                    args.split_gradient))
    sweep = bool(args.speed_factors or args.speeds)
    if "bar" in wanted and not sweep:
        for fragments in (True, False):
            record(bar_result(fragments, args.grid, 0.1))
    if "momentum" in wanted and not sweep:
        record(momentum_result(0.2))
    print(json.dumps({"benchmark": "fragments_acceptance", "grid": args.grid, "block_duration_s": args.duration,
                      "results": results}, indent=2))


if __name__ == "__main__":
    main()
