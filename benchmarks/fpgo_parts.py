"""Which part of FPGO moves the self-referenced metrics of a simulation (the ablation, docs/results.md).

Renders the reference frame and the window frames of ``--sim`` (docs/formulas.md §14) from ``--views`` orbit
cameras with the frame's Gaussians in seven variants, scores each with the protocol of
``evaluate.py`` and compares it with the run without FPGO (paired over the views,
:mod:`fracture_gs.metrics.paired`):

* ``fpgo``: FPGO as render.py draws it (lenses + interior Gaussians);
* ``no_fpgo``: the particles' own Gaussians only (the baseline);
* ``fpgo_without_interior``: FPGO without the interpolated Gaussians of fractured interior
  particles that no lens replaced (the lenses alone);
* ``interior_only``: the baseline plus those interior Gaussians (no lens, every g_i kept);
* ``fpgo_no_exclusive``: FPGO with every lens blending (no occlusion-aware sampling);
* ``fpgo_keep_replaced``: FPGO's lenses and interior Gaussians added to the baseline, every g_i
  kept (the lenses add coverage instead of replacing g_i);
* ``lenses_keep_replaced``: the lenses alone added to the baseline, every g_i kept.

``--fpgo JSON`` overrides :class:`FPGOSettings` fields, e.g. ``'{"k_sigma": 3}'``. Images are
rounded to 8 bits like the PNGs evaluate.py reads. Prints one JSON object.

Usage: PYTHONPATH=. python benchmarks/fpgo_parts.py --sim output/demo/sims/teapot_table
           [--views 8] [--size 400] [--window 5] [--fpgo '{"k_sigma": 3}'] [--weights-dir DIR]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from fracture_gs.pipeline.experiments.sim_eval import EvaluationError, evaluation_views, open_simulation
from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.metrics.onset import fracture_window_from_simulation
from fracture_gs.metrics.paired import paired_differences
from fracture_gs.metrics.protocol import MetricNetworks, self_referenced_metrics
from fracture_gs.render.frame_gaussians import FrameGaussians, SceneGaussians

VARIANTS = ("fpgo", "no_fpgo", "fpgo_without_interior", "interior_only", "fpgo_no_exclusive", "fpgo_keep_replaced",
            "lenses_keep_replaced")


def joined(first: FrameGaussians, second: FrameGaussians) -> FrameGaussians:
    """The Gaussians of both frames (tensor columns concatenated, the rest from ``first``)."""
    columns = {}
    for column in dataclasses.fields(first):
        value = getattr(first, column.name)
        if isinstance(value, torch.Tensor):
            columns[column.name] = torch.cat([value, getattr(second, column.name)])
    return dataclasses.replace(first, **columns)


def frame_variants(scene: SceneGaussians, frame) -> dict[str, FrameGaussians]:
    """The variants of one frame's Gaussians (VARIANTS; module docstring)."""
    with_fpgo, without = scene.frame(frame, fpgo=True), scene.frame(frame, fpgo=False)
    interior = with_fpgo.is_fpgo & (with_fpgo.exclusive < 0)   # lenses carry an exclusive group
    lenses = with_fpgo.is_fpgo & ~interior
    return {"fpgo": with_fpgo, "no_fpgo": without,
            "fpgo_without_interior": with_fpgo.select(~interior),
            "interior_only": joined(without, with_fpgo.select(interior)),
            "fpgo_no_exclusive": with_fpgo.without_exclusive(),
            "fpgo_keep_replaced": joined(without, with_fpgo.select(with_fpgo.is_fpgo)),
            "lenses_keep_replaced": joined(without, with_fpgo.select(lenses))}


def add_window_arguments(parser: argparse.ArgumentParser) -> None:
    """--sim, --views, --size, --window: the simulation and the protocol's views and window."""
    parser.add_argument("--sim", type=Path, required=True)
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--window", type=int, default=5)


def open_window(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """(simulation, fracture window, orbit views) of ``args``; a one-line error exit otherwise."""
    try:
        sim = open_simulation(args.sim)
        window = fracture_window_from_simulation(args.sim, args.window)
        views = evaluation_views(sim, f"orbit:{args.views}", (args.size, args.size))
    except (EvaluationError, ValueError, TypeError, FileNotFoundError) as error:
        parser.exit(2, f"error: {error}\n")
    if not window.usable:
        parser.exit(2, f"error: {args.sim}: no usable fracture window ({window.note})\n")
    return sim, window, views


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_window_arguments(parser)
    parser.add_argument("--fpgo", default="{}", help="JSON object of FPGOSettings fields")
    parser.add_argument("--weights-dir", type=Path, default=None)
    args = parser.parse_args()
    try:
        overrides = json.loads(args.fpgo)
    except json.JSONDecodeError as error:
        parser.exit(2, f"error: --fpgo {args.fpgo!r} is not JSON ({error})\n")
    if not isinstance(overrides, dict):
        parser.exit(2, f"error: --fpgo must be a JSON object of FPGOSettings fields, got {args.fpgo!r}\n")
    try:
        settings = FPGOSettings(**overrides)
    except (ValueError, TypeError) as error:
        parser.exit(2, f"error: {error}\n")
    sim, window, views = open_window(parser, args)
    device = torch.device("cpu")
    scene = SceneGaussians.from_simulation(sim, device, settings)
    background = torch.ones(3, device=device)
    frames = [window.reference_frame, *window.window_frames]
    images: dict[str, list[torch.Tensor]] = {name: [] for name in VARIANTS}
    with torch.no_grad():
        for index in frames:
            for name, gaussians in frame_variants(scene, sim.load_frame(index, device)).items():
                images[name].append(torch.stack([
                    gaussians.rasterize(view.camera, background)["rgb"].clamp(0, 1)
                    for view in views]))
    networks = MetricNetworks.load(device, args.weights_dir)
    metrics = {}
    for name, per_frame in images.items():
        stacked = torch.round(torch.stack(per_frame) * 255) / 255          # (F, V, H, W, 3)
        metrics[name] = self_referenced_metrics(stacked[0], stacked[1:].transpose(0, 1), networks)
    result = {"sim": str(args.sim), "window": window.note, "views": args.views, "size": args.size,
              "fpgo_settings": dataclasses.asdict(settings), "variants": {}}
    for name, values in metrics.items():
        entry = {"psnr": float(values.psnr.mean()),
                 "lpips": float(values.lpips.mean()) if values.lpips is not None else None,
                 "fid": values.fid}
        if name != "no_fpgo":
            entry["against_no_fpgo"] = {metric: difference.to_json() for metric, difference
                                        in paired_differences(values, metrics["no_fpgo"]).items()}
        result["variants"][name] = entry
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
