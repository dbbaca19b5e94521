#!/usr/bin/env python3
"""Side-by-side picture of one test view: the ground truth and the renders of train.py models.

    python tools/figures/train_strip.py -s data/teapot -m output/teapot_a output/teapot_b \
        --labels "bound 0.25" "bound 1" --view 5 --out docs/train_teapot.png

Each panel is the test view rendered from the model's latest point_cloud.ply (on the dataset's
background colour), cropped to the object's box in the ground truth, labelled with the view's
PSNR over the whole image (``fracture_gs.report.plots.frame_strip`` writes the PNG); prints the
PSNRs as JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))  # the repository root

from fracture_gs.data import DatasetError, load_dataset  # noqa: E402
from fracture_gs.gaussians import read_ply  # noqa: E402
from fracture_gs.metrics.image import psnr  # noqa: E402
from fracture_gs.recon.gaussian_fit import render_model  # noqa: E402
from fracture_gs.io.model_layout import latest_iteration, point_cloud_path  # noqa: E402
from fracture_gs.report.plots import frame_strip  # noqa: E402


def _crop(image: torch.Tensor, box: tuple[int, int, int, int]) -> np.ndarray:
    """The crop ``box`` (top, bottom, left, right) of an (H, W, 3) float image as uint8 RGB."""
    top, bottom, left, right = box
    return np.ascontiguousarray((image[top:bottom, left:right].numpy() * 255).round().astype(np.uint8))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-s", "--source_path", required=True)
    parser.add_argument("-m", "--models", nargs="+", required=True)
    parser.add_argument("--labels", nargs="+", default=None)
    parser.add_argument("--view", type=int, default=0, help="test view index")
    parser.add_argument("--height", type=int, default=300, help="height of the panels in pixels")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    labels = args.labels or [os.path.basename(os.path.normpath(m)) for m in args.models]
    if len(labels) != len(args.models):
        parser.error("--labels: give one label per model")
    try:
        test = load_dataset(args.source_path, "test", 1, False)
    except DatasetError as exc:
        parser.error(str(exc))
    iterations = [latest_iteration(m) for m in args.models]
    for model_path, iteration in zip(args.models, iterations):
        if iteration is None:
            parser.error(f"{model_path}: no point_cloud/iteration_N (not a train.py model folder)")
    if not 0 <= args.view < len(test):
        parser.error(f"--view: {args.view} is not a test view (0..{len(test) - 1})")
    camera, target = test.cameras[args.view], test.images[args.view]
    mask = test.masks[args.view].numpy() > 0.5 if test.masks is not None else np.ones(target.shape[:2], bool)
    rows, cols = np.nonzero(mask)
    pad = 8
    top, bottom = max(rows.min() - pad, 0), min(rows.max() + pad + 1, mask.shape[0])
    left, right = max(cols.min() - pad, 0), min(cols.max() + pad + 1, mask.shape[1])
    box = (top, bottom, left, right)
    panels, captions, scores = [_crop(target, box)], ["ground truth"], {}
    for model_path, iteration, label in zip(args.models, iterations, labels):
        model = read_ply(point_cloud_path(model_path, iteration), isotropic=True)
        with torch.no_grad():
            rgb = render_model(model, camera, torch.tensor(test.background, dtype=torch.float32))["rgb"].clamp(0, 1)
        value = float(psnr(rgb, target))
        scores[label] = round(value, 2)
        panels.append(_crop(rgb, box))
        captions.append(f"{label}: {value:.2f} dB")
    frame_strip([(f"test view {args.view}", panels, captions)], Path(args.out), max_height=args.height)
    print(json.dumps({"view": args.view, "psnr_db": scores, "out": args.out}, indent=2))


if __name__ == "__main__":
    main()
