"""Holes in a rendered fracture, with and without FPGO (issue 11, acceptance 2).

For every frame from the fracture onset on (first frame whose fractured count exceeds
max(10, 0.1 % of the particles), SPEC §7) and each of ``--views`` orbit cameras, the frame is
rendered with FPGO and without (the PhysGaussian / GIC baseline). The object's silhouette is
where its particles project, dilated by ``--dilate`` projected rest spacings (which closes the
gaps between neighbouring particles); the *hole fraction* is the share of silhouette pixels whose
rendered alpha is below 0.5. Particles that FPGO drops as tiny fragments (below
``--min-fragment``) are left out of the silhouette for both renders, so both are judged on the
same pixels.

Usage: PYTHONPATH=. python benchmarks/fpgo_holes.py --sim output/sims/<name> [--views 4]
           [--size 400] [--markdown]
Prints one JSON object (per-frame numbers, both averaged over the views); ``--markdown`` adds a
table for the README on stderr.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from fracture_gs.cli.render import resolve_views
from fracture_gs.fracture.fpgo import FPGOSettings, small_fragment_mask
from fracture_gs.render.camera import Camera
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.sim import Simulation


def onset_frame(sim: Simulation) -> int | None:
    """First frame with more than max(10, 0.1 % of N) fractured particles (SPEC §7)."""
    threshold = max(10, 0.001 * len(sim.particles))
    for index in sim.frames:
        if int(sim.load_frame(index).fractured.sum()) > threshold:
            return index
    return None


def silhouette(points: torch.Tensor, camera: Camera, spacing: float, dilate: float) -> np.ndarray:
    """Pixels within ``dilate`` projected spacings of a projected particle (H, W) bool."""
    uv, depth = camera.project(points)
    front = depth > camera.near
    uv, depth = uv[front], depth[front]
    mask = np.zeros((camera.height, camera.width), np.uint8)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    pixels = uv[inside].floor().long().numpy()
    mask[pixels[:, 1], pixels[:, 0]] = 1
    radius = max(1, int(round(dilate * spacing * camera.fx / float(depth.median()))))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask, kernel).astype(bool)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", type=Path, required=True)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--dilate", type=float, default=1.0,
                        help="silhouette dilation in projected rest spacings (default 1)")
    parser.add_argument("--min-fragment", type=int, default=FPGOSettings().min_fragment)
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args(argv)
    sim = Simulation.open(args.sim)
    settings = FPGOSettings(min_fragment=args.min_fragment)
    scene = SceneGaussians.from_simulation(sim, settings=settings)
    onset = onset_frame(sim)
    result: dict = {"sim": str(args.sim), "particles": len(sim.particles), "views": args.views,
                    "size": args.size, "dilate_spacings": args.dilate, "onset": onset,
                    "gaussians_no_fpgo": scene.num_gaussians, "frames": []}
    if onset is None:
        result["note"] = "no fracture onset in this run"
        print(json.dumps(result, indent=1))
        return 0
    frames = [f for f in sim.frames if f >= onset]
    views = resolve_views(f"orbit:{args.views}", sim, frames, (args.size, args.size))
    fracture = scene.fracture
    for index in frames:
        frame = sim.load_frame(index)
        active = torch.ones(len(fracture.rows_by_object), dtype=torch.bool)
        hidden = small_fragment_mask(frame.x, fracture, settings, active)
        rendered = {label: scene.frame(frame, fpgo=fpgo) for label, fpgo in
                    (("fpgo", True), ("no_fpgo", False))}
        holes = {"fpgo": 0, "no_fpgo": 0}
        silhouette_pixels = 0
        for view in views:
            mask = np.zeros((args.size, args.size), bool)
            for o, rows in enumerate(fracture.rows_by_object):
                keep = rows[~hidden[rows]]
                spacing = float(fracture.object_spacing[o])
                mask |= silhouette(frame.x[keep], view.camera, spacing, args.dilate)
            silhouette_pixels += int(mask.sum())
            for label, gaussians in rendered.items():
                alpha = gaussians.rasterize(view.camera)["alpha"].numpy()
                holes[label] += int((alpha[mask] < 0.5).sum())
        result["frames"].append({
            "frame": index, "fractured": int(frame.fractured.sum()),
            "hole_fraction_fpgo": round(holes["fpgo"] / max(silhouette_pixels, 1), 5),
            "hole_fraction_no_fpgo": round(holes["no_fpgo"] / max(silhouette_pixels, 1), 5),
            "gaussians_fpgo": len(rendered["fpgo"]), "silhouette_pixels": silhouette_pixels})
        print(f"frame {index}: holes {result['frames'][-1]['hole_fraction_fpgo']:.4f} with FPGO, "
              f"{result['frames'][-1]['hole_fraction_no_fpgo']:.4f} without", file=sys.stderr)
    rows = result["frames"]
    result["fpgo_lower_in_every_frame"] = all(r["hole_fraction_fpgo"] < r["hole_fraction_no_fpgo"]
                                              for r in rows)
    result["frames_fpgo_lower"] = sum(r["hole_fraction_fpgo"] < r["hole_fraction_no_fpgo"] for r in rows)
    result["mean_hole_fraction_fpgo"] = round(float(np.mean([r["hole_fraction_fpgo"] for r in rows])), 5)
    result["mean_hole_fraction_no_fpgo"] = round(float(np.mean([r["hole_fraction_no_fpgo"] for r in rows])), 5)
    print(json.dumps(result, indent=1))
    if args.markdown:
        print("| frame | fractured | hole fraction, FPGO | hole fraction, no FPGO |", file=sys.stderr)
        print("|---|---|---|---|", file=sys.stderr)
        for r in rows:
            print(f"| {r['frame']} | {r['fractured']} | {100 * r['hole_fraction_fpgo']:.2f} % | "
                  f"{100 * r['hole_fraction_no_fpgo']:.2f} % |", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
