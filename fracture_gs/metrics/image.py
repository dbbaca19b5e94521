"""Image quality metrics shared by training, static rendering and evaluation.

Images are float tensors in [0, 1], either (H, W, 3) or batched (B, H, W, 3). SSIM is the
one of 3DGS / Wang et al. 2004: an 11 x 11 Gaussian window (sigma 1.5) applied separably,
C1 = 0.01², C2 = 0.03², averaged over pixels and channels ("same" padding with zeros, as the
3DGS training loss does). It is differentiable, so ``1 - ssim`` serves as a loss.
"""
from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def _as_batch(image: torch.Tensor) -> torch.Tensor:
    """(H, W, C) or (B, H, W, C) -> (B, C, H, W)."""
    if image.ndim == 3:
        image = image[None]
    if image.ndim != 4:
        raise ValueError(f"expected an image (H,W,C) or a batch (B,H,W,C), got {tuple(image.shape)}")
    return image.permute(0, 3, 1, 2)


def mse(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Mean squared error per image: a scalar for (H,W,C) inputs, (B,) for batches."""
    if image.shape != reference.shape:
        raise ValueError(f"shapes differ: {tuple(image.shape)} vs {tuple(reference.shape)}")
    error = (image - reference).square()
    return error.mean() if image.ndim == 3 else error.flatten(1).mean(dim=1)


def psnr(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB for a peak of 1 (per image for batches)."""
    return -10.0 * torch.log10(mse(image, reference).clamp_min(1e-12))


@functools.lru_cache(maxsize=8)
def _gaussian_taps(size: int, sigma: float, dtype: torch.dtype,
                   device: torch.device) -> torch.Tensor:
    offsets = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    taps = torch.exp(-offsets.square() / (2 * sigma * sigma))
    return (taps / taps.sum()).to(dtype=dtype, device=device)


def _blur(planes: torch.Tensor, taps: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian blur of (B, C, H, W) with zero padding ("same" size)."""
    channels = planes.shape[1]
    size = taps.numel()
    horizontal = taps.view(1, 1, 1, size).expand(channels, 1, 1, size)
    vertical = taps.view(1, 1, size, 1).expand(channels, 1, size, 1)
    planes = F.conv2d(planes, horizontal, padding=(0, size // 2), groups=channels)
    return F.conv2d(planes, vertical, padding=(size // 2, 0), groups=channels)


def ssim(image: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """Structural similarity (module docstring): a scalar for (H,W,C), (B,) for batches."""
    if image.shape != reference.shape:
        raise ValueError(f"shapes differ: {tuple(image.shape)} vs {tuple(reference.shape)}")
    x, y = _as_batch(image), _as_batch(reference)
    taps = _gaussian_taps(SSIM_WINDOW, SSIM_SIGMA, x.dtype, x.device)
    channels = x.shape[1]
    # One blur call for the five moment images.
    stacked = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), taps)
    mu_x, mu_y, xx, yy, xy = stacked.split(channels, dim=1)
    var_x = xx - mu_x.square()
    var_y = yy - mu_y.square()
    cov = xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)
    denominator = (mu_x.square() + mu_y.square() + SSIM_C1) * (var_x + var_y + SSIM_C2)
    per_image = (numerator / denominator).flatten(1).mean(dim=1)
    return per_image[0] if image.ndim == 3 else per_image
