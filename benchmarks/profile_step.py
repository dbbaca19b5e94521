"""Where the Collision-MPM step spends its time, kernel by kernel (prints JSON).

The scene is bench_mpm.py's: two spheres of one material pressed into each other at 6 m/s, in
simulate.py's particle order, after --warmup steps (40 by default: the spheres press into each other;
by 150 the brittle spheres have cracked through much of their volume, as in the late blocks of
bench_gaussianfluent.py). For every configuration (material NACC or brittle, cracks opening or not,
each particle count) it times --steps steps and splits each step
into the solver's calls of ``fracture_gs.mpm.ops`` (binning, P2G, the fragment passes, grid update,
contact, boundaries, G2P with the material update, ...); ``other`` is the rest of the step in
Python (the material's per-substep hook, the blow-up check, the periodic re-sort).

    python benchmarks/profile_step.py [--grid 128] [--particles 50000 200000] [--steps 20] [--warmup 40]

Each op is timed around its call (on CUDA with a synchronize before and after, which serialises
the stream: the sum is then a little above the unprofiled step). The JSON gives per configuration
the milliseconds per step of each op, its share of the step, and the share of particles fractured.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import json
import time
from collections import defaultdict
from collections.abc import Callable, Iterator

import torch

from bench_mpm import two_spheres
from fracture_gs._backend import compiled_module
from fracture_gs.mpm import ops
from fracture_gs.mpm.solver import CollisionMPM

# The ops the solver's step calls, in the order they run.
STEP_OPS = ("bin_particles", "p2g", "fragment_reference", "fragment_partition", "fragment_field_blocks",
            "grid_update", "collision", "boundaries", "g2p", "fragment_clear")


def synchronizer(device: torch.device) -> Callable[[], None]:
    """What waits for the device's queued work before a clock is read (nothing on the CPU)."""
    return torch.cuda.synchronize if device.type == "cuda" else (lambda: None)


@contextlib.contextmanager
def timed_ops(device: torch.device, seconds: dict[str, float]) -> Iterator[None]:
    """Within the block, every call of a ``STEP_OPS`` function adds its wall time to ``seconds[name]``."""
    sync = synchronizer(device)
    originals = {name: getattr(ops, name) for name in STEP_OPS}

    def timed(name: str, fn: Callable) -> Callable:
        @functools.wraps(fn)
        def call(*args, **kwargs):
            sync()
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                sync()
                seconds[name] += time.perf_counter() - start
        return call

    try:
        for name, fn in originals.items():
            setattr(ops, name, timed(name, fn))
        yield
    finally:
        for name, fn in originals.items():
            setattr(ops, name, fn)


def profile(solver: CollisionMPM, steps: int) -> dict:
    """Milliseconds per step of each op over ``steps`` steps of ``solver``, and the rest as ``other``."""
    seconds: dict[str, float] = defaultdict(float)
    sync = synchronizer(solver.device)
    with timed_ops(solver.device, seconds):
        sync()
        start = time.perf_counter()
        for _ in range(steps):
            solver.step(solver.stable_dt())
        sync()
        total = time.perf_counter() - start
    per_op = {name: seconds[name] for name in STEP_OPS if name in seconds}
    per_op["other"] = max(total - sum(per_op.values()), 0.0)
    return {
        "ms_per_step": round(1e3 * total / steps, 3),
        "ops_ms_per_step": {name: round(1e3 * value / steps, 3) for name, value in per_op.items()},
        "ops_share": {name: round(value / total, 4) for name, value in per_op.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--particles", type=int, nargs="+", default=[50_000, 200_000])
    parser.add_argument("--steps", type=int, default=20, help="profiled steps per configuration")
    parser.add_argument("--warmup", type=int, default=40, help="steps before the profiled ones")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    if args.warmup < 0 or args.steps < 1:
        parser.error("--warmup must be >= 0 and --steps >= 1")
    if compiled_module() is None:
        parser.error("the compiled extension fracture_gs._C is not built (bash install.sh)")
    device = torch.device(args.device)
    rows = []
    for n in args.particles:
        for material in ("nacc", "brittle"):
            for fragments in (False, True):
                solver = two_spheres(n, args.grid, device, "cpp", fragments, material)
                for _ in range(args.warmup):
                    solver.step(solver.stable_dt())
                row = {"material": material, "fragments": fragments, "particles": len(solver.particles),
                       "warmup": args.warmup, "steps": args.steps}
                row.update(profile(solver, args.steps))
                row["fractured_fraction"] = round(float(solver.state.fractured.float().mean()), 4)
                rows.append(row)
    print(json.dumps({"benchmark": "mpm_step_profile", "grid": args.grid, "device": str(device),
                      "threads": int(compiled_module().openmp_max_threads()), "results": rows}, indent=2))


if __name__ == "__main__":
    main()
