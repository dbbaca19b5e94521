"""Where FPGO's parts gain or lose against the run without FPGO, pixel by pixel (docs/results.md, The demo).

The self-referenced protocol (docs/formulas.md §14) scores each window frame against the reference frame
I_ref = t_f − 1 of the same view. This script renders the reference and the window frames of
``--sim`` from ``--views`` orbit cameras, without FPGO and with each of FPGO's two parts alone
(``benchmarks/fpgo_parts.py``: the lenses, ``fpgo_without_interior``; the interior Gaussians,
``interior_only``) and with the whole of FPGO, and computes per pixel the change of the squared
error against I_ref that the variant makes: Δ = |I_variant − I_ref|² − |I_no_fpgo − I_ref|²
(summed over the colour channels; > 0: the variant is further from the reference).

It prints one JSON object: per variant the summed Δ over all views and window frames, split by
what the reference shows at the pixel (its alpha ≥ 0.5: the object, ``on_object``; else the
background, ``on_background``) and by sign, and the share of the loss that falls on background
pixels of the reference. With ``--out PNG`` it also draws a grid: per (view, frame) row the
reference, the render without FPGO, each variant, and each variant's Δ map (red: worse than
without FPGO, green: better; ±``--scale`` saturates).

    python tools/figures/fpgo_error_maps.py --sim output/demo/sims/teapot_table \
        [--views 8] [--size 400] [--window 5] [--out docs/fpgo_error_maps.png] \
        [--show-views 0 3] [--show-frames 2 4 6]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]  # the package and fpgo_parts.py
from fpgo_parts import add_window_arguments, frame_variants, open_window  # noqa: E402  (benchmarks/fpgo_parts.py)

from fracture_gs.fracture.fpgo import FPGOSettings  # noqa: E402
from fracture_gs.render.frame_gaussians import SceneGaussians  # noqa: E402

VARIANTS = {"lenses": "fpgo_without_interior", "interior": "interior_only", "fpgo": "fpgo"}


def squared_error(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """(H, W) squared colour error of 8-bit-rounded images, as evaluate.py reads its PNGs."""
    image, reference = (torch.round(t.clamp(0, 1) * 255) / 255 for t in (image, reference))
    return ((image - reference) ** 2).sum(-1)


def delta_map(delta: torch.Tensor, scale: float) -> np.ndarray:
    """RGB picture of a Δ map: white 0, red where Δ > 0 (worse), green where Δ < 0 (better)."""
    s = (delta / scale).clamp(-1, 1)
    worse, better = s.clamp(min=0), (-s).clamp(min=0)
    picture = torch.ones(*delta.shape, 3)
    picture[..., 0] -= better
    picture[..., 1] -= worse
    picture[..., 2] -= worse + better
    return picture.clamp(0, 1).numpy()


def summary(deltas: list[torch.Tensor], on_object: list[torch.Tensor]) -> dict[str, float]:
    """Summed Δ split by the reference's coverage and by sign, and the loss share on background."""
    delta, obj = torch.stack(deltas).double(), torch.stack(on_object)
    worse = delta.clamp(min=0)
    out = {"total": float(delta.sum()),
           "on_object": float(delta[obj].sum()), "on_background": float(delta[~obj].sum()),
           "worse": float(worse.sum()), "better": float(delta.clamp(max=0).sum()),
           "worse_on_background": float(worse[~obj].sum())}
    out["loss_share_on_background"] = out["worse_on_background"] / out["worse"] if out["worse"] > 0 else 0.0
    return out


def draw(rows: list[tuple[str, list[np.ndarray]]], titles: list[str], out: Path) -> None:
    """The grid of pictures, one row per (view, frame), with column titles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_rows, n_cols = len(rows), len(titles)
    figure, axes = plt.subplots(n_rows, n_cols, figsize=(2.0 * n_cols, 2.0 * n_rows + 0.3), squeeze=False)
    for r, (label, pictures) in enumerate(rows):
        for c, picture in enumerate(pictures):
            axes[r, c].imshow(picture)
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
            if r == 0:
                axes[r, c].set_title(titles[c], fontsize=8)
        axes[r, 0].set_ylabel(label, fontsize=8)
    figure.tight_layout()
    figure.savefig(out, dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_window_arguments(parser)
    parser.add_argument("--out", type=Path, default=None, help="PNG of the maps (optional)")
    parser.add_argument("--show-views", type=int, nargs="+", default=[0])
    parser.add_argument("--show-frames", type=int, nargs="+", default=None,
                        help="window frames to draw (default: the first, middle and last)")
    parser.add_argument("--crop", type=float, default=1.0, help="central share of each picture drawn")
    parser.add_argument("--scale", type=float, default=0.05, help="|Δ| drawn at full colour")
    args = parser.parse_args()
    if not 0.0 < args.crop <= 1.0:
        parser.exit(2, f"error: --crop must be in (0, 1], got {args.crop}\n")
    if not args.scale > 0.0:
        parser.exit(2, f"error: --scale must be > 0, got {args.scale}\n")
    if args.out is not None and not args.out.parent.resolve().is_dir():
        parser.exit(2, f"error: --out {args.out}: folder {args.out.parent} does not exist\n")
    sim, window, views = open_window(parser, args)
    shown_frames = args.show_frames or [window.window_frames[0], window.window_frames[len(window.window_frames) // 2],
                                        window.window_frames[-1]]
    for view in args.show_views:
        if not 0 <= view < len(views):
            parser.exit(2, f"error: --show-views {view}: there are {len(views)} views\n")
    device = torch.device("cpu")
    scene = SceneGaussians.from_simulation(sim, device, FPGOSettings())
    background = torch.ones(3, device=device)
    deltas: dict[str, list[torch.Tensor]] = {name: [] for name in VARIANTS}
    on_object: list[torch.Tensor] = []
    rows: list[tuple[str, list[np.ndarray]]] = []
    margin = int(round(args.size * (1 - args.crop) / 2))
    crop = slice(margin, args.size - margin)
    with torch.no_grad():
        reference_gaussians = scene.frame(sim.load_frame(window.reference_frame, device), fpgo=False)
        references = [reference_gaussians.rasterize(view.camera, background) for view in views]
        for frame in window.window_frames:
            variants = frame_variants(scene, sim.load_frame(frame, device))
            for v, view in enumerate(views):
                reference = references[v]["rgb"]
                base = variants["no_fpgo"].rasterize(view.camera, background)["rgb"]
                base_error = squared_error(base, reference)
                on_object.append(references[v]["alpha"].reshape(base_error.shape) >= 0.5)
                images = {}
                for name, variant in VARIANTS.items():
                    images[name] = variants[variant].rasterize(view.camera, background)["rgb"]
                    deltas[name].append(squared_error(images[name], reference) - base_error)
                if args.out is not None and v in args.show_views and frame in shown_frames:
                    pictures = [reference, base, *images.values()]
                    pictures = [p.clamp(0, 1).numpy()[crop, crop] for p in pictures]
                    pictures += [delta_map(deltas[name][-1], args.scale)[crop, crop] for name in VARIANTS]
                    rows.append((f"view {v}, frame {frame}", pictures))
    result = {"sim": str(args.sim), "window": window.note, "views": args.views, "size": args.size,
              "delta_squared_error": {name: summary(values, on_object) for name, values in deltas.items()}}
    if args.out is not None:
        titles = [f"I_ref (frame {window.reference_frame})", "no FPGO", "lenses only", "interior Gaussians only",
                  "FPGO", "Δ lenses", "Δ interior", "Δ FPGO"]
        draw(rows, titles, args.out)
        result["picture"] = str(args.out)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
