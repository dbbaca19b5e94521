"""Fracture onset, reference frame and evaluation window (docs/formulas.md §14, paper App. A.3).

* Onset t_f: the first frame whose count of fractured particles *exceeds*
  max(10, 0.1 % of the particles).
* Reference frame I_ref = t_f − 1: the last frame of the intact object.
* Window: the ``window`` frames after the onset, t_f + 1 … t_f + window (docs/formulas.md §14; the
  paper's "subsequent 5 frames" after I_ref would be t_f … t_f + 4).

Edge cases are reported, not guessed: a run that never crosses the threshold has no onset;
one already fractured at frame 0 has no intact reference; a run that ends inside the window
gets a shorter window (``truncated``), possibly empty when t_f is the last frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MIN_FRACTURED_PARTICLES = 10
FRACTURED_FRACTION = 1e-3
DEFAULT_WINDOW = 5


def onset_threshold(particle_count: int) -> float:
    """The count a frame must exceed to be the onset: max(10, 0.1 % of the particles)."""
    if particle_count < 1:
        raise ValueError(f"particle_count must be >= 1, got {particle_count}")
    return max(float(MIN_FRACTURED_PARTICLES), FRACTURED_FRACTION * particle_count)


@dataclass(frozen=True)
class FractureWindow:
    """Where a run fractures and which frames the self-referenced metrics compare.

    ``frames`` are frame numbers as in ``frames/frame_<n>.npz`` (frame 0 = initial state).
    """

    particle_count: int
    threshold: float
    frame_count: int
    requested_window: int
    onset_frame: int | None
    reference_frame: int | None
    window_frames: list[int] = field(default_factory=list)

    @property
    def truncated(self) -> bool:
        """The run ended before the full window (fewer than ``requested_window`` frames)."""
        return self.onset_frame is not None and len(self.window_frames) < self.requested_window

    @property
    def usable(self) -> bool:
        """A reference frame and at least one window frame exist."""
        return self.reference_frame is not None and len(self.window_frames) > 0

    @property
    def note(self) -> str:
        """One line saying what was found (printed in reports)."""
        if self.onset_frame is None:
            return (f"no fracture: the fractured count never exceeds {self.threshold:g} "
                    f"(max(10, 0.1% of {self.particle_count} particles)) in {self.frame_count} frames")
        if self.reference_frame is None:
            return (f"fractured already at frame 0: no intact reference frame "
                    f"(threshold {self.threshold:g})")
        text = (f"onset at frame {self.onset_frame}, reference frame {self.reference_frame}, "
                f"window frames {self.window_frames[0]}-{self.window_frames[-1]}"
                if self.window_frames else
                f"onset at frame {self.onset_frame} (the last frame), reference frame "
                f"{self.reference_frame}, no frames after the onset")
        if self.window_frames and self.truncated:
            text += (f" (run ends after frame {self.frame_count - 1}: "
                     f"{len(self.window_frames)} of {self.requested_window} window frames)")
        return text

    def to_json(self) -> dict:
        """Plain-JSON summary for ``metrics.json``."""
        return {"particle_count": self.particle_count, "threshold": self.threshold,
                "frame_count": self.frame_count, "onset_frame": self.onset_frame,
                "reference_frame": self.reference_frame, "window_frames": list(self.window_frames),
                "requested_window": self.requested_window, "truncated": self.truncated,
                "usable": self.usable, "note": self.note}


def fracture_window(fractured_counts: np.ndarray | list[int], particle_count: int,
                    window: int = DEFAULT_WINDOW) -> FractureWindow:
    """Onset, reference frame and window from per-frame fractured counts (index = frame)."""
    counts = np.asarray(fractured_counts)
    if counts.ndim != 1 or counts.size == 0:
        raise ValueError(f"fractured_counts must be a non-empty 1-D sequence, got shape {counts.shape}")
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    if np.any(counts < 0) or np.any(counts > particle_count):
        raise ValueError(f"fractured counts must lie in [0, {particle_count}], "
                         f"got [{counts.min()}, {counts.max()}]")
    threshold = onset_threshold(particle_count)
    crossing = np.flatnonzero(counts > threshold)
    onset = int(crossing[0]) if crossing.size else None
    reference = onset - 1 if onset is not None and onset > 0 else None
    frames = (list(range(onset + 1, min(onset + window, counts.size - 1) + 1))
              if reference is not None else [])
    return FractureWindow(particle_count=int(particle_count), threshold=threshold,
                          frame_count=int(counts.size), requested_window=int(window),
                          onset_frame=onset, reference_frame=reference, window_frames=frames)


def latched_fractured_counts(alpha_history: np.ndarray, alpha_threshold: float | np.ndarray = 0.0
                             ) -> np.ndarray:
    """Per-frame fractured counts from hardening states ``alpha_history`` (frames, particles).

    A particle is fractured from the first frame with α ≥ ``alpha_threshold`` on (the flag
    latches, docs/formulas.md §4); the threshold may be per particle. Frames sample the run, so this
    sees only crossings visible at frame times; the simulator's own ``fractured`` flag
    (diagnostics.csv) also catches α that crossed and fell back between frames.
    """
    alpha = np.asarray(alpha_history, dtype=np.float64)
    if alpha.ndim != 2:
        raise ValueError(f"alpha_history must be (frames, particles), got shape {alpha.shape}")
    fractured = np.logical_or.accumulate(alpha >= alpha_threshold, axis=0)
    return fractured.sum(axis=1)


def fracture_window_from_simulation(sim_dir: str | Path, window: int = DEFAULT_WINDOW) -> FractureWindow:
    """:func:`fracture_window` for a ``simulate.py`` output folder (``diagnostics.csv`` for the
    counts, ``particles.npz`` for the particle count)."""
    from fracture_gs.io.sim_layout import SimLayout
    from fracture_gs.folders.sim_reader import read_diagnostics_csv

    sim_dir = Path(sim_dir)
    layout = SimLayout(sim_dir)
    csv_path, particles_path = layout.csv_path, layout.particles_path
    for path in (csv_path, particles_path):
        if not path.is_file():
            raise FileNotFoundError(f"{path}: not found (is {sim_dir} a simulate.py output folder?)")
    columns = read_diagnostics_csv(csv_path)
    if "fractured" not in columns or "frame" not in columns:
        raise ValueError(f"{csv_path}: needs the columns 'frame' and 'fractured'")
    frames = columns["frame"].astype(np.int64)
    if not np.array_equal(frames, np.arange(frames.size)):
        raise ValueError(f"{csv_path}: frames must run 0, 1, 2, ... without gaps")
    with np.load(particles_path) as particles:
        if "mass" not in particles.files:
            raise ValueError(f"{particles_path}: has no 'mass' array")
        particle_count = int(particles["mass"].shape[0])
    return fracture_window(columns["fractured"].astype(np.int64), particle_count, window)
