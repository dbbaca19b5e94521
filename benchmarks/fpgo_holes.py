"""Holes in a rendered fracture, with and without FPGO.

For every frame from the fracture onset on (first frame whose fractured count exceeds
max(10, 0.1 % of the particles), docs/formulas.md §14) and each of ``--views`` orbit cameras, the frame is
rendered with FPGO, with FPGO but lens Gaussians not ``exclusive``, and without FPGO (the
PhysGaussian / GIC baseline). The object's silhouette is where its particles project, dilated by
``--dilate`` projected rest spacings, which closes the gaps between neighbouring particles; the
*hole fraction* is the share of silhouette pixels whose rendered alpha is below 0.5.

Two silhouettes are reported: ``hole_fraction_*`` erodes the dilated one again by the same
radius (a morphological closing: the object's own area, gaps closed), ``band_hole_fraction_*``
keeps the plain dilation, which adds a band one spacing wide around the object where no splat
of scale <= spacing/2 reaches alpha 0.5 — that band dominates the plain measure and rewards fat
splats at the outline rather than filled fracture surfaces. Particles that FPGO drops as tiny
fragments (below ``--min-fragment``) are left out of the silhouette for all renders, so all are
judged on the same pixels; and, by the same rule, the alpha counted is that of the Gaussians of
the silhouette's particles: the baseline's Gaussians of those tiny fragments, which FPGO does not
draw, are not counted either (``no_fpgo``). They are not part of the object the silhouette
measures, and would otherwise cover its pixels (a crumb projected onto the body, or floating just
outside its outline) in the baseline only. ``no_fpgo_all_gaussians`` is the baseline with every
Gaussian counted. ``--silhouette all`` takes the
silhouette from every particle, the tiny fragments included (FPGO then has holes wherever it left
one out).

``--map FRAME PATH`` also draws where the two renders differ in that frame, every view side by
side: the dilated silhouette grey, its holes (alpha < 0.5) red with FPGO only, green without FPGO
only, dark grey in both.

Usage: PYTHONPATH=. python benchmarks/fpgo_holes.py --sim output/sims/<name> [--views 4]
           [--size 400] [--markdown] [--map FRAME PATH]
Prints one JSON object (per-frame numbers, both averaged over the views); ``--markdown`` adds a
table for docs/rendering.md on stderr.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from fracture_gs.cli.render import add_interior_options
from fracture_gs.pipeline.views import resolve_views
from fracture_gs.fracture.fpgo import FPGOSettings, small_fragment_mask
from fracture_gs.metrics.onset import fracture_window_from_simulation
from fracture_gs.render.camera import Camera
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.folders.sim_reader import Simulation


def silhouette(points: torch.Tensor, camera: Camera, spacing: float,
               dilate: float) -> tuple[np.ndarray, np.ndarray]:
    """(closed, dilated) silhouettes (H, W) bool: pixels within ``dilate`` projected spacings of
    a projected particle, and that set eroded again by the same disc."""
    empty = np.zeros((camera.height, camera.width), bool)
    if points.shape[0] == 0:
        return empty, empty
    uv, depth = camera.project(points)
    front = depth > camera.near
    uv, depth = uv[front], depth[front]
    if depth.numel() == 0:
        return empty, empty
    mask = np.zeros((camera.height, camera.width), np.uint8)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    pixels = uv[inside].floor().long().numpy()
    mask[pixels[:, 1], pixels[:, 0]] = 1
    radius = max(1, int(round(dilate * spacing * camera.fx / float(depth.median()))))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    dilated = cv2.dilate(mask, kernel)
    return cv2.erode(dilated, kernel).astype(bool), dilated.astype(bool)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", type=Path, required=True)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--dilate", type=float, default=1.0,
                        help="silhouette dilation in projected rest spacings (default 1)")
    parser.add_argument("--min-fragment", type=int, default=FPGOSettings().min_fragment)
    parser.add_argument("--markdown", action="store_true")
    parser.add_argument("--map", nargs=2, metavar=("FRAME", "PATH"), default=None,
                        help="also write a picture of the hole pixels of FRAME to PATH")
    parser.add_argument("--silhouette", choices=("drawn", "all"), default="drawn",
                        help="particles the silhouette comes from: 'drawn' leaves out the tiny "
                        "fragments FPGO does not draw (default), 'all' every particle")
    add_interior_options(parser)
    args = parser.parse_args(argv)
    sim = Simulation.open(args.sim)
    settings = FPGOSettings(min_fragment=args.min_fragment, interior=args.interior,
                            exposure=args.exposure)
    scene = SceneGaussians.from_simulation(sim, settings=settings)
    onset = fracture_window_from_simulation(sim.root).onset_frame
    result: dict = {"sim": str(args.sim), "particles": len(sim.particles), "views": args.views,
                    "size": args.size, "dilate_spacings": args.dilate, "onset": onset,
                    "silhouette": args.silhouette,
                    "gaussians_no_fpgo": scene.num_gaussians, "frames": []}
    if onset is None:
        result["note"] = "no fracture onset in this run"
        print(json.dumps(result, indent=1))
        return 0
    frames = [f for f in sim.frames if f >= onset]
    views = resolve_views(f"orbit:{args.views}", sim, frames, (args.size, args.size))
    fracture = scene.fracture
    labels = ("fpgo", "fpgo_no_exclusive", "no_fpgo", "no_fpgo_all_gaussians")
    for index in frames:
        frame = sim.load_frame(index)
        active = torch.ones(len(fracture.rows_by_object), dtype=torch.bool)
        hidden = (small_fragment_mask(frame.x, fracture, settings, active)
                  if args.silhouette == "drawn" else torch.zeros(frame.x.shape[0], dtype=torch.bool))
        fpgo = scene.frame(frame, fpgo=True)
        baseline = scene.frame(frame, fpgo=False)
        rendered = {"fpgo": fpgo, "no_fpgo": baseline.select(~hidden[baseline.particle]),
                    "fpgo_no_exclusive": fpgo.without_exclusive(),
                    "no_fpgo_all_gaussians": baseline}
        holes = {(label, kind): 0 for label in labels for kind in ("closed", "band")}
        pixels = {"closed": 0, "band": 0}
        panels = []
        for view in views:
            closed = np.zeros((args.size, args.size), bool)
            band = np.zeros((args.size, args.size), bool)
            for o, rows in enumerate(fracture.rows_by_object):
                keep = rows[~hidden[rows]]
                object_closed, object_band = silhouette(frame.x[keep], view.camera,
                                                        float(fracture.object_spacing[o]),
                                                        args.dilate)
                closed |= object_closed
                band |= object_band
            pixels["closed"] += int(closed.sum())
            pixels["band"] += int(band.sum())
            open_pixels = {}
            for label, gaussians in rendered.items():
                alpha = gaussians.rasterize(view.camera)["alpha"].numpy()
                holes[(label, "closed")] += int((alpha[closed] < 0.5).sum())
                holes[(label, "band")] += int((alpha[band] < 0.5).sum())
                open_pixels[label] = band & (alpha < 0.5)
            if args.map is not None and index == int(args.map[0]):
                panels.append(hole_map(band, open_pixels["fpgo"], open_pixels["no_fpgo"]))
        row = {"frame": index, "fractured": int(frame.fractured.sum()),
               "gaussians_fpgo": len(fpgo), "silhouette_pixels": pixels["closed"]}
        for label in labels:
            row[f"hole_fraction_{label}"] = round(holes[(label, "closed")] / max(pixels["closed"], 1), 6)
            row[f"band_hole_fraction_{label}"] = round(holes[(label, "band")] / max(pixels["band"], 1), 6)
        result["frames"].append(row)
        if panels:
            picture = np.concatenate(panels, axis=1)
            rows = np.nonzero((picture < 255).any(axis=(1, 2)))[0]   # the rows the objects cover
            if rows.size:
                picture = picture[max(rows[0] - 8, 0):rows[-1] + 9]
            cv2.imwrite(args.map[1], picture[..., ::-1])
            result["map"] = {"frame": index, "path": args.map[1]}
        print(f"frame {index}: holes {row['hole_fraction_fpgo']:.5f} with FPGO "
              f"({row['hole_fraction_fpgo_no_exclusive']:.5f} lenses not exclusive), "
              f"{row['hole_fraction_no_fpgo']:.5f} without", file=sys.stderr)
    rows = result["frames"]
    after = [r for r in rows if r["frame"] > onset]
    for label in ("fpgo", "fpgo_no_exclusive"):
        for prefix in ("", "band_"):
            key = f"{prefix}hole_fraction_{label}"
            base = f"{prefix}hole_fraction_no_fpgo"
            result[f"{prefix}frames_lower_{label}"] = sum(r[key] < r[base] for r in rows)
            result[f"{prefix}frames_higher_{label}"] = sum(r[key] > r[base] for r in rows)
            result[f"{prefix}frames_after_onset_lower_{label}"] = [
                sum(r[key] < r[base] for r in after), len(after)]
    for label in labels:
        result[f"mean_hole_fraction_{label}"] = round(float(np.mean([r[f"hole_fraction_{label}"] for r in rows])), 6)
        result[f"mean_band_hole_fraction_{label}"] = round(float(np.mean([r[f"band_hole_fraction_{label}"] for r in rows])), 6)
    print(json.dumps(result, indent=1))
    if args.markdown:
        print(markdown_table(rows), file=sys.stderr)
    return 0


def hole_map(silhouette_pixels: np.ndarray, holes_fpgo: np.ndarray,
             holes_no_fpgo: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB: silhouette grey, holes red (FPGO only), green (without FPGO only),
    dark grey (both)."""
    image = np.full(silhouette_pixels.shape + (3,), 255, np.uint8)
    image[silhouette_pixels] = (215, 215, 215)
    image[holes_fpgo & holes_no_fpgo] = (110, 110, 110)
    image[holes_fpgo & ~holes_no_fpgo] = (220, 30, 30)
    image[holes_no_fpgo & ~holes_fpgo] = (20, 150, 40)
    return image


def markdown_table(rows: list[dict]) -> str:
    """The markdown table: hole fractions in the closed and in the plain dilated silhouette, the
    baseline also with the Gaussians of the tiny fragments counted."""
    lines = ["| frame | fractured | closed: FPGO | closed: no FPGO | dilated: FPGO | "
             "dilated: no FPGO | dilated: no FPGO, tiny fragments' Gaussians counted |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['frame']} | {r['fractured']} | {100 * r['hole_fraction_fpgo']:.2f} % | "
                     f"{100 * r['hole_fraction_no_fpgo']:.2f} % | "
                     f"{100 * r['band_hole_fraction_fpgo']:.2f} % | "
                     f"{100 * r['band_hole_fraction_no_fpgo']:.2f} % | "
                     f"{100 * r['band_hole_fraction_no_fpgo_all_gaussians']:.2f} % |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
