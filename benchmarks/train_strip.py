#!/usr/bin/env python3
"""Side-by-side picture of one test view: the ground truth and the renders of train.py models.

    python benchmarks/train_strip.py -s data/teapot -m output/teapot_a output/teapot_b \
        --labels "bound 0.25" "bound 1" --view 5 --out docs/train_teapot.png

Each panel is the test view rendered from the model's latest point_cloud.ply (on the model's
background colour), cropped to the object's box in the ground truth, labelled with the view's
PSNR over the whole image; prints the PSNRs as JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import cv2
import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_gs.data import load_dataset  # noqa: E402
from fracture_gs.gaussians import read_ply  # noqa: E402
from fracture_gs.metrics.image import psnr  # noqa: E402
from fracture_gs.recon.gaussian_fit import render_model  # noqa: E402
from fracture_gs.recon.model_io import latest_iteration, point_cloud_path  # noqa: E402


def _panel(image: np.ndarray, box: tuple[int, int, int, int], zoom: int, text: str) -> np.ndarray:
    """The crop ``box`` (top, bottom, left, right) of an (H, W, 3) float image, enlarged, labelled."""
    top, bottom, left, right = box
    crop = np.repeat(np.repeat(image[top:bottom, left:right], zoom, 0), zoom, 1)
    out = np.ascontiguousarray((crop * 255).round().astype(np.uint8))
    cv2.putText(out, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-s", "--source_path", required=True)
    parser.add_argument("-m", "--models", nargs="+", required=True)
    parser.add_argument("--labels", nargs="+", default=None)
    parser.add_argument("--view", type=int, default=0, help="test view index")
    parser.add_argument("--zoom", type=int, default=2, help="pixel repeat of the crop")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    labels = args.labels or [os.path.basename(os.path.normpath(m)) for m in args.models]
    if len(labels) != len(args.models):
        parser.error("--labels: give one label per model")
    test = load_dataset(args.source_path, "test", 1, False)
    camera, target = test.cameras[args.view], test.images[args.view]
    mask = test.masks[args.view].numpy() > 0.5 if test.masks is not None else np.ones(target.shape[:2], bool)
    rows, cols = np.nonzero(mask)
    pad = 8
    top, bottom = max(rows.min() - pad, 0), min(rows.max() + pad + 1, mask.shape[0])
    left, right = max(cols.min() - pad, 0), min(cols.max() + pad + 1, mask.shape[1])
    box = (top, bottom, left, right)
    panels = [_panel(target.numpy(), box, args.zoom, "ground truth")]
    scores = {}
    for model_path, label in zip(args.models, labels):
        model = read_ply(point_cloud_path(model_path, latest_iteration(model_path)), isotropic=True)
        with torch.no_grad():
            rgb = render_model(model, camera, torch.tensor(test.background, dtype=torch.float32))["rgb"].clamp(0, 1)
        value = float(psnr(rgb, target))
        scores[label] = round(value, 2)
        panels.append(_panel(rgb.numpy(), box, args.zoom, f"{label}: {value:.2f} dB"))
    strip = np.concatenate(panels, axis=1)
    cv2.imwrite(args.out, cv2.cvtColor(strip, cv2.COLOR_RGB2BGR))
    print(json.dumps({"view": args.view, "psnr_db": scores, "out": args.out}, indent=2))


if __name__ == "__main__":
    main()
