"""Full Collision-MPM step throughput: compiled backend vs the torch reference (prints JSON).

Scene: two NACC spheres already in contact and driven into each other, so the contact pass and
the plastic projection both really run. The step is bins + P2G + grid update + contact +
boundaries + G2P with the NACC return map; the particles are in simulate.py's order and the
solver's periodic re-sort (every 50 substeps) is part of the timed steps. The compiled backend
runs twice, without and with ``contact.fragments`` (crack opening inside objects, issue 14): the
JSON gives both and their ratio (``fragment_cost``), with the share of particles that were
fractured and that read a split node while timed.

    python benchmarks/bench_mpm.py [--grid 128] [--particles 50000 200000] [--device cpu]

The compiled backend is timed in --repeats consecutive blocks of --steps steps; the JSON gives the
median block (ms_per_step, particle_steps_per_s) and the slowest and fastest block, because a
shared machine's speed drifts between seconds.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import torch

from fracture_gs._backend import compiled_module
from fracture_gs.mpm.lattice import LatticeBody, lattice_sphere, particle_set
from fracture_gs.mpm.materials import NACCMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import BoxBoundary, ContactSettings, Domain


def two_spheres(n_total: int, grid: int, device: torch.device, backend: str, fragments: bool = False) -> CollisionMPM:
    """Two touching NACC spheres with ~n_total particles, spacing dx/2, approaching at 6 m/s."""
    domain = Domain((0, 0, 0), (1, 1, 1), grid)
    spacing = domain.dx / 2
    radius = spacing * (3 * (n_total / 2) / (4 * math.pi)) ** (1 / 3)
    bodies = [LatticeBody(lattice_sphere((0.5 - radius - spacing / 2, 0.5, 0.5), radius, spacing), (3, 0, 0), 0,
                          spacing),
              LatticeBody(lattice_sphere((0.5 + radius + spacing / 2, 0.5, 0.5), radius, spacing), (-3, 0, 0), 0,
                          spacing)]
    material = NACCMaterial(E=2e5, nu=0.3, density=1e3, alpha0=-0.01, beta=0.3, xi=1.0, M=2.36)
    particles = particle_set(bodies, [material.density])
    # The order simulate.py runs with (build_scene): each grid block's particles together.
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    return CollisionMPM(particles, [material], domain,
                        contact=ContactSettings(mode="collision", fragments=fragments),
                        boundaries=[BoxBoundary("slip")],
                        gravity=(0, 0, -9.8), cfl=0.3, backend=backend, device=device)


def measure(solver: CollisionMPM, steps: int, repeats: int) -> tuple[list[float], float]:
    """Seconds per step of ``repeats`` consecutive blocks of ``steps`` steps, after one warm-up step,
    and the mean share of particles that read a split node (fragments)."""
    solver.step(solver.stable_dt())
    seconds, split_masks = [], []
    for _ in range(repeats):
        if solver.device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        for _ in range(steps):
            solver.step(solver.stable_dt())
            split_masks.append(solver.last_split_mask)  # counted after the timing
        if solver.device.type == "cuda":
            torch.cuda.synchronize()
        seconds.append((time.perf_counter() - start) / steps)
    split = sum(int(mask.sum()) for mask in split_masks if mask is not None)
    return seconds, split / (steps * repeats * max(len(solver.particles), 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--particles", type=int, nargs="+", default=[50_000, 200_000])
    parser.add_argument("--steps", type=int, default=30, help="steps per timed block, compiled backend")
    parser.add_argument("--repeats", type=int, default=5,
                        help="timed blocks of the compiled backend; the median block is reported")
    parser.add_argument("--reference-steps", type=int, default=2, help="timed steps of the torch reference")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--skip-reference", action="store_true", help="time the compiled backend only")
    args = parser.parse_args()
    device = torch.device(args.device)
    results = []
    cost = []
    for n in args.particles:
        runs = (("cpp", False, args.steps, args.repeats), ("cpp", True, args.steps, args.repeats)) + (
            () if args.skip_reference else (("reference", False, args.reference_steps, 1),))
        for backend, fragments, steps, repeats in runs:
            if backend == "cpp" and compiled_module() is None:
                continue
            solver = two_spheres(n, args.grid, device, backend, fragments)
            # Let the spheres press into each other so contact and plasticity are active.
            for _ in range(5 if backend == "reference" else 40):
                solver.step(solver.stable_dt())
            alpha_start = solver.state.alpha.clone()
            blocks, split_share = measure(solver, steps, repeats)
            seconds = statistics.median(blocks)
            plastic = float((solver.state.alpha != alpha_start).float().mean())
            n_particles = len(solver.particles)
            if backend == "cpp":
                cost.append((n_particles, fragments, seconds))
            results.append({
                "backend": backend, "fragments": fragments, "particles": n_particles, "steps": steps,
                "repeats": repeats,
                "ms_per_step": round(1e3 * seconds, 3),
                "particle_steps_per_s": round(n_particles / seconds),
                "particle_steps_per_s_range": [round(n_particles / max(blocks)), round(n_particles / min(blocks))],
                "plastic_fraction_during_timing": round(plastic, 4),
                "fractured_fraction": round(float(solver.state.fractured.float().mean()), 4),
                "split_particle_fraction": round(split_share, 4),
                "contact_blocks": int(len(solver.last_bins.contact_blocks)) if solver.last_bins else None,
            })
    print(json.dumps({
        "benchmark": "mpm_full_step", "grid": args.grid, "device": str(device),
        "threads": int(compiled_module().openmp_max_threads()) if compiled_module() else 1,
        "torch_threads": torch.get_num_threads(), "results": results,
        # ms per step with fragments / without, per particle count (issue 14 asks <= 1.4).
        "fragment_cost": [{"particles": n, "ratio": round(on / off, 3)}
                          for (n, f_off, off), (_, f_on, on) in zip(cost[0::2], cost[1::2])]}, indent=2))


if __name__ == "__main__":
    main()
