"""The pixel bookkeeping of tools/figures/fpgo_error_maps.py, whose sums docs/results.md quotes:
the change of squared error a variant makes, split by what the reference frame shows."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools" / "figures"))
from fpgo_error_maps import delta_map, squared_error, summary  # noqa: E402


def test_squared_error_rounds_to_8_bits_like_the_pngs() -> None:
    reference = torch.zeros(1, 2, 3)
    image = torch.tensor([[[0.5, 0.0, 0.0], [0.001, 0.001, 0.001]]])
    error = squared_error(image, reference)
    assert error[0, 0] == pytest.approx((128 / 255) ** 2)
    assert error[0, 1] == 0.0   # below half an 8-bit step: the same PNG


def test_summary_splits_by_the_reference_coverage_and_by_sign() -> None:
    delta = torch.tensor([[1.0, -2.0], [4.0, -8.0]])
    on_object = torch.tensor([[True, True], [False, False]])
    out = summary([delta, 2 * delta], [on_object, on_object])
    assert out["total"] == pytest.approx(3 * -5.0)
    assert out["on_object"] == pytest.approx(3 * -1.0)
    assert out["on_background"] == pytest.approx(3 * -4.0)
    assert out["worse"] == pytest.approx(3 * 5.0)
    assert out["better"] == pytest.approx(3 * -10.0)
    assert out["worse_on_background"] == pytest.approx(3 * 4.0)
    assert out["loss_share_on_background"] == pytest.approx(0.8)


def test_delta_map_colours_losses_red_and_gains_green() -> None:
    picture = delta_map(torch.tensor([[0.1, -0.1, 0.0]]), scale=0.05)
    assert picture[0, 0].tolist() == [1.0, 0.0, 0.0]
    assert picture[0, 1].tolist() == [0.0, 1.0, 0.0]
    assert picture[0, 2].tolist() == [1.0, 1.0, 1.0]
