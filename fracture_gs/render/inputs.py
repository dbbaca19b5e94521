"""Validation of the rasterizer's arguments, shared by the compiled path and the reference."""
from __future__ import annotations

from dataclasses import dataclass

import torch

from fracture_gs.render.camera import Camera

SH_COEFFICIENT_COUNTS = {1: 0, 4: 1, 9: 2, 16: 3}


@dataclass
class RasterInputs:
    """The checked per-Gaussian inputs of one rasterize call (see ``rasterize``)."""

    means: torch.Tensor
    opacities: torch.Tensor
    scales: torch.Tensor | None
    quats: torch.Tensor | None
    covariances: torch.Tensor | None
    sh: torch.Tensor | None
    colors: torch.Tensor | None
    background: torch.Tensor
    exclusive: torch.Tensor | None
    view_rotations: torch.Tensor | None

    @property
    def sh_degree(self) -> int:
        """SH degree (0-3); 0 as well when precomputed colours are given."""
        return 0 if self.sh is None else SH_COEFFICIENT_COUNTS[self.sh.shape[1]]


def _check_shape(name: str, tensor: torch.Tensor | None, shape: tuple[int, ...],
                 device: torch.device) -> None:
    if tensor is None:
        return
    if not isinstance(tensor, torch.Tensor):
        raise ValueError(f"rasterize: {name} must be a torch.Tensor, got {type(tensor).__name__}")
    if tuple(tensor.shape) != shape:
        raise ValueError(f"rasterize: {name} must have shape {shape}, got {tuple(tensor.shape)}")
    if tensor.device != device:
        raise ValueError(f"rasterize: {name} is on {tensor.device}, means are on {device}")


def check_inputs(means: torch.Tensor, opacities: torch.Tensor, camera: Camera, *,
                 scales: torch.Tensor | None, quats: torch.Tensor | None,
                 covariances: torch.Tensor | None, sh: torch.Tensor | None,
                 colors: torch.Tensor | None, background: torch.Tensor | None,
                 exclusive: torch.Tensor | None,
                 view_rotations: torch.Tensor | None) -> RasterInputs:
    """Check shapes, devices and the either/or arguments; raise ValueError naming the argument.

    Opacities may be (N,) or (N, 1); the returned ``opacities`` is (N,). A missing background
    becomes black (3,), in the means' dtype and device.
    """
    if not isinstance(camera, Camera):
        raise ValueError(f"rasterize: camera must be a fracture_gs.render.Camera, got {type(camera).__name__}")
    if not isinstance(means, torch.Tensor) or means.dim() != 2 or means.shape[1] != 3:
        shape = tuple(means.shape) if isinstance(means, torch.Tensor) else type(means).__name__
        raise ValueError(f"rasterize: means must have shape (N, 3), got {shape}")
    if not means.is_floating_point():
        raise ValueError(f"rasterize: means must be floating point, got {means.dtype}")
    n, device = means.shape[0], means.device
    if isinstance(opacities, torch.Tensor) and opacities.dim() == 2 and opacities.shape[1] == 1:
        opacities = opacities[:, 0]
    _check_shape("opacities", opacities, (n,), device)
    if (scales is None) != (quats is None):
        raise ValueError("rasterize: scales and quats must be given together")
    if (scales is None) == (covariances is None):
        raise ValueError("rasterize: give exactly one of scales+quats or covariances")
    _check_shape("scales", scales, (n, 3), device)
    _check_shape("quats", quats, (n, 4), device)
    _check_shape("covariances", covariances, (n, 3, 3), device)
    if (sh is None) == (colors is None):
        raise ValueError("rasterize: give exactly one of sh or colors")
    if sh is not None:
        if sh.dim() != 3 or sh.shape[1] not in SH_COEFFICIENT_COUNTS:
            raise ValueError(f"rasterize: sh must have shape (N, K, 3) with K in 1, 4, 9, 16, "
                             f"got {tuple(sh.shape)}")
        _check_shape("sh", sh, (n, sh.shape[1], 3), device)
    _check_shape("colors", colors, (n, 3), device)
    _check_shape("view_rotations", view_rotations, (n, 3, 3), device)
    if view_rotations is not None and sh is None:
        raise ValueError("rasterize: view_rotations only apply to sh colours")
    if exclusive is not None:
        _check_shape("exclusive", exclusive, (n,), device)
        if exclusive.dtype not in (torch.bool, torch.int8, torch.int16, torch.int32, torch.int64):
            # uint8 is refused too: 0/1 flags in it would silently read as groups 0 and 1
            raise ValueError("rasterize: exclusive must be a bool tensor (global rule) or a "
                             f"signed integer tensor of group ids (group rule), got {exclusive.dtype}")
    if background is None:
        background = torch.zeros(3, dtype=means.dtype, device=device)
    _check_shape("background", background, (3,), device)
    return RasterInputs(means, opacities, scales, quats, covariances, sh, colors, background,
                        exclusive, view_rotations)
