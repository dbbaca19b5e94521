#!/usr/bin/env python3
"""Halo of a trained model in its test renders, as JSON.

    python train.py -s <DTU folder> -m out -r 4 --holdout-every 8
    python render.py -m out
    python benchmarks/halo.py -m out [--split test] [--dilate-px 4] [--threshold 10]

Reads the renders ``render.py -m`` wrote (``<model>/<split>/ours_<N>/renders/``) and the object
masks of the same views from the model's dataset (the resolution and hold-out it was trained
with), and prints per view and over all views the share of the pixels outside the mask dilated by
``--dilate-px`` whose colour differs from the training background by more than ``--threshold``
(out of 255, largest channel): background fitted into the splats shows there
(:mod:`fracture_gs.metrics.halo`).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_gs.data import DatasetError, load_dataset  # noqa: E402
from fracture_gs.folders.model_folder import read_cfg_args  # noqa: E402
from fracture_gs.io.model_layout import (CFG_ARGS_FILE, RENDERED_DIR, latest_iteration,  # noqa: E402
                                         split_render_dir, view_image_name)
from fracture_gs.metrics.halo import DEFAULT_DILATE_PX, halo  # noqa: E402


def measure(model: str, split: str, dilate_px: int, threshold: float) -> dict:
    options = read_cfg_args(os.path.join(model, CFG_ARGS_FILE))
    iteration = latest_iteration(model)
    if iteration is None:
        raise ValueError(f"{model}: no point_cloud/iteration_N (not a train.py model folder)")
    renders = os.path.join(split_render_dir(model, split, iteration), RENDERED_DIR)
    dataset = load_dataset(options["source_path"], split, int(options.get("resolution", 1)),
                           bool(options.get("white_background", False)),
                           int(options.get("holdout_every", 0)))
    if dataset.masks is None:
        raise ValueError(f"{options['source_path']}: the dataset has no masks")
    views = []
    for index in range(len(dataset)):
        path = os.path.join(renders, view_image_name(index))
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{path}: missing or unreadable (run render.py -m {model} first)")
        result = halo(image[:, :, ::-1].astype(np.float32) / 255.0, dataset.masks[index].numpy(),
                      dataset.background, dilate_px, threshold / 255.0)
        views.append({"view": os.path.basename(dataset.image_paths[index]),
                      "outside_pixels": result.outside, "differing_pixels": result.differing,
                      "share": result.share})
    outside = sum(v["outside_pixels"] for v in views)
    differing = sum(v["differing_pixels"] for v in views)
    return {"model": model, "split": split, "iteration": iteration,
            "image_size": [dataset.width, dataset.height], "background": list(dataset.background),
            "dilate_px": dilate_px, "threshold": threshold,
            "share": differing / outside if outside else 0.0,
            "largest_view_share": max(v["share"] for v in views), "views": views}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-m", "--model_path", required=True, help="train.py model folder")
    parser.add_argument("--split", choices=("test", "train"), default="test")
    parser.add_argument("--dilate-px", type=int, default=DEFAULT_DILATE_PX,
                        help=f"mask dilation in pixels (default {DEFAULT_DILATE_PX})")
    parser.add_argument("--threshold", type=float, default=10.0,
                        help="colour difference from the background that counts, out of 255 "
                        "(default 10)")
    args = parser.parse_args(argv)
    try:
        result = measure(args.model_path, args.split, args.dilate_px, args.threshold)
    except (OSError, ValueError, KeyError, DatasetError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
