"""Frame strip of a simulation with its particles coloured by fragment (docs/simulation.md).

    python tools/figures/fragment_strip.py --sim output/sims/two_spheres --frames 0 6 12 23 \\
        --out docs/fragments_two_spheres.png [--title "two spheres"] [--view 20 -60]

Reads ``frames/frame_NNNNN.npz`` of a ``simulate.py`` folder (which carry ``fragment_id``) and
draws each chosen frame as a 3-D scatter: every fragment with >= 1 % of the particles gets its
own colour, smaller pieces are grey (the colours of view.py's "colour by piece"). Prints one JSON
line with the pieces per frame.
"""
from __future__ import annotations

import argparse
import sys
import json
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import torch  # noqa: E402

from fracture_gs.mpm.fragments import piece_ranks  # noqa: E402
from fracture_gs.io.sim_layout import PARTICLES_FILE, frame_file_name  # noqa: E402
from fracture_gs.folders.sim_reader import OutputError, load_frame  # noqa: E402
from fracture_gs.io.atomic import atomic_write  # noqa: E402
from fracture_gs.viewer.splats import piece_colours  # noqa: E402


def fragment_colours(labels: np.ndarray, obj_id: np.ndarray) -> tuple[np.ndarray, int]:
    """RGBA per particle, as view.py's "colour by piece" colours them: the i-th largest fragment
    holding >= 1 % of its object's particles gets tab20 colour i (piece_ranks), the rest grey; and
    the number of such fragments."""
    ranks = piece_ranks(torch.from_numpy(labels), torch.from_numpy(obj_id)).numpy()
    colours = np.empty((labels.size, 4))
    colours[:, :3] = piece_colours(ranks)
    colours[:, 3] = np.where(ranks >= 0, 1.0, 0.35)   # small pieces faded
    return colours, int(ranks.max()) + 1 if ranks.size else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", required=True, type=Path)
    parser.add_argument("--frames", type=int, nargs="+", required=True)
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--title", default=None)
    parser.add_argument("--view", type=float, nargs=2, default=(20.0, -60.0), help="elevation, azimuth (degrees)")
    parser.add_argument("--max-points", type=int, default=40_000, help="subsample larger frames for drawing")
    args = parser.parse_args()
    try:
        frames = [load_frame(args.sim / "frames" / frame_file_name(f)) for f in args.frames]
        with np.load(args.sim / PARTICLES_FILE) as particles:
            obj_id = particles["obj_id"].astype(np.int64)
    except (OutputError, OSError, KeyError, ValueError) as error:   # one line, not a traceback
        parser.exit(2, f"error: {error}\n")
    if any("fragment_id" not in frame for frame in frames):
        parser.exit(2, f"error: {args.sim}: frames have no fragment_id (simulated without fragment ids?)\n")
    everything = np.concatenate([frame["x"] for frame in frames])
    lower, upper = everything.min(0), everything.max(0)
    centre, half = (lower + upper) / 2, (upper - lower).max() / 2 * 1.05
    figure = plt.figure(figsize=(3.2 * len(frames), 3.4))
    pieces = []
    for column, (number, frame) in enumerate(zip(args.frames, frames)):
        axes = figure.add_subplot(1, len(frames), column + 1, projection="3d")
        colours, count = fragment_colours(frame["fragment_id"].astype(np.int64), obj_id)
        pieces.append(count)
        pick = np.arange(frame["x"].shape[0])
        if pick.size > args.max_points:
            pick = np.random.default_rng(0).choice(pick, args.max_points, replace=False)
        x = frame["x"][pick]
        axes.scatter(x[:, 0], x[:, 1], x[:, 2], c=colours[pick], s=1.0, depthshade=False, linewidths=0)
        for axis, setter in enumerate((axes.set_xlim, axes.set_ylim, axes.set_zlim)):
            setter(centre[axis] - half, centre[axis] + half)
        axes.view_init(*args.view)
        axes.set_axis_off()
        axes.set_title(f"frame {number}: {count} piece{'' if count == 1 else 's'} of ≥ 1 %", fontsize=9)
    if args.title:
        figure.suptitle(args.title, fontsize=10)
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda handle: figure.savefig(handle, format="png", dpi=110))
    print(json.dumps({"sim": str(args.sim), "frames": args.frames, "pieces_1pct": pieces, "out": str(args.out)}))


if __name__ == "__main__":
    main()
