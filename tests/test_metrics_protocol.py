"""Self-referenced protocol (docs/formulas.md §14): PSNR against hand-computed values, JSON, unavailable
networks. The networks themselves are tested in test_metrics_networks.py."""
import math

import numpy as np
import pytest
import torch

from fracture_gs.metrics.protocol import (MetricNetworks, fid_bias_warning, psnr_db,
                                          self_referenced_metrics)

CPU = torch.device("cpu")


def _no_networks() -> MetricNetworks:
    return MetricNetworks(device=CPU, lpips=None, inception=None,
                          lpips_unavailable="unavailable: expected /x/alexnet.ckpt",
                          fid_unavailable="unavailable: expected /x/default_1.pt")


def test_psnr_equals_hand_computed_values():
    height, width = 6, 8
    reference = np.full((2, height, width, 3), 0.5, np.float32)
    reference[1] = 0.25
    window = np.repeat(reference[:, None], 3, axis=1).copy()
    window[0, 0] += 0.1                          # every value off by 0.1: MSE 0.01 → 20 dB
    window[0, 1, :, : width // 2] += 0.2         # half the pixels off by 0.2: MSE 0.02
    window[0, 2, 0, 0, 0] = 1.0                  # one value off by 0.5: MSE 0.25 / 144
    window[1, 0] = 0.0                           # all off by 0.25: MSE 0.0625
    window[1, 1, :3] += 0.5                      # half the rows off by 0.5: MSE 0.125
    # window[1, 2] equals its reference: +inf
    result = self_referenced_metrics(reference, window, _no_networks())
    expected = [[20.0, 10 * math.log10(1 / 0.02), 10 * math.log10(144 / 0.25)],
                [10 * math.log10(1 / 0.0625), 10 * math.log10(1 / 0.125), math.inf]]
    assert result.psnr.shape == (2, 3)
    np.testing.assert_allclose(result.psnr, expected, rtol=0, atol=1e-5)


def test_psnr_db_broadcasts_one_reference():
    reference = torch.zeros(4, 4, 3)
    images = torch.stack([torch.full((4, 4, 3), level) for level in (0.1, 0.01)])
    np.testing.assert_allclose(psnr_db(images, reference).numpy(), [20.0, 40.0], atol=1e-6)


def test_unavailable_networks_are_reported_with_the_file():
    reference = np.zeros((2, 4, 4, 3), np.float32)
    window = np.full((2, 1, 4, 4, 3), 0.1, np.float32)
    summary = self_referenced_metrics(reference, window, _no_networks()).to_json()
    assert summary["lpips"] == "unavailable: expected /x/alexnet.ckpt"
    assert summary["fid"] == "unavailable: expected /x/default_1.pt"
    assert summary["psnr"]["mean"] == pytest.approx(20.0)
    assert summary["n_reference"] == 2 and summary["n_window"] == 2
    assert summary["fid_warning"] is None


def test_identical_images_give_inf_psnr_as_json_string():
    reference = np.full((1, 4, 4, 3), 0.3, np.float32)
    summary = self_referenced_metrics(reference, reference[:, None], _no_networks()).to_json()
    assert summary["psnr"]["per_view"] == [["inf"]] and summary["psnr"]["mean"] == "inf"


def test_fid_bias_warning_names_n():
    warning = fid_bias_warning(8, 40)
    assert "8 reference and 40 window images" in warning and "biased" in warning
    assert fid_bias_warning(5000, 5000) is None


@pytest.mark.parametrize("window_shape", [(2, 4, 4, 3), (3, 1, 4, 4, 3), (2, 1, 5, 4, 3)])
def test_mismatched_shapes_are_rejected(window_shape):
    with pytest.raises(ValueError, match="window_images"):
        self_referenced_metrics(np.zeros((2, 4, 4, 3), np.float32),
                                np.zeros(window_shape, np.float32), _no_networks())


def test_out_of_range_pixels_are_rejected():
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        self_referenced_metrics(np.full((1, 4, 4, 3), 1.5, np.float32),
                                np.zeros((1, 1, 4, 4, 3), np.float32), _no_networks())
