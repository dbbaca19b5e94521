"""Vertical cross-sections of a dropped block over time: why a block breaks or not (docs/simulation.md).

    python tools/figures/block_section.py --scene block_weak_6 --jitter-seed 0 --ground-friction 0.5 \\
        --times 0.01 0.04 0.08 0.15 0.25 --out docs/fragments_jittered_weak_block_section.png [--no-fragments]

Simulates one block scene of ``bench_fragments.py`` (same builder, grid and settings) and draws,
at each time, the particles of the block's middle lattice layer (chosen in the rest
configuration, so the same particles in every panel) seen from the side: top row coloured by
NACC α (fixed scale; α >= 0: cohesion gone, the fracture flag latches; α >= 0.005: damaged for
the partition), bottom row by fragment (pieces with >= 1 % of the particles in their own colour,
as ``fragment_strip.py``). Prints one JSON line per time: pieces >= 2 %, fractured share, height
of the block.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]  # the package and bench_fragments.py

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from bench_fragments import BLOCKS, PIECE_SHARE  # noqa: E402
from fracture_gs.testing.fragment_scenes import block_drop  # noqa: E402
from fracture_gs.mpm.fragments import fragment_sizes  # noqa: E402
from fracture_gs.io.atomic import atomic_write  # noqa: E402
from fragment_strip import fragment_colours  # noqa: E402

ALPHA_RANGE = (-0.1, 0.1)  # colour scale of α: compacted (hardened) ... dilated past the threshold 0


def middle_layer(rest_y: np.ndarray, thickness: float = 0.0) -> np.ndarray:
    """Bool mask of the particles of the middle layer at rest: the lattice layer (constant y)
    nearest the centre, or with ``thickness`` > 0 (jittered blocks) the slab of that thickness
    around the centre."""
    centre = 0.5 * (rest_y.min() + rest_y.max())
    if thickness > 0:
        return np.abs(rest_y - centre) < 0.5 * thickness
    nearest = rest_y[np.argmin(np.abs(rest_y - centre))]
    return np.abs(rest_y - nearest) < 1e-6


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="block_test_3.5", help=f"one of {', '.join(BLOCKS)}")
    parser.add_argument("--times", type=float, nargs="+", default=[0.01, 0.02, 0.04, 0.08, 0.15])
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--no-fragments", action="store_true", help="contact.fragments false")
    parser.add_argument("--jitter-seed", type=int, default=None,
                        help="sample the block as a YAML box primitive with this seed (default: a lattice)")
    parser.add_argument("--ground-friction", type=float, default=0.3)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.scene not in BLOCKS:
        print(f"error: unknown scene {args.scene!r}; one of {', '.join(BLOCKS)}", file=sys.stderr)
        return 2
    times = sorted(args.times)
    if times[0] <= 0:
        print(f"error: times must be > 0, got {times[0]}", file=sys.stderr)
        return 2
    if (args.jitter_seed is not None and args.jitter_seed < 0) or not args.ground_friction >= 0:
        print("error: --jitter-seed and --ground-friction must be >= 0", file=sys.stderr)
        return 2
    speed, E, density, alpha0, beta, _ = BLOCKS[args.scene]
    solver = block_drop(speed, E=E, density=density, alpha0=alpha0, beta=beta, grid=args.grid,
                        fragments=not args.no_fragments, jitter_seed=args.jitter_seed,
                        ground_friction=args.ground_friction)
    spacing = solver.domain.dx / 2   # the particle spacing of block_drop
    layer = middle_layer(solver.state_in_input_order().x.numpy()[:, 1],
                         spacing if args.jitter_seed is not None else 0.0)
    n = len(solver.particles)
    lower, upper = np.full(2, np.inf), np.full(2, -np.inf)  # (x, z) bounds of every panel
    figure, axes = plt.subplots(2, len(times), figsize=(3.0 * len(times), 3.6), squeeze=False,
                               layout="constrained")
    for column, time in enumerate(times):
        while time - solver.state.time > 1e-12:
            solver.step(min(solver.stable_dt(), time - solver.state.time))
        state = solver.state_in_input_order()
        x, alpha = state.x.numpy(), state.alpha.numpy()
        labels = solver.fragment_ids().numpy()
        sizes = fragment_sizes(solver.fragment_ids())
        row = {"time": time, "pieces_2pct": sum(1 for s in sizes if s >= PIECE_SHARE * n),
               "largest_pieces": sizes[:4], "fractured": round(float(state.fractured.float().mean()), 4),
               "height": round(float(x[:, 2].max() - x[:, 2].min()), 4)}
        print(json.dumps(row), flush=True)
        colours, _ = fragment_colours(labels, np.zeros(n, np.int64))
        lower = np.minimum(lower, x[layer][:, [0, 2]].min(0))
        upper = np.maximum(upper, x[layer][:, [0, 2]].max(0))
        top, bottom = axes[0, column], axes[1, column]
        picture = top.scatter(x[layer, 0], x[layer, 2], c=alpha[layer], s=2, cmap="viridis",
                              vmin=ALPHA_RANGE[0], vmax=ALPHA_RANGE[1])
        bottom.scatter(x[layer, 0], x[layer, 2], c=colours[layer], s=2)
        top.set_title(f"t = {time:g} s: {100 * row['fractured']:.0f} % fractured", fontsize=9)
        bottom.set_title(f"{row['pieces_2pct']} piece(s) of >= 2 %", fontsize=9)
        for axis in (top, bottom):
            axis.set_aspect("equal")
            axis.tick_params(labelsize=7)
    margin = 0.02 * (upper - lower).max()
    for axis in axes.flat:  # one scale for every panel, so that the shapes compare
        axis.set_xlim(lower[0] - margin, upper[0] + margin)
        axis.set_ylim(lower[1] - margin, upper[1] + margin)
    figure.colorbar(picture, ax=axes[:, -1].tolist(), shrink=0.6, label="NACC α (top row)")
    mode = "off" if args.no_fragments else "on"
    figure.suptitle(f"{args.scene} (E = {E:g}, ρ = {density:g}, α0 = {alpha0}, {speed:g} m/s), "
                    f"fragments {mode}: middle layer seen from the side (x, z in m)", fontsize=10)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda handle: figure.savefig(handle, format="png", dpi=110))
    return 0


if __name__ == "__main__":
    sys.exit(main())
