"""Checking and converting image batches for the metric networks.

Metric inputs follow the renderer's convention: RGB, channel-last ``(H, W, 3)`` or
``(N, H, W, 3)``, float in [0, 1] (uint8 in [0, 255] is accepted and scaled).
"""
from __future__ import annotations

import numpy as np
import torch



def image_batch(images: torch.Tensor | np.ndarray, name: str = "images") -> torch.Tensor:
    """``images`` as a float32 ``(N, H, W, 3)`` tensor in [0, 1] (same device as given).

    Raises ValueError with a one-line message for a wrong shape, NaN/Inf or values
    outside [0, 1].
    """
    tensor = torch.as_tensor(images)
    if tensor.dtype == torch.uint8:
        tensor = tensor.float() / 255.0
    elif not tensor.is_floating_point():
        raise ValueError(f"{name}: expected float or uint8 pixels, got {tensor.dtype}")
    if tensor.dim() == 3:
        tensor = tensor.unsqueeze(0)
    if tensor.dim() != 4 or tensor.shape[-1] != 3:
        raise ValueError(f"{name}: expected shape (H, W, 3) or (N, H, W, 3), got {tuple(tensor.shape)}")
    if tensor.shape[0] == 0:
        raise ValueError(f"{name}: no images")
    tensor = tensor.float()
    if not bool(torch.isfinite(tensor).all()):
        raise ValueError(f"{name}: contains NaN or Inf pixels")
    low, high = float(tensor.min()), float(tensor.max())
    if low < 0.0 or high > 1.0:
        raise ValueError(f"{name}: pixel values must lie in [0, 1], got [{low:.4g}, {high:.4g}]")
    return tensor


def channels_first(images: torch.Tensor) -> torch.Tensor:
    """``(N, H, W, 3)`` → contiguous ``(N, 3, H, W)``."""
    return images.permute(0, 3, 1, 2).contiguous()


def batch_slices(count: int, batch_size: int) -> list[slice]:
    """Consecutive slices of at most ``batch_size`` items covering ``range(count)``."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    return [slice(start, min(start + batch_size, count)) for start in range(0, count, batch_size)]
