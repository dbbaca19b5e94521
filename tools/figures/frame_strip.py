"""A frame strip of a simulation for the docs: chosen frames side by side, with FPGO (top rows:
one per lens exclusive rule of ``--exclusive-rows``, default the group rule; ``--no-exclusive-row``
adds lenses that blend like all others; ``--interior-all-row`` FPGO with a Gaussian for every
fractured interior particle, every fractured interior particle) and without FPGO (bottom row), from one
orbit view.

Usage: python tools/figures/frame_strip.py --sim output/sims/two_spheres \
           --frames 3 5 7 10 24 --out docs/two_spheres_fpgo.png [--size 320] [--view 0]
Prints one JSON line (what it wrote).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root

import cv2
import numpy as np
import torch

from fracture_gs.pipeline.views import resolve_views
from fracture_gs.fracture.fpgo import EXCLUSIVE_RULES, FPGOSettings
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.render.video import to_uint8
from fracture_gs.folders.sim_reader import Simulation


def label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1, cv2.LINE_AA)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", type=Path, required=True)
    parser.add_argument("--frames", type=int, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--size", type=int, default=320)
    parser.add_argument("--view", type=int, default=0, help="orbit camera index (of 8)")
    parser.add_argument("--crop", type=float, default=1.0,
                        help="keep this central share of each image (zoom)")
    parser.add_argument("--exclusive-rows", nargs="+", choices=EXCLUSIVE_RULES, default=["group"],
                        help="one FPGO row per lens exclusive rule (render.py --exclusive)")
    parser.add_argument("--no-exclusive-row", action="store_true",
                        help="add a row: FPGO with lens Gaussians that are not exclusive")
    parser.add_argument("--interior-all-row", action="store_true",
                        help="add a row: FPGO with interior='all' (every fractured interior "
                        "particle drawn, not only the exposed ones)")
    args = parser.parse_args(argv)
    sim = Simulation.open(args.sim)
    frames = [sim.select_frames(str(f))[0] for f in args.frames]
    view = resolve_views("orbit:8", sim, sim.frames, (args.size, args.size))[args.view]
    scene = SceneGaussians.from_simulation(sim)
    background = torch.ones(3)
    rules = list(args.exclusive_rows) + (["none"] if args.no_exclusive_row else [])
    names = {"group": "FPGO", "all": "FPGO, global rule", "none": "FPGO, not exclusive"}
    variants = [(names[rule], True, rule, scene) for rule in rules]
    if args.interior_all_row:
        every = SceneGaussians.from_simulation(sim, settings=FPGOSettings(interior="all"))
        variants.append(("FPGO, all interior", True, "group", every))
    variants.append(("no FPGO", False, "group", scene))
    rows = []
    for name, fpgo, rule, source in variants:
        tiles = []
        for index in frames:
            gaussians = source.frame(sim.load_frame(index), fpgo=fpgo)
            if rule == "none":
                gaussians = gaussians.without_exclusive()
            elif rule == "all":
                gaussians = replace(gaussians, exclusive_rule="all")
            image = to_uint8(gaussians.rasterize(view.camera, background)["rgb"])
            margin = int(round(args.size * (1.0 - args.crop) / 2.0))
            image = image[margin:args.size - margin, margin:args.size - margin]
            caption = f"frame {index}" + (f", {name}" if index == frames[0] else "")
            tiles.append(label(image, caption))
        rows.append(np.concatenate(tiles, axis=1))
    strip = np.concatenate(rows, axis=0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), strip[..., ::-1])
    print(json.dumps({"out": str(args.out), "frames": frames, "view": view.name,
                      "size": list(strip.shape[:2])}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
