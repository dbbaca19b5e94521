"""Rendering a trained static model like 3DGS's render.py (``render.py -m``).

Writes ``<model>/{train,test}/ours_<iteration>/{renders,gt}/<index:05d>.png`` for the views of
the dataset recorded in ``<model>/cfg_args`` (background and image scale as trained), records
them in that folder's manifest, and returns the mean PSNR / SSIM of each split. The test split
is the dataset's own (Blender) or the views ``train.py --holdout-every`` held out (COLMAP, DTU).
One render at a time writes a split's folder (its lock ``.render.lock``), only where no file is
in the way that the tools did not write there, replacing the files of the earlier render of that
folder.
"""
from __future__ import annotations

import os
import sys

import cv2
import numpy as np
import torch
from tqdm import tqdm

from fracture_gs.data import Dataset, load_dataset
from fracture_gs.data.loading import has_test_split
from fracture_gs.folders.model_folder import read_cfg_args
from fracture_gs.gaussians import GaussianModel, read_ply
from fracture_gs.io.atomic import atomic_path
from fracture_gs.io.device import DeviceError, resolve_device
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import claim_folder, replace_written
from fracture_gs.io.model_layout import (CFG_ARGS_FILE, GROUND_TRUTH_DIR, POINT_CLOUD_DIR,
                                         RENDERED_DIR, latest_iteration, point_cloud_path,
                                         split_render_dir, view_image_name)
from fracture_gs.metrics.image import psnr, ssim
from fracture_gs.recon.gaussian_fit import render_model as render_gaussians


LOCK_FILE = ".render.lock"
KIND = "model-render"         # the manifest kind of a split's render folder


class RenderInputError(ValueError):
    """Bad model folder or options; the message names the file or flag."""


def _write_png(path: str, image: torch.Tensor) -> None:
    pixels = (image.clamp(0, 1).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
    with atomic_path(path) as temporary:
        if not cv2.imwrite(str(temporary), cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)) or \
                not os.path.isfile(temporary):
            raise OSError(f"{path}: could not write the image")


def render_split(model_path: str, split: str, iteration: int, dataset: Dataset,
                 gaussians: GaussianModel, device: torch.device, quiet: bool) -> dict[str, float]:
    """Render every view of ``dataset`` into ``<model>/<split>/ours_<iteration>/``."""
    root = split_render_dir(model_path, split, iteration)
    files = [os.path.join(root, kind, view_image_name(index)) for index in range(len(dataset))
             for kind in (RENDERED_DIR, GROUND_TRUTH_DIR)]
    with folder_lock(root, LOCK_FILE, "render.py -m", "render folder"):
        replace_written(claim_folder(root, KIND, files, option="-m"), files)
        return _render_views(root, dataset, gaussians, device, quiet, split)


def _render_views(root: str, dataset: Dataset, gaussians: GaussianModel, device: torch.device,
                  quiet: bool, split: str) -> dict[str, float]:
    """:func:`render_split` once its folder is locked and claimed."""
    background = torch.tensor(dataset.background, dtype=torch.float32, device=device)
    psnrs, ssims = [], []
    with torch.no_grad():
        for index in tqdm(range(len(dataset)), desc=f"render {split}", disable=quiet,
                          leave=False, file=sys.stderr):
            rgb = render_gaussians(gaussians, dataset.cameras[index].to(device), background)["rgb"]
            rgb = rgb.clamp(0, 1)
            target = dataset.images[index].to(device)
            _write_png(os.path.join(root, RENDERED_DIR, view_image_name(index)), rgb)
            _write_png(os.path.join(root, GROUND_TRUTH_DIR, view_image_name(index)), target)
            psnrs.append(float(psnr(rgb, target)))
            ssims.append(float(ssim(rgb, target)))
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "views": len(psnrs)}


def render_model(model_path: str, *, source_path: str | None = None, iteration: int = -1,
                 skip_train: bool = False, skip_test: bool = False, device: str | None = "cpu",
                 quiet: bool = False) -> dict[str, dict[str, float]]:
    """Render the views of a trained model's dataset (module docstring); ``iteration`` -1 is
    the latest. Returns PSNR / SSIM / view count per split rendered. RenderInputError (and the
    dataset's and PLY reader's errors) for bad input."""
    cfg_path = os.path.join(model_path, CFG_ARGS_FILE)
    if not os.path.isdir(model_path):
        raise RenderInputError(f"{model_path}: model folder not found")
    if not os.path.isfile(cfg_path):
        raise RenderInputError(f"{cfg_path}: not found (is {model_path} a train.py output?)")
    try:
        options = read_cfg_args(cfg_path)
    except ValueError as error:
        raise RenderInputError(str(error)) from None
    iteration = iteration if iteration >= 0 else latest_iteration(model_path)
    if iteration is None:
        raise RenderInputError(f"{os.path.join(model_path, POINT_CLOUD_DIR)}: no "
                               f"iteration_N/point_cloud.ply")
    ply_path = point_cloud_path(model_path, iteration)
    if not os.path.isfile(ply_path):
        raise RenderInputError(f"{ply_path}: not found (--iteration {iteration})")
    try:
        torch_device = resolve_device(device)
    except DeviceError as error:
        raise RenderInputError(str(error)) from None
    gaussians = read_ply(ply_path, device=torch_device)
    source = source_path or options.get("source_path")
    if not source:
        raise RenderInputError(f"{cfg_path}: no source_path; pass -s <dataset>")
    resolution = int(options.get("resolution", 1))
    white = bool(options.get("white_background", False))
    holdout_every = int(options.get("holdout_every", 0))
    results = {}
    for split, skip in (("train", skip_train), ("test", skip_test)):
        if skip:
            continue
        if split == "test" and not has_test_split(source, holdout_every):
            continue
        dataset = load_dataset(source, split, resolution, white, holdout_every)
        results[split] = render_split(model_path, split, iteration, dataset, gaussians,
                                      torch_device, quiet)
        print(f"[render] {split}: {results[split]['views']} views, PSNR "
              f"{results[split]['psnr']:.2f} dB, SSIM {results[split]['ssim']:.4f} -> "
              f"{split_render_dir(model_path, split, iteration)}")
    return results
