"""The self-referenced fracture protocol (docs/formulas.md §14, paper App. A.3).

Per view, every window frame is compared with the same view's reference frame I_ref (the
last intact frame): PSNR and LPIPS per image pair, and FID between the set of reference
renders (one per view) and the set of window renders (all views × window frames). FID with
so few images is strongly biased, so the result carries N and a warning. The per-view values
and the Inception features of every image are kept, so that two runs can be compared view by
view (:mod:`fracture_gs.metrics.paired`).

Networks are loaded once (:class:`MetricNetworks`) and reused for every run compared; a
network whose weights are missing is reported as unavailable with the file expected.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np
import torch

from fracture_gs.metrics.batches import image_batch
from fracture_gs.metrics.fid import (INCEPTION_FEATURES, InceptionFeatures,
                                     frechet_distance_from_features, image_features)
from fracture_gs.metrics.lpips_alex import LpipsAlex
from fracture_gs.metrics.weights import WeightsUnavailable

T = TypeVar("T")


@dataclass
class MetricNetworks:
    """LPIPS and FID networks on one device; a missing one holds its "unavailable" line."""

    device: torch.device
    lpips: LpipsAlex | None
    inception: InceptionFeatures | None
    lpips_unavailable: str | None = None
    fid_unavailable: str | None = None

    @classmethod
    def load(cls, device: torch.device, weights_dir: str | Path | None = None,
             lpips: bool = True, fid: bool = True) -> "MetricNetworks":
        """Load the networks asked for; missing weights become ``*_unavailable`` lines."""
        lpips_alex, lpips_unavailable = _load_or_reason(lambda: LpipsAlex.load(device, weights_dir), lpips)
        inception, fid_unavailable = _load_or_reason(lambda: InceptionFeatures.load(device, weights_dir), fid)
        return cls(device=device, lpips=lpips_alex, inception=inception,
                   lpips_unavailable=lpips_unavailable, fid_unavailable=fid_unavailable)


def _load_or_reason(load: Callable[[], T], wanted: bool) -> tuple[T | None, str | None]:
    """``(load(), None)``, or ``(None, "unavailable: ...")`` when not wanted or weights are missing."""
    if not wanted:
        return None, "unavailable: not requested"
    try:
        return load(), None
    except WeightsUnavailable as error:
        return None, str(error)


def psnr_db(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """PSNR (dB, peak 1) of ``(..., H, W, 3)`` images against broadcastable references,
    one value per image (float64); identical images give +inf."""
    squared_error = (images.double() - references.double()).square()
    return -10.0 * torch.log10(squared_error.mean(dim=(-3, -2, -1)))


def fid_bias_warning(n_reference: int, n_window: int) -> str | None:
    """The caveat printed beside a FID computed from few images (None for large sets)."""
    smallest = min(n_reference, n_window)
    if smallest > INCEPTION_FEATURES:
        return None
    return (f"FID from {n_reference} reference and {n_window} window images is biased upward at "
            f"this N (the {INCEPTION_FEATURES}-d covariances have rank <= N-1; published FIDs use "
            f">= 10000 images): compare it only between runs evaluated with the same views and N")


@dataclass
class SelfReferencedMetrics:
    """Metrics of one run: ``psnr`` / ``lpips`` are (views, window frames) arrays;
    ``reference_features`` (views, D) and ``window_features`` (views, window frames, D) are the
    Inception features FID came from (None without FID; not written to JSON)."""

    psnr: np.ndarray
    lpips: np.ndarray | None
    fid: float | None
    n_reference: int
    n_window: int
    lpips_unavailable: str | None = None
    fid_unavailable: str | None = None
    fid_warning: str | None = None
    reference_features: np.ndarray | None = None
    window_features: np.ndarray | None = None

    def to_json(self) -> dict:
        """Means and per-view values as plain JSON (+inf PSNR of identical images as "inf")."""
        def number(value: float) -> float | str:
            return float(value) if math.isfinite(value) else str(float(value))

        def per_view(values: np.ndarray) -> dict:
            return {"mean": number(values.mean()),
                    "per_view": [[number(v) for v in row] for row in values]}

        return {"psnr": per_view(self.psnr),
                "lpips": per_view(self.lpips) if self.lpips is not None else self.lpips_unavailable,
                "fid": number(self.fid) if self.fid is not None else self.fid_unavailable,
                "n_reference": self.n_reference, "n_window": self.n_window,
                "fid_warning": self.fid_warning}


def self_referenced_metrics(reference_images: torch.Tensor | np.ndarray,
                            window_images: torch.Tensor | np.ndarray,
                            networks: MetricNetworks, batch_size: int = 8) -> SelfReferencedMetrics:
    """PSNR / LPIPS of every window frame against its view's reference frame, and FID between
    the reference set and the window set.

    ``reference_images``: ``(V, H, W, 3)``, one I_ref render per view; ``window_images``:
    ``(V, T, H, W, 3)``, the T window frames of each view; float in [0, 1] (or uint8).
    """
    references = image_batch(reference_images, "reference_images")
    window = torch.as_tensor(window_images)
    if window.dim() != 5 or tuple(window.shape[0:1]) + tuple(window.shape[2:]) != tuple(references.shape):
        raise ValueError(f"window_images must be (V, T, H, W, 3) matching reference_images "
                         f"{tuple(references.shape)}, got {tuple(window.shape)}")
    views, frames = window.shape[:2]
    window_flat = image_batch(window.reshape(views * frames, *window.shape[2:]), "window_images")
    references_per_pair = references.repeat_interleave(frames, dim=0)

    psnr = psnr_db(window_flat, references_per_pair).reshape(views, frames).numpy()
    lpips = None
    if networks.lpips is not None:
        lpips = networks.lpips.distance(references_per_pair, window_flat, batch_size)
        lpips = lpips.reshape(views, frames).numpy()

    n_reference, n_window = int(references.shape[0]), int(window_flat.shape[0])
    fid, fid_unavailable = None, networks.fid_unavailable
    reference_features = window_features = None
    if networks.inception is not None:
        if min(n_reference, n_window) < 2:
            fid_unavailable = (f"unavailable: FID needs at least 2 images per set "
                               f"(got {n_reference} reference, {n_window} window)")
        else:
            reference_rows = image_features(networks.inception, references, networks.device,
                                            batch_size)
            window_rows = image_features(networks.inception, window_flat, networks.device,
                                         batch_size)
            fid = frechet_distance_from_features(reference_rows, window_rows)
            reference_features = reference_rows.numpy()
            window_features = window_rows.reshape(views, frames, -1).numpy()
    return SelfReferencedMetrics(
        psnr=psnr, lpips=lpips, fid=fid, n_reference=n_reference, n_window=n_window,
        lpips_unavailable=networks.lpips_unavailable, fid_unavailable=fid_unavailable,
        fid_warning=fid_bias_warning(n_reference, n_window) if fid is not None else None,
        reference_features=reference_features, window_features=window_features)
