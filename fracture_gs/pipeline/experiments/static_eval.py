"""Static metrics of a trained model on its test views (like 3DGS's ``metrics.py``).

Reads ``<model>/test/ours_<N>/{renders,gt}/<index:05d>.png`` (written by ``render.py -m``;
rendered here first when missing) and computes PSNR, SSIM and LPIPS (AlexNet) per view. Writes
3DGS's ``results.json`` / ``per_view.json`` into the model folder.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.model_layout import (GROUND_TRUTH_DIR, RENDERED_DIR, latest_iteration,
                                         split_render_dir)
from fracture_gs.metrics.image import psnr, ssim
from fracture_gs.metrics.protocol import MetricNetworks
from fracture_gs.pipeline.experiments.sim_eval import EvaluationError


@dataclass
class StaticResult:
    """Per-view and mean PSNR / SSIM / LPIPS of one model's test split."""

    model: Path
    iteration: int
    split: str
    names: list[str]
    psnr: np.ndarray
    ssim: np.ndarray
    lpips: np.ndarray | None
    lpips_unavailable: str | None
    sample: tuple[np.ndarray, np.ndarray] | None   # (render, gt) of the first view, uint8

    def to_json(self) -> dict:
        lpips = float(self.lpips.mean()) if self.lpips is not None else self.lpips_unavailable
        return {"model": str(self.model), "iteration": self.iteration, "split": self.split,
                "views": len(self.names), "PSNR": float(self.psnr.mean()),
                "SSIM": float(self.ssim.mean()), "LPIPS": lpips}


def _read_png(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise EvaluationError(f"{path}: unreadable image")
    return np.ascontiguousarray(image[..., ::-1])


def _render_folder(model: Path, split: str, device: torch.device) -> tuple[Path, int]:
    """``<model>/<split>/ours_<N>`` holding renders/ and gt/, rendered if missing."""
    from fracture_gs.data import DatasetError
    from fracture_gs.gaussians import PlyFormatError
    from fracture_gs.pipeline.render_model import RenderInputError, render_model

    if not model.is_dir():
        raise EvaluationError(f"{model}: model folder not found")
    iteration = latest_iteration(str(model))
    if iteration is None:
        raise EvaluationError(f"{model / 'point_cloud'}: no iteration_N/point_cloud.ply "
                              "(is it a train.py output folder?)")
    folder = Path(split_render_dir(str(model), split, iteration))
    if not (folder / RENDERED_DIR).is_dir() or not (folder / GROUND_TRUTH_DIR).is_dir():
        try:
            render_model(str(model), iteration=iteration, skip_train=split != "train",
                         skip_test=split != "test", device=device.type, quiet=True)
        except (RenderInputError, DatasetError, PlyFormatError) as exc:
            raise EvaluationError(str(exc)) from None
    if not (folder / RENDERED_DIR).is_dir():
        raise EvaluationError(f"{folder}: no renders/ (the dataset has no {split} split; a "
                              f"COLMAP or DTU folder has one when train.py ran with "
                              f"--holdout-every N)")
    return folder, iteration


def evaluate_model(model: Path, networks: MetricNetworks, split: str = "test",
                   device: torch.device | None = None) -> StaticResult:
    """PSNR / SSIM / LPIPS of every ``split`` view (module docstring); writes results.json and
    per_view.json into the model folder."""
    device = device if device is not None else torch.device("cpu")
    folder, iteration = _render_folder(Path(model), split, device)
    names = sorted(p.name for p in (folder / RENDERED_DIR).glob("*.png"))
    if not names:
        raise EvaluationError(f"{folder / 'renders'}: no images")
    renders = np.stack([_read_png(folder / RENDERED_DIR / n) for n in names])
    gts = np.stack([_read_png(folder / GROUND_TRUTH_DIR / n) for n in names])
    if renders.shape != gts.shape:
        raise EvaluationError(f"{folder}: renders/ and gt/ images differ in size")
    render_t = torch.from_numpy(renders).float() / 255.0
    gt_t = torch.from_numpy(gts).float() / 255.0
    psnrs = psnr(render_t, gt_t).double().numpy()
    ssims = ssim(render_t, gt_t).double().numpy()
    lpips = networks.lpips.distance(render_t, gt_t).double().numpy() if networks.lpips else None
    result = StaticResult(Path(model), iteration, split, names, psnrs, ssims, lpips,
                          networks.lpips_unavailable, (renders[0], gts[0]))
    method = f"ours_{iteration}"
    summary = result.to_json()
    write_text_atomic(Path(model) / "results.json", json.dumps(
        {method: {"SSIM": summary["SSIM"], "PSNR": summary["PSNR"], "LPIPS": summary["LPIPS"]}},
        indent=2) + "\n")
    per_view = {"SSIM": dict(zip(names, map(float, ssims))),
                "PSNR": dict(zip(names, map(float, psnrs))),
                "LPIPS": dict(zip(names, map(float, lpips))) if lpips is not None
                else result.lpips_unavailable}
    write_text_atomic(Path(model) / "per_view.json", json.dumps({method: per_view}, indent=2) + "\n")
    return result
