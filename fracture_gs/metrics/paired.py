"""Paired comparison of two runs evaluated on the same views and window frames.

The ablation asks which of two renderings of a fracture stays closer to the intact reference.
The runs share their cameras, so the comparison is paired: per view, the difference of the two
runs' PSNR (or LPIPS) averaged over the window frames. How much that difference can be trusted
comes from a bootstrap over the views (the frames of one view are strongly correlated, the
views much less): views are drawn with replacement, ``resamples`` times, and the mean difference
recomputed; the interval holds the central ``confidence`` share of those means. FID is one
number per image set, so its difference is recomputed on the same resampled views (the
reference image and the window images of each drawn view) from the kept Inception features.

Signs: an ``advantage`` is positive where the *first* run is better — PSNR(first) − PSNR(second),
LPIPS(second) − LPIPS(first), FID(second) − FID(first).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fracture_gs.metrics.fid import frechet_distance_from_features
from fracture_gs.metrics.protocol import SelfReferencedMetrics

DEFAULT_RESAMPLES = 2000
DEFAULT_CONFIDENCE = 0.95


@dataclass(frozen=True)
class PairedDifference:
    """The first run's advantage in one metric, with its bootstrap interval over views."""

    metric: str                 # "psnr" | "lpips" | "fid"
    advantage: float            # positive: the first run is closer to the reference
    low: float                  # bootstrap interval of the advantage
    high: float
    views_better: int | None    # views where the first run's window mean is better (not FID)
    views: int

    @property
    def verdict(self) -> str:
        """"first better" / "first worse" when the interval excludes 0, else "no clear difference"."""
        if self.low > 0.0:
            return "first better"
        if self.high < 0.0:
            return "first worse"
        return "no clear difference"

    def to_json(self) -> dict:
        """Plain JSON."""
        return {"advantage": self.advantage, "interval": [self.low, self.high],
                "views_better": self.views_better, "views": self.views, "verdict": self.verdict}


def view_resamples(views: int, resamples: int, seed: int) -> np.ndarray:
    """(resamples, views) int: view indices drawn with replacement (fixed seed: reproducible)."""
    if views < 1 or resamples < 1:
        raise ValueError(f"need at least one view and one resample, got {views} and {resamples}")
    return np.random.default_rng(seed).integers(0, views, size=(resamples, views))


def _interval(samples: np.ndarray, confidence: float) -> tuple[float, float]:
    tail = 50.0 * (1.0 - confidence)
    low, high = np.percentile(samples, [tail, 100.0 - tail])
    return float(low), float(high)


def _per_view_difference(metric: str, first: np.ndarray, second: np.ndarray,
                         draws: np.ndarray, confidence: float) -> PairedDifference | None:
    """Advantage of per-view means (first − second for PSNR, second − first for LPIPS)."""
    if not (np.isfinite(first).all() and np.isfinite(second).all()):
        return None                      # identical images give PSNR = inf: no mean difference
    sign = 1.0 if metric == "psnr" else -1.0
    per_view = sign * (first.mean(axis=1) - second.mean(axis=1))
    low, high = _interval(per_view[draws].mean(axis=1), confidence)
    return PairedDifference(metric, float(per_view.mean()), low, high,
                            int((per_view > 0).sum()), int(per_view.size))


def _fid_of_views(reference: torch.Tensor, window: torch.Tensor, draws: np.ndarray) -> np.ndarray:
    """FID of the reference and window features of the drawn views, one value per draw."""
    values = []
    for draw in draws:
        rows = torch.from_numpy(draw)
        values.append(frechet_distance_from_features(reference[rows],
                                                     window[rows].reshape(-1, window.shape[-1])))
    return np.asarray(values)


def _fid_difference(first: SelfReferencedMetrics, second: SelfReferencedMetrics,
                    draws: np.ndarray, confidence: float) -> PairedDifference | None:
    """FID(second) − FID(first) and its interval from FIDs recomputed on resampled views."""
    if any(m.fid is None or m.reference_features is None or m.window_features is None
           for m in (first, second)):
        return None
    features = [(torch.from_numpy(m.reference_features), torch.from_numpy(m.window_features))
                for m in (first, second)]
    fid_first, fid_second = (_fid_of_views(reference, window, draws)
                             for reference, window in features)
    low, high = _interval(fid_second - fid_first, confidence)
    return PairedDifference("fid", float(second.fid - first.fid), low, high, None,
                            int(first.psnr.shape[0]))


def paired_differences(first: SelfReferencedMetrics, second: SelfReferencedMetrics,
                       resamples: int = DEFAULT_RESAMPLES, confidence: float = DEFAULT_CONFIDENCE,
                       seed: int = 0) -> dict[str, PairedDifference]:
    """The first run's advantage over the second in PSNR, LPIPS and FID (those both runs have),
    each with a bootstrap interval over the views (module docstring).

    Both runs must have the same (views, window frames), with at least 2 views (one view has no
    spread to draw from).
    """
    if first.psnr.shape != second.psnr.shape:
        raise ValueError(f"runs are not paired: {first.psnr.shape} and {second.psnr.shape} "
                         "(views, window frames)")
    if first.psnr.shape[0] < 2:
        raise ValueError(f"a paired comparison needs at least 2 views, got {first.psnr.shape[0]}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    draws = view_resamples(first.psnr.shape[0], resamples, seed)
    out: dict[str, PairedDifference] = {}
    found = [_per_view_difference("psnr", first.psnr, second.psnr, draws, confidence)]
    if first.lpips is not None and second.lpips is not None:
        found.append(_per_view_difference("lpips", first.lpips, second.lpips, draws, confidence))
    found.append(_fid_difference(first, second, draws, confidence))
    for difference in found:
        if difference is not None:
            out[difference.metric] = difference
    return out
