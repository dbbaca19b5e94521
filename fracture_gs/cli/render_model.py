"""``render.py -m <model>``: render a trained static model like 3DGS's render.py.

Writes ``<model>/{train,test}/ours_<iteration>/{renders,gt}/<index:05d>.png`` for the views
of the dataset recorded in ``<model>/cfg_args`` (background and image scale as trained) and
prints the mean PSNR / SSIM of each split. Exit status 0, or 2 on invalid input (one
``error: ...`` line).
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Sequence

import cv2
import numpy as np
import torch
from tqdm import tqdm

from fracture_gs.cli.output_folder import os_error_line
from fracture_gs.data import Dataset, DatasetError, load_dataset
from fracture_gs.gaussians import PlyFormatError, read_ply
from fracture_gs.metrics.image import psnr, ssim
from fracture_gs.recon.gaussian_fit import render_model
from fracture_gs.recon.model_io import atomic_path, latest_iteration, point_cloud_path, \
    read_cfg_args


class RenderInputError(ValueError):
    """Bad model folder or options; the message names the file or flag."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="render.py",
                                     description="Render a trained static model's views.")
    parser.add_argument("-m", "--model_path", required=True, help="train.py output folder")
    parser.add_argument("-s", "--source_path", default=None,
                        help="dataset folder (default: the one in <model>/cfg_args)")
    parser.add_argument("--iteration", type=int, default=-1,
                        help="point_cloud/iteration_N to render (default: the latest)")
    parser.add_argument("--skip_train", action="store_true")
    parser.add_argument("--skip_test", action="store_true")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--quiet", action="store_true")
    return parser


def _write_png(path: str, image: torch.Tensor) -> None:
    pixels = (image.clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    with atomic_path(path) as temporary:
        if not cv2.imwrite(temporary, cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR),
                           ) or not os.path.isfile(temporary):
            raise OSError(f"{path}: could not write the image")


def render_split(model_path: str, split: str, iteration: int, dataset: Dataset, gaussians,
                 device: torch.device, quiet: bool) -> dict[str, float]:
    """Render every view of ``dataset`` into ``<model>/<split>/ours_<iteration>/``."""
    root = os.path.join(model_path, split, f"ours_{iteration}")
    background = torch.tensor(dataset.background, dtype=torch.float32, device=device)
    psnrs, ssims = [], []
    with torch.no_grad():
        for index in tqdm(range(len(dataset)), desc=f"render {split}", disable=quiet,
                          leave=False, file=sys.stderr):
            rgb = render_model(gaussians, dataset.cameras[index].to(device), background)["rgb"]
            rgb = rgb.clamp(0, 1)
            target = dataset.images[index].to(device)
            _write_png(os.path.join(root, "renders", f"{index:05d}.png"), rgb)
            _write_png(os.path.join(root, "gt", f"{index:05d}.png"), target)
            psnrs.append(float(psnr(rgb, target)))
            ssims.append(float(ssim(rgb, target)))
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "views": len(psnrs)}


def run(args: argparse.Namespace) -> dict[str, dict[str, float]]:
    model_path = args.model_path
    cfg_path = os.path.join(model_path, "cfg_args")
    if not os.path.isdir(model_path):
        raise RenderInputError(f"{model_path}: model folder not found")
    if not os.path.isfile(cfg_path):
        raise RenderInputError(f"{cfg_path}: not found (is {model_path} a train.py output?)")
    try:
        options = read_cfg_args(cfg_path)
    except ValueError as error:
        raise RenderInputError(str(error)) from None
    iteration = args.iteration if args.iteration >= 0 else latest_iteration(model_path)
    if iteration is None:
        raise RenderInputError(f"{os.path.join(model_path, 'point_cloud')}: no "
                               f"iteration_N/point_cloud.ply")
    ply_path = point_cloud_path(model_path, iteration)
    if not os.path.isfile(ply_path):
        raise RenderInputError(f"{ply_path}: not found (--iteration {iteration})")
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise RenderInputError("--device: cuda was requested but no CUDA device is available")
    gaussians = read_ply(ply_path, device=device)
    source = args.source_path or options.get("source_path")
    if not source:
        raise RenderInputError(f"{cfg_path}: no source_path; pass -s <dataset>")
    resolution = int(options.get("resolution", 1))
    white = bool(options.get("white_background", False))
    results = {}
    for split, skip in (("train", args.skip_train), ("test", args.skip_test)):
        if skip:
            continue
        if split == "test" and not os.path.isfile(os.path.join(source, "transforms_test.json")):
            continue
        dataset = load_dataset(source, split, resolution, white)
        results[split] = render_split(model_path, split, iteration, dataset, gaussians, device,
                                      args.quiet)
        print(f"[render] {split}: {results[split]['views']} views, PSNR "
              f"{results[split]['psnr']:.2f} dB, SSIM {results[split]['ssim']:.4f} -> "
              f"{os.path.join(model_path, split, f'ours_{iteration}')}")
    return results


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``render.py -m``; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        run(args)
    except (RenderInputError, DatasetError, PlyFormatError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # writing into the model folder failed (read-only, disk full, ...)
        print(f"error: {os_error_line(error)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
