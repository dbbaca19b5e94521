"""Isotropic Gaussians on the surface particles, fitted with the differentiable rasterizer.

One Gaussian per surface particle (paper §3, "surface particles learn Gaussian attributes
using isotropic kernels"): SH colour (degree raised progressively like 3DGS), opacity and a
single log-scale are learned with Adam (3DGS's parameter groups; the learning rates are the
caller's, see ``fracture_gs.recon.pipeline.PRESETS``), against the loss
``(1 - λ) L1 + λ (1 - SSIM)``, λ = 0.2, one training view per iteration (3DGS's shuffled
view stack). Positions may move by at most ``max_offset`` x the particle spacing from their
particle (projected back after every step), so that particles stay at the surface; the
moved positions become the particles' positions. An isotropic Gaussian centred on the
surface reaches about one standard deviation (plus the rasterizer's 0.3 px² low-pass) past
it, which bloats every silhouette; with a bound of one spacing the fit moves the Gaussians
that far inwards and the silhouettes close up (teapot test PSNR 29.3 dB with a bound of
0.25 spacing, 33.6 dB with 1; docs/training.md shows the two renders).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from fracture_gs.data.dataset import Dataset
from fracture_gs.gaussians import GaussianModel
from fracture_gs.metrics.image import psnr, ssim
from fracture_gs.render import Camera, rasterize

LAMBDA_DSSIM = 0.2


@dataclass
class FitSettings:
    """Gaussian-stage settings (3DGS names and learning rates)."""

    iterations: int = 3000
    sh_degree: int = 3
    sh_interval: int = 1000          # iterations per SH degree step (3DGS: 1000)
    max_offset: float = 1.0          # bound of the position refinement, x particle spacing
    position_lr_init: float = 1.6e-4
    position_lr_final: float = 1.6e-6
    feature_lr: float = 2.5e-3
    opacity_lr: float = 2.5e-2
    scaling_lr: float = 5e-3
    initial_opacity: float = 0.7
    lambda_dssim: float = LAMBDA_DSSIM
    seed: int = 0


def position_learning_rate(settings: FitSettings, iteration: int) -> float:
    """3DGS's exponential decay from ``position_lr_init`` to ``position_lr_final``."""
    fraction = min(max(iteration / max(settings.iterations, 1), 0.0), 1.0)
    return math.exp((1 - fraction) * math.log(settings.position_lr_init)
                    + fraction * math.log(settings.position_lr_final))


def active_sh_degree(settings: FitSettings, iteration: int) -> int:
    """SH degree in use at ``iteration`` (one degree more every ``sh_interval`` steps)."""
    return min(settings.sh_degree, iteration // max(settings.sh_interval, 1))


def initial_model(positions: np.ndarray, colors: np.ndarray | None,
                  settings: FitSettings, device: torch.device) -> GaussianModel:
    """Isotropic Gaussians at ``positions`` with scales from the 3 nearest neighbours."""
    model = GaussianModel.from_points(torch.from_numpy(positions).float(),
                                      None if colors is None else
                                      torch.from_numpy(colors).float().clamp(0.02, 0.98),
                                      sh_degree=settings.sh_degree, isotropic=True,
                                      initial_opacity=settings.initial_opacity)
    return model.to(device)


def render_model(model: GaussianModel, camera: Camera, background: torch.Tensor,
                 sh_degree: int | None = None) -> dict[str, torch.Tensor]:
    """Render ``model`` (SH truncated to ``sh_degree`` if given)."""
    sh = model.sh
    if sh_degree is not None:
        sh = sh[:, :(sh_degree + 1) ** 2]
    return rasterize(model.means, model.opacities, camera, scales=model.scales,
                     quats=model.rotations, sh=sh, background=background)


def make_optimizer(model: GaussianModel, settings: FitSettings,
                   spatial_scale: float) -> torch.optim.Adam:
    """Adam over every parameter but the (unused) rotation of the isotropic Gaussians."""
    groups = model.param_groups(spatial_lr_scale=spatial_scale,
                                means_lr=settings.position_lr_init,
                                sh_dc_lr=settings.feature_lr, opacity_lr=settings.opacity_lr,
                                scaling_lr=settings.scaling_lr)
    return torch.optim.Adam([g for g in groups if g["name"] != "quats"], lr=0.0, eps=1e-15)


def project_offsets(model: GaussianModel, anchors: torch.Tensor, bound: float) -> None:
    """Pull every mean back to within ``bound`` of its anchor (in place)."""
    with torch.no_grad():
        offset = model.means - anchors
        length = offset.norm(dim=1, keepdim=True)
        scale = torch.where(length > bound, bound / length.clamp_min(1e-12),
                            torch.ones_like(length))
        model.means.copy_(anchors + offset * scale)


@dataclass
class FitState:
    """Everything needed to continue fitting (what a checkpoint stores)."""

    model: GaussianModel
    optimizer: torch.optim.Adam
    anchors: torch.Tensor
    iteration: int
    view_order: list[int]


def new_fit_state(positions: np.ndarray, colors: np.ndarray | None, settings: FitSettings,
                  spatial_scale: float, device: torch.device) -> FitState:
    model = initial_model(positions, colors, settings, device)
    return FitState(model, make_optimizer(model, settings, spatial_scale),
                    model.means.detach().clone(), 0, [])


def fit_gaussians(state: FitState, dataset: Dataset, settings: FitSettings, spacing: float,
                  generator: np.random.Generator,
                  on_step: Callable[[FitState, dict], None] | None = None) -> FitState:
    """Run the fitting from ``state.iteration`` to ``settings.iterations``.

    ``on_step(state, row)`` is called after every iteration with the loss and PSNR of that
    iteration's view (the CLI uses it for the progress bar, the log and checkpoints).
    """
    device = state.model.device
    background = torch.tensor(dataset.background, dtype=torch.float32, device=device)
    images = dataset.images
    bound = settings.max_offset * spacing
    means_group = next(g for g in state.optimizer.param_groups if g["name"] == "means")
    spatial_scale = means_group.get("spatial_scale", None)
    if spatial_scale is None:
        spatial_scale = means_group["lr"] / settings.position_lr_init
        means_group["spatial_scale"] = spatial_scale
    while state.iteration < settings.iterations:
        if not state.view_order:
            state.view_order = [int(v) for v in generator.permutation(len(dataset))]
        view = state.view_order.pop()
        means_group["lr"] = position_learning_rate(settings, state.iteration) * spatial_scale
        degree = active_sh_degree(settings, state.iteration)
        target = images[view].to(device)
        out = render_model(state.model, dataset.cameras[view].to(device), background, degree)
        l1 = (out["rgb"] - target).abs().mean()
        loss = (1 - settings.lambda_dssim) * l1 + settings.lambda_dssim * (
            1 - ssim(out["rgb"], target))
        state.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        state.optimizer.step()
        if bound > 0:
            project_offsets(state.model, state.anchors, bound)
        else:
            with torch.no_grad():
                state.model.means.copy_(state.anchors)
        state.iteration += 1
        if on_step is not None:
            with torch.no_grad():
                value = float(psnr(out["rgb"].detach(), target))
            on_step(state, {"stage": "gaussians", "iteration": state.iteration,
                            "loss": loss.item(), "psnr": value, "sh_degree": degree})
    return state


def evaluate_views(model: GaussianModel, dataset: Dataset,
                   device: torch.device) -> dict[str, float]:
    """Mean PSNR and SSIM of ``model`` over all views of ``dataset``."""
    background = torch.tensor(dataset.background, dtype=torch.float32, device=device)
    psnrs, ssims = [], []
    with torch.no_grad():
        for camera, image in zip(dataset.cameras, dataset.images):
            rgb = render_model(model, camera.to(device), background)["rgb"].clamp(0, 1)
            target = image.to(device)
            psnrs.append(float(psnr(rgb, target)))
            ssims.append(float(ssim(rgb, target)))
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)), "views": len(psnrs)}
