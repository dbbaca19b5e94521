"""Paired comparison of two evaluated runs (fracture_gs.metrics.paired)."""
import numpy as np
import pytest
import torch

from fracture_gs.metrics.fid import frechet_distance_from_features
from fracture_gs.metrics.paired import paired_differences, view_resamples
from fracture_gs.metrics.protocol import SelfReferencedMetrics


def _run(psnr: np.ndarray, lpips: np.ndarray | None = None, reference=None, window=None
         ) -> SelfReferencedMetrics:
    fid = None
    if reference is not None:
        fid = frechet_distance_from_features(torch.from_numpy(reference),
                                             torch.from_numpy(window.reshape(-1, window.shape[-1])))
    return SelfReferencedMetrics(psnr=psnr, lpips=lpips, fid=fid, n_reference=psnr.shape[0],
                                 n_window=psnr.size, reference_features=reference,
                                 window_features=window)


def test_identical_runs_have_no_advantage():
    rng = np.random.default_rng(0)
    psnr, lpips = rng.uniform(18, 26, (6, 5)), rng.uniform(0.05, 0.2, (6, 5))
    reference, window = rng.normal(size=(6, 32)), rng.normal(size=(6, 5, 32))
    result = paired_differences(_run(psnr, lpips, reference, window),
                                _run(psnr, lpips, reference, window), resamples=200)
    for metric in ("psnr", "lpips", "fid"):
        assert result[metric].advantage == pytest.approx(0.0, abs=1e-9)
        assert result[metric].low == pytest.approx(0.0, abs=1e-9)
        assert result[metric].high == pytest.approx(0.0, abs=1e-9)
        assert result[metric].verdict == "no clear difference"
    assert result["psnr"].views_better == 0 and result["psnr"].views == 6


def test_a_consistent_gain_is_found_with_its_size_and_sign():
    rng = np.random.default_rng(1)
    base = rng.uniform(18, 26, (8, 5))
    lpips = rng.uniform(0.05, 0.2, (8, 5))
    better = _run(base + 0.5 + rng.normal(0, 0.05, base.shape), lpips - 0.01)
    worse = _run(base, lpips)
    ahead = paired_differences(better, worse, resamples=500)
    assert ahead["psnr"].advantage == pytest.approx(0.5, abs=0.05)
    assert 0.4 < ahead["psnr"].low <= ahead["psnr"].advantage <= ahead["psnr"].high < 0.6
    assert ahead["psnr"].views_better == 8 and ahead["psnr"].verdict == "first better"
    assert ahead["lpips"].advantage == pytest.approx(0.01) and ahead["lpips"].verdict == "first better"
    behind = paired_differences(worse, better, resamples=500)     # the same pair, swapped
    assert behind["psnr"].advantage == pytest.approx(-ahead["psnr"].advantage)
    assert behind["psnr"].verdict == "first worse" and behind["psnr"].views_better == 0


def test_noise_without_a_gain_gives_an_interval_around_zero():
    rng = np.random.default_rng(2)
    base = rng.uniform(18, 26, (8, 5))
    first, second = base + rng.normal(0, 0.3, base.shape), base + rng.normal(0, 0.3, base.shape)
    result = paired_differences(_run(first), _run(second), resamples=1000)
    assert result["psnr"].low < 0.0 < result["psnr"].high
    per_view = first.mean(axis=1) - second.mean(axis=1)
    assert result["psnr"].advantage == pytest.approx(per_view.mean())
    # the interval is about ±2 standard errors of the mean over 8 views
    half_width = 0.5 * (result["psnr"].high - result["psnr"].low)
    assert half_width == pytest.approx(2 * per_view.std() / np.sqrt(8), rel=0.35)


def test_fid_advantage_uses_the_resampled_views():
    rng = np.random.default_rng(3)
    reference = rng.normal(size=(6, 16))
    near = reference[:, None, :] + rng.normal(0, 0.1, (6, 4, 16))
    far = reference[:, None, :] + rng.normal(0, 1.0, (6, 4, 16))
    psnr = np.full((6, 4), 20.0)
    close, distant = _run(psnr, None, reference, near), _run(psnr, None, reference, far)
    result = paired_differences(close, distant, resamples=300)
    assert result["fid"].advantage == pytest.approx(distant.fid - close.fid)
    assert result["fid"].advantage > 0 and result["fid"].verdict == "first better"
    assert result["fid"].views_better is None
    assert "lpips" not in result                                 # neither run has LPIPS


def test_infinite_psnr_is_left_out_and_unpaired_runs_are_refused():
    psnr = np.full((3, 2), np.inf)
    assert "psnr" not in paired_differences(_run(psnr), _run(psnr), resamples=10)
    with pytest.raises(ValueError, match="not paired"):
        paired_differences(_run(np.zeros((3, 2))), _run(np.zeros((4, 2))))
    with pytest.raises(ValueError, match="at least 2 views"):
        paired_differences(_run(np.zeros((1, 2))), _run(np.zeros((1, 2))))
    with pytest.raises(ValueError, match="confidence"):
        paired_differences(_run(np.zeros((3, 2))), _run(np.zeros((3, 2))), confidence=1.0)


def test_resamples_are_reproducible():
    assert np.array_equal(view_resamples(5, 20, seed=4), view_resamples(5, 20, seed=4))
    draws = view_resamples(5, 2000, seed=0)
    assert draws.min() == 0 and draws.max() == 4
