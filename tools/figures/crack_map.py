"""Damage maps of the crack checks' last states (docs/results.md, "Cracks from notch tips").

    python benchmarks/notched_plate.py --grid 128 --dump output/cracks
    python benchmarks/brittle_disc.py --ratios 1.6 --weibull 0 --dump output/cracks
    python tools/figures/crack_map.py output/cracks/plate_g128_v8_s0.npz output/cracks/disc_g64_r1.6_m0_s0.npz \\
        --titles "notched plate, grid 128 (rest shape)" "spun disc at 1.6 x burst speed" --out docs/crack_maps.png

Each panel is one dump (``--dump`` of those benchmarks: npz with x, damage and, for the plate, the
rest positions), seen along z: the plate in its rest shape (where the cracks lie in the material),
the disc where its particles are. Intact particles grey, partly damaged ones yellow to red by
damage, completely damaged ones black.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LinearSegmentedColormap  # noqa: E402

PARTIAL = LinearSegmentedColormap.from_list("partial", ["#f2d64b", "#d7301f"])


def load_dump(dump: Path) -> tuple[np.ndarray, np.ndarray]:
    """(positions to draw (n, 3), damage (n,)) of a dump; ValueError if it is not one."""
    try:
        with np.load(dump) as data:
            points = data["rest"] if "rest" in data else data["x"]
            damage = data["damage"]
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{dump}: not a dump of notched_plate.py / brittle_disc.py --dump ({exc})") from None
    if points.ndim != 2 or points.shape[1] < 2 or damage.shape != (len(points),):
        raise ValueError(f"{dump}: positions {points.shape} and damage {damage.shape} do not match")
    return points, damage


def draw(axis: plt.Axes, dump: Path, points: np.ndarray, damage: np.ndarray, title: str) -> dict:
    """One panel; returns the particle counts it drew."""
    intact, partial, complete = damage <= 0, (damage > 0) & (damage < 1), damage >= 1
    size = 40000.0 / max(len(points), 1)
    axis.scatter(points[intact, 0], points[intact, 1], s=size, c="#c8c8c8", linewidths=0)
    axis.scatter(points[partial, 0], points[partial, 1], s=size, c=damage[partial], cmap=PARTIAL, vmin=0, vmax=1,
                 linewidths=0)
    axis.scatter(points[complete, 0], points[complete, 1], s=size, c="black", linewidths=0)
    axis.set_aspect("equal")
    axis.set_xticks([])
    axis.set_yticks([])
    axis.set_title(title, fontsize=10)
    return {"file": str(dump), "intact": int(intact.sum()), "partly_damaged": int(partial.sum()),
            "completely_damaged": int(complete.sum())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dumps", type=Path, nargs="+", help="npz files written by the benchmarks' --dump")
    parser.add_argument("--titles", nargs="+", default=None, help="one title per dump")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--size", type=float, default=4.0, help="panel size in inches")
    args = parser.parse_args()
    titles = args.titles or [dump.stem for dump in args.dumps]
    if len(titles) != len(args.dumps):
        parser.error(f"{len(args.dumps)} dumps but {len(titles)} titles")
    missing = [str(dump) for dump in args.dumps if not dump.is_file()]
    if missing:
        parser.error(f"no such dump: {missing[0]}")
    try:
        loaded = [load_dump(dump) for dump in args.dumps]
    except ValueError as exc:
        parser.error(str(exc))
    figure, axes = plt.subplots(1, len(args.dumps), figsize=(args.size * len(args.dumps), args.size), squeeze=False)
    counts = [draw(axis, dump, points, damage, title)
              for axis, dump, (points, damage), title in zip(axes[0], args.dumps, loaded, titles)]
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=110)
    print(json.dumps(counts))


if __name__ == "__main__":
    main()
