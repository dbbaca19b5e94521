"""Pieces of every object at the last frame of a scene, run once per seed (prints JSON).

The seed sets the Weibull strengths of brittle materials, so the runs differ only in where the
material is weak: the spread over seeds says how firmly a scene breaks the way it does. Per run:
for each object its pieces of >= 1 % of its particles, its largest piece's share and its share of
particles with complete damage (``fracture_gs.metrics.pieces``), and the wall time. Every run is a
simulate.py folder under --out (``seed_<n>``), which view.py and render.py read.

    python benchmarks/scene_pieces.py --scene configs/paper/teapot_ground_porcelain.yaml \\
        [--seeds 0 1 2 3 4 5] [--out output/scene_pieces/teapot_ground_porcelain]
    python benchmarks/scene_pieces.py --markdown benchmarks/results/scene_pieces_teapot_ground_porcelain.json
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import torch

from fracture_gs.config.scene import SceneError, load_scene
from fracture_gs.folders.sim_reader import Simulation
from fracture_gs.metrics.pieces import last_frame_pieces
from fracture_gs.pipeline.simulate import run_simulation


def markdown(result: dict) -> str:
    """The runs of a printed JSON result as a markdown table, one row per seed and object."""
    lines = ["| seed | object | pieces of >= 1 % | largest piece | completely damaged |", "|---|---|---|---|---|"]
    for run in result["runs"]:
        for piece in run["objects"]:
            lines.append(f"| {run['seed']} | {piece['name']} | {piece['pieces']} | {100 * piece['largest_share']:.1f} % "
                         f"| {100 * piece['complete_damage_share']:.1f} % |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", type=Path, help="scene YAML")
    parser.add_argument("--markdown", type=Path, metavar="JSON",
                        help="print the runs of an earlier result (this script's JSON) as a markdown table")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5])
    parser.add_argument("--out", type=Path, default=None,
                        help="folder of the runs (default output/scene_pieces/<scene name>)")
    args = parser.parse_args()
    if args.markdown is not None:
        try:
            table = markdown(json.loads(args.markdown.read_text()))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            parser.exit(2, f"error: --markdown {args.markdown}: not a result of this script ({exc})\n")
        print(table)
        return
    if args.scene is None:
        parser.exit(2, "error: --scene is required (or --markdown JSON)\n")
    try:
        scene = load_scene(args.scene)
    except (OSError, SceneError) as exc:
        parser.exit(2, f"error: --scene {args.scene}: {exc}\n")
    torch.set_grad_enabled(False)
    out = args.out or Path("output/scene_pieces") / args.scene.stem
    runs = []
    for seed in args.seeds:
        config = dataclasses.replace(scene, seed=seed)
        folder = out / f"seed_{seed}"
        start = time.perf_counter()
        try:
            with open(Path("/dev/null"), "w") as quiet:
                run_simulation(config, folder, device=torch.device("cpu"), progress=False, log=quiet)
        except KeyboardInterrupt:
            parser.exit(130, f"interrupted in seed {seed}; its frames so far are in {folder} "
                             f"(simulate.py --resume continues it)\n")
        pieces = last_frame_pieces(Simulation.open(folder)) or []
        runs.append({"seed": seed, "wall_s": round(time.perf_counter() - start, 1),
                     "objects": [{**p.to_json(), "largest_share": round(p.largest_share, 4),
                                  "complete_damage_share": round(p.complete_damage_share, 4)} for p in pieces]})
    print(json.dumps({"benchmark": "scene_pieces", "scene": str(args.scene), "grid": scene.domain.grid,
                      "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
