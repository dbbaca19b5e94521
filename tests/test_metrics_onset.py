"""Fracture onset, reference frame and window (docs/formulas.md §14) on synthetic histories."""
from pathlib import Path

import numpy as np
import pytest

from fracture_gs.metrics.onset import (fracture_window, fracture_window_from_simulation,
                                       latched_fractured_counts, onset_threshold)


def test_threshold_is_ten_or_one_permille():
    assert onset_threshold(5_000) == 10.0
    assert onset_threshold(10_000) == 10.0
    assert onset_threshold(250_000) == 250.0


def test_count_must_exceed_threshold():
    # 20 000 particles → threshold 20: a count of exactly 20 is not yet the onset
    result = fracture_window([0, 5, 20, 21, 40, 80, 90, 95, 99, 99], 20_000)
    assert (result.onset_frame, result.reference_frame) == (3, 2)
    assert result.window_frames == [4, 5, 6, 7, 8]
    assert not result.truncated and result.usable


def test_onset_from_latched_alpha_history():
    frames, particles = 9, 20_000            # threshold 20
    alpha = np.full((frames, particles), -0.05)
    alpha[3:, :15] = 0.01                    # 15 fractured at frame 3: below the threshold
    alpha[4, 15:30] = 0.0                    # 15 more reach α = 0 at frame 4 only ...
    alpha[5:, 15:30] = -0.01                 # ... and fall back: the flag latches
    alpha[6:, 30:100] = 0.2
    counts = latched_fractured_counts(alpha, alpha_threshold=0.0)
    assert counts.tolist() == [0, 0, 0, 15, 30, 30, 100, 100, 100]
    result = fracture_window(counts, particles)
    assert (result.onset_frame, result.reference_frame) == (4, 3)
    # frames end at 8: the 5-frame window 5..9 is cut to 5..8
    assert result.window_frames == [5, 6, 7, 8]
    assert result.truncated and result.usable
    assert "4 of 5 window frames" in result.note


def test_per_particle_alpha_threshold():
    alpha = np.array([[-0.1, -0.1], [0.05, -0.05]])
    counts = latched_fractured_counts(alpha, alpha_threshold=np.array([0.0, -0.06]))
    assert counts.tolist() == [0, 2]


def test_never_fractured():
    result = fracture_window([0, 3, 7, 10, 10, 9], 1_000)
    assert result.onset_frame is None and result.reference_frame is None
    assert result.window_frames == [] and not result.usable and not result.truncated
    assert result.note.startswith("no fracture")


def test_fractured_at_frame_zero_has_no_reference():
    result = fracture_window([50, 60, 70, 80], 1_000)
    assert result.onset_frame == 0 and result.reference_frame is None
    assert result.window_frames == [] and not result.usable
    assert "frame 0" in result.note


def test_fracture_at_frame_one_uses_frame_zero():
    result = fracture_window([0, 11, 30, 40, 50, 60, 70, 80], 1_000, window=5)
    assert (result.onset_frame, result.reference_frame) == (1, 0)
    assert result.window_frames == [2, 3, 4, 5, 6]


def test_onset_on_last_frame_leaves_empty_window():
    result = fracture_window([0, 0, 0, 500], 1_000)
    assert (result.onset_frame, result.reference_frame) == (3, 2)
    assert result.window_frames == [] and result.truncated and not result.usable
    assert "no frames after the onset" in result.note


def test_custom_window_length_and_json():
    result = fracture_window([0, 0, 20, 30, 40, 50], 100, window=2)
    assert result.window_frames == [3, 4]
    summary = result.to_json()
    assert summary["onset_frame"] == 2 and summary["window_frames"] == [3, 4]
    assert summary["usable"] and not summary["truncated"]


@pytest.mark.parametrize("counts, particles, window", [([], 100, 5), ([0, 200], 100, 5),
                                                       ([0, -1], 100, 5), ([0, 1], 100, 0)])
def test_bad_input_is_rejected(counts, particles, window):
    with pytest.raises(ValueError):
        fracture_window(counts, particles, window)


def _write_simulation(folder: Path, counts: list[int], particle_count: int) -> None:
    folder.mkdir()
    rows = ["frame,time,fractured"] + [f"{i},{i / 60!r},{c}" for i, c in enumerate(counts)]
    (folder / "diagnostics.csv").write_text("\n".join(rows) + "\n")
    np.savez(folder / "particles.npz", mass=np.ones(particle_count, np.float32))


def test_window_from_simulation_folder(tmp_path):
    _write_simulation(tmp_path / "sim", [0, 0, 4, 12, 30, 31, 32], 2_000)
    result = fracture_window_from_simulation(tmp_path / "sim", window=3)
    assert (result.onset_frame, result.reference_frame) == (3, 2)
    assert result.window_frames == [4, 5, 6] and result.particle_count == 2_000


def test_simulation_folder_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="diagnostics.csv"):
        fracture_window_from_simulation(tmp_path)
    folder = tmp_path / "gaps"
    _write_simulation(folder, [0, 1, 2], 100)
    (folder / "diagnostics.csv").write_text("frame,fractured\n0,0\n2,5\n")
    with pytest.raises(ValueError, match="without gaps"):
        fracture_window_from_simulation(folder)
