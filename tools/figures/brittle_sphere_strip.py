"""Strip of the brittle sphere dropped at four speeds (the folders of benchmarks/brittle_sphere.py).

    python tools/figures/brittle_sphere_strip.py --runs output/brittle_sphere --out docs/brittle_sphere_strip.png \\
        [--frame -1] [--fragments on|off]

One column per speed (the ``v<speed>_fragments_<on|off>`` folders, slowest first): on top the
particles of the chosen frame (default the last) in 3-D, each piece of >= 1 % of the sphere in its
own colour (view.py's "colour by piece"), the rest grey; below, the vertical mid-plane slice coloured
by damage (black intact, yellow complete). Prints one JSON line with the pieces per speed.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from fracture_gs.mpm.fragments import piece_ranks  # noqa: E402
from fracture_gs.folders.sim_reader import OutputError, load_frame, read_npz  # noqa: E402
from fracture_gs.io.atomic import atomic_write  # noqa: E402
from fracture_gs.viewer.splats import damage_colours, piece_colours  # noqa: E402

_FOLDER = re.compile(r"^v(\d+(?:\.\d+)?)_fragments_(on|off)$")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=Path("output/brittle_sphere"))
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--frame", type=int, default=-1, help="frame to draw (negative: from the end)")
    parser.add_argument("--fragments", choices=("on", "off"), default="on")
    args = parser.parse_args()
    folders = sorted(((float(m.group(1)), path) for path in args.runs.glob("v*_fragments_*")
                      if (m := _FOLDER.match(path.name)) and m.group(2) == args.fragments), key=lambda t: t[0])
    if not folders:
        parser.exit(2, f"error: {args.runs}: no v<speed>_fragments_{args.fragments} folders "
                       "(run benchmarks/brittle_sphere.py first)\n")
    figure = plt.figure(figsize=(3.3 * len(folders), 6.4))
    pieces = []
    try:
        for column, (speed, folder) in enumerate(folders):
            frames = sorted((folder / "frames").glob("frame_*.npz"))
            frame = load_frame(frames[args.frame])
            obj_id = read_npz(folder / "particles.npz")["obj_id"].astype(np.int64)
            ranks = piece_ranks(torch.from_numpy(frame["fragment_id"].astype(np.int64)),
                                torch.from_numpy(obj_id)).numpy()
            count = int(ranks.max()) + 1 if ranks.size else 0
            pieces.append({"speed": speed, "pieces": count, "frame": frames[args.frame].stem})
            x, damage = frame["x"], frame["damage"]
            centre, half = x.mean(0), (x.max(0) - x.min(0)).max() / 2 * 1.05
            axes = figure.add_subplot(2, len(folders), column + 1, projection="3d")
            colours = np.concatenate([piece_colours(ranks), np.where(ranks >= 0, 1.0, 0.25)[:, None]], 1)
            axes.scatter(x[:, 0], x[:, 1], x[:, 2], c=colours, s=0.8, depthshade=False, linewidths=0)
            for axis, setter in enumerate((axes.set_xlim, axes.set_ylim, axes.set_zlim)):
                setter(centre[axis] - half, centre[axis] + half)
            axes.view_init(25, -60)
            axes.set_axis_off()
            axes.set_title(f"{speed:g} m/s: {count} piece{'' if count == 1 else 's'} of ≥ 1 %", fontsize=9)
            spacing = float(np.median(read_npz(folder / "particles.npz")["rest_volume"])) ** (1 / 3)
            section = np.abs(x[:, 1] - centre[1]) < 0.5 * spacing
            axes = figure.add_subplot(2, len(folders), len(folders) + column + 1)
            axes.scatter(x[section, 0], x[section, 2], c=damage_colours(damage[section]), s=4, linewidths=0)
            axes.set_aspect("equal")
            axes.set_xlim(centre[0] - half, centre[0] + half)
            axes.set_xticks([])
            axes.set_yticks([])
            axes.set_title(f"mid-plane damage, {float((damage >= 1).mean()):.0%} complete", fontsize=8)
    except (OutputError, OSError, KeyError, ValueError, IndexError) as error:   # one line, not a traceback
        parser.exit(2, f"error: {error}\n")
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(args.out, lambda handle: figure.savefig(handle, format="png", dpi=100))
    print(json.dumps({"runs": str(args.runs), "fragments": args.fragments, "pieces": pieces, "out": str(args.out)}))


if __name__ == "__main__":
    main()
