"""Full Collision-MPM step throughput: compiled backend vs the torch reference (prints JSON).

Scene: two spheres already in contact and driven into each other, so the contact pass and the
material update both really run. The step is bins + P2G + grid update + contact + boundaries +
G2P with the material update; the particles are in simulate.py's order and the solver's periodic
re-sort (every 50 substeps) is part of the timed steps. The compiled backend runs three times:
NACC spheres and brittle spheres (which crack where they press into each other), each without and
with ``contact.fragments`` (crack opening inside objects). The JSON gives each and the
ratios ``fragment_cost`` (NACC with fragments / without) and ``brittle_cost`` (brittle with
fragments / NACC with fragments), with the share of particles that were fractured and that read a
split node while timed.

    python benchmarks/bench_mpm.py [--grid 128] [--particles 50000 200000] [--device cpu]

The compiled backend is timed in --repeats blocks of --steps steps; the JSON gives the median
block (ms_per_step, particle_steps_per_s) and the slowest and fastest block, because a shared
machine's speed drifts between seconds. The solvers without and with fragments take turns, one
block each per round, so that such a drift does not fall on one of them only; fragment_cost gives
the ratio of their medians and the median and range of the per-round ratios.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import torch

from fracture_gs._backend import compiled_module
from fracture_gs.materials import BrittleMaterial, NACCMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import BoxBoundary, ContactSettings, Domain

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root
from fracture_gs.testing.lattice import LatticeBody, lattice_sphere, particle_set  # noqa: E402


MATERIALS = {
    "nacc": NACCMaterial(E=2e5, nu=0.3, density=1e3, alpha0=-0.01, beta=0.3, xi=1.0, M=2.36),
    # Impact stress rho c v ~ 5 times the strength at the spheres' 6 m/s: they crack where they meet.
    "brittle": BrittleMaterial(E=2e5, nu=0.3, density=1e3, strength=1e4, fracture_energy=5.0, weibull_m=6.0),
}


def two_spheres(n_total: int, grid: int, device: torch.device, backend: str, fragments: bool = False,
                material_name: str = "nacc") -> CollisionMPM:
    """Two touching spheres of one material with ~n_total particles, spacing dx/2, approaching at 6 m/s."""
    domain = Domain((0, 0, 0), (1, 1, 1), grid)
    spacing = domain.dx / 2
    radius = spacing * (3 * (n_total / 2) / (4 * math.pi)) ** (1 / 3)
    bodies = [LatticeBody(lattice_sphere((0.5 - radius - spacing / 2, 0.5, 0.5), radius, spacing), (3, 0, 0), 0,
                          spacing),
              LatticeBody(lattice_sphere((0.5 + radius + spacing / 2, 0.5, 0.5), radius, spacing), (-3, 0, 0), 0,
                          spacing)]
    material = MATERIALS[material_name]
    particles = particle_set(bodies, [material.density])
    # The order simulate.py runs with (build_scene): each grid block's particles together.
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    return CollisionMPM(particles, [material], domain,
                        contact=ContactSettings(mode="collision", fragments=fragments),
                        boundaries=[BoxBoundary("slip")],
                        gravity=(0, 0, -9.8), cfl=0.3, backend=backend, device=device)


def timed_block(solver: CollisionMPM, steps: int, split_masks: list) -> float:
    """Seconds per step of one block of ``steps`` steps (split masks kept for after the timing)."""
    if solver.device.type == "cuda":
        torch.cuda.synchronize()
    start = time.perf_counter()
    for _ in range(steps):
        solver.step(solver.stable_dt())
        split_masks.append(solver.last_split_mask)  # counted after the timing
    if solver.device.type == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - start) / steps


def measure(solvers: list[CollisionMPM], steps: int, repeats: int) -> list[tuple[list[float], float]]:
    """Per solver: seconds per step of ``repeats`` blocks of ``steps`` steps, after one warm-up step,
    and the mean share of particles that read a split node (fragments). The solvers take turns,
    one block each per round, so that a drift of the machine's speed (seconds long on a shared
    machine) falls on all of them alike instead of on whichever ran last."""
    for solver in solvers:
        solver.step(solver.stable_dt())
    seconds = [[] for _ in solvers]
    split_masks = [[] for _ in solvers]
    for _ in range(repeats):
        for i, solver in enumerate(solvers):
            seconds[i].append(timed_block(solver, steps, split_masks[i]))
    out = []
    for solver, blocks, masks in zip(solvers, seconds, split_masks):
        split = sum(int(mask.sum()) for mask in masks if mask is not None)
        out.append((blocks, split / (steps * repeats * max(len(solver.particles), 1))))
    return out


def result_row(solver: CollisionMPM, backend: str, material: str, fragments: bool, steps: int, repeats: int,
               blocks: list[float], split_share: float, alpha_start: torch.Tensor) -> dict:
    """One JSON row: the median block and the range of the blocks."""
    seconds = statistics.median(blocks)
    n_particles = len(solver.particles)
    return {
        "backend": backend, "material": material, "fragments": fragments, "particles": n_particles, "steps": steps,
        "repeats": repeats,
        "ms_per_step": round(1e3 * seconds, 3),
        "particle_steps_per_s": round(n_particles / seconds),
        "particle_steps_per_s_range": [round(n_particles / max(blocks)), round(n_particles / min(blocks))],
        "plastic_fraction_during_timing": round(float((solver.state.alpha != alpha_start).float().mean()), 4),
        "fractured_fraction": round(float(solver.state.fractured.float().mean()), 4),
        "split_particle_fraction": round(split_share, 4),
        "contact_blocks": int(len(solver.last_bins.contact_blocks)) if solver.last_bins else None,
    }


def run_timed(n: int, args: argparse.Namespace, device: torch.device,
              configs: list[tuple[str, str, bool, int, int]]) -> list[tuple[dict, list[float]]]:
    """Builds one solver per (backend, material, fragments, steps, repeats), lets the spheres press
    into each other (contact and the material update active), and times them; solvers with the same
    steps and repeats take turns (measure). Returns (JSON row, block seconds) per config."""
    rows: list[tuple[dict, list[float]]] = []
    groups: dict[tuple[int, int], list[tuple[str, str, bool]]] = {}
    for backend, material, fragments, steps, repeats in configs:
        groups.setdefault((steps, repeats), []).append((backend, material, fragments))
    for (steps, repeats), members in groups.items():
        solvers, alpha_starts = [], []
        for backend, material, fragments in members:
            solver = two_spheres(n, args.grid, device, backend, fragments, material)
            for _ in range(5 if backend == "reference" else 40):
                solver.step(solver.stable_dt())
            solvers.append(solver)
            alpha_starts.append(solver.state.alpha.clone())
        for (backend, material, fragments), solver, alpha_start, (blocks, split_share) in zip(
                members, solvers, alpha_starts, measure(solvers, steps, repeats)):
            rows.append((result_row(solver, backend, material, fragments, steps, repeats, blocks, split_share,
                                    alpha_start), blocks))
    return rows


def ratio_entry(particles: int, slower: list[float], faster: list[float]) -> dict:
    """The ratio of the medians of two solvers' blocks, and the median and range of the per-round ratios
    (the blocks of a round ran back to back, at nearly the same speed of the machine)."""
    rounds = [a / b for a, b in zip(slower, faster)]
    return {"particles": particles, "ratio": round(statistics.median(slower) / statistics.median(faster), 3),
            "round_ratio_median": round(statistics.median(rounds), 3),
            "round_ratio_range": [round(min(rounds), 3), round(max(rounds), 3)]}


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
    results, cost, brittle_cost = [], [], []
    for n in args.particles:
        configs = [] if compiled_module() is None else [("cpp", material, fragments, args.steps, args.repeats)
                                                         for material in ("nacc", "brittle")
                                                         for fragments in (False, True)]
        if not args.skip_reference:
            configs.append(("reference", "nacc", False, args.reference_steps, 1))
        rows = run_timed(n, args, device, configs)
        results += [row for row, _ in rows]
        compiled = {(row["material"], row["fragments"]): blocks for row, blocks in rows if row["backend"] == "cpp"}
        if len(compiled) == 4:
            particles = rows[0][0]["particles"]
            cost.append(ratio_entry(particles, compiled[("nacc", True)], compiled[("nacc", False)]))
            brittle_cost.append(ratio_entry(particles, compiled[("brittle", True)], compiled[("nacc", True)]))
    print(json.dumps({
        "benchmark": "mpm_full_step", "grid": args.grid, "device": str(device),
        "threads": int(compiled_module().openmp_max_threads()) if compiled_module() else 1,
        "torch_threads": torch.get_num_threads(), "results": results,
        # ms per step of NACC with fragments / without, and of brittle with fragments / NACC with them.
        "fragment_cost": cost, "brittle_cost": brittle_cost}, indent=2))


if __name__ == "__main__":
    main()
