"""Pictures of an evaluation: momentum over time (like the paper's Fig. 7), energy over time
(Fig. 8), frame strips and line plots of sweeps. Every file is written atomically; matplotlib is
used through its object API (Agg canvas, no pyplot global state)."""
from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fracture_gs.io.atomic import write_bytes_atomic
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.folders.sim_reader import read_diagnostics_csv

_STYLES = ("--", ":", "-.", (0, (5, 1)))
_AXES = {"x": "tab:red", "y": "tab:green", "z": "tab:blue"}


def _save(fig, path: Path) -> None:
    buffer = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buffer, format="png", dpi=110)
    write_bytes_atomic(Path(path), buffer.getvalue())


def object_names_of(columns: dict[str, np.ndarray]) -> list[str]:
    """Object names of a diagnostics.csv (from its ``<name>_kinetic`` columns, in order)."""
    return [name[: -len("_kinetic")] for name in columns if name.endswith("_kinetic")]


@dataclass(frozen=True)
class ConservationSummary:
    """Momentum and energy facts of one run (the acceptance numbers of the paper's Fig. 7 / 8).

    ``momentum_drift``: max over frames of |p(t) − p(0)| / Σ_objects |p_object(0)| (the momentum
    the objects carry at the start, which for rigidly moving objects equals Σ m|v|);
    ``momentum_balance``: max over frames of |p(t) − p(0) − J(t)|, J the impulse gravity and the
    boundaries gave (diagnostics columns ``impulse_*``; NaN for runs without them), divided by
    the larger of that scale and max |J|: the conservation check of scenes with gravity, a
    ground or walls, where the drift itself is physics;
    ``energy_rise``: max over frames of (E(t) − E(0)) / |E(0)|."""

    momentum_drift: float
    momentum_scale: float
    momentum_balance: float
    energy_rise: float
    energy_start: float
    energy_min: float
    exchanged_momentum: float   # largest change of one object's momentum (shows the exchange)

    def to_json(self) -> dict:
        """The fields as JSON values (null where a number is not available, e.g. NaN)."""
        values = {name: float(getattr(self, name)) for name in self.__dataclass_fields__}
        return {name: value if math.isfinite(value) else None for name, value in values.items()}


def conservation_summary(columns: dict[str, np.ndarray]) -> ConservationSummary:
    """:class:`ConservationSummary` of diagnostics columns."""
    total = np.stack([columns["px"], columns["py"], columns["pz"]], axis=1)
    names = object_names_of(columns)
    per_object = [np.stack([columns[f"{n}_p{a}"] for a in "xyz"], axis=1) for n in names]
    scale = float(sum(np.linalg.norm(p[0]) for p in per_object)) or float(np.linalg.norm(total[0]))
    drift = float(np.max(np.linalg.norm(total - total[0], axis=1)) / scale) if scale > 0 else 0.0
    balance = momentum_balance_residual(columns, scale)
    exchanged = max((float(np.max(np.linalg.norm(p - p[0], axis=1))) for p in per_object),
                    default=0.0)
    energy = columns["total_energy"]
    start = float(energy[0])
    rise = float(np.max(energy - start) / abs(start)) if start != 0 else float(np.max(energy - start))
    return ConservationSummary(momentum_drift=drift, momentum_scale=scale,
                               momentum_balance=float(np.max(balance)) if balance is not None
                               else float("nan"), energy_rise=rise,
                               energy_start=start, energy_min=float(np.min(energy)),
                               exchanged_momentum=exchanged)


def external_impulse(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    """(frames, 3) impulse of gravity and the boundaries since frame 0 (None when the
    diagnostics have no ``impulse_*`` columns)."""
    if not all(f"impulse_{a}" in columns for a in "xyz"):
        return None
    return np.stack([columns[f"impulse_{a}"] for a in "xyz"], axis=1)


def momentum_balance_residual(columns: dict[str, np.ndarray], scale: float) -> np.ndarray | None:
    """Per frame |p(t) − p(0) − J(t)| / max(scale, max |J|), J the external impulse columns
    (None when the diagnostics have no ``impulse_*`` columns)."""
    impulse = external_impulse(columns)
    if impulse is None:
        return None
    total = np.stack([columns["px"], columns["py"], columns["pz"]], axis=1)
    reference = max(scale, float(np.max(np.linalg.norm(impulse, axis=1))), 1e-30)
    return np.linalg.norm(total - total[0] - impulse, axis=1) / reference


def momentum_plot(columns: dict[str, np.ndarray], path: Path, title: str = "") -> None:
    """Per-object and total momentum components over time (paper Fig. 7), and below it the
    total's relative drift on a log scale."""
    from matplotlib.figure import Figure

    time = columns["time"]
    names = object_names_of(columns)
    summary = conservation_summary(columns)
    fig = Figure(figsize=(8, 6.5))
    ax_p, ax_d = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1.3]})
    for axis, colour in _AXES.items():
        values = [columns[f"{n}_p{axis}"] for n in names] + [columns[f"p{axis}"]]
        if max(float(np.max(np.abs(v))) for v in values) <= 1e-3 * max(summary.momentum_scale, 1e-30):
            continue  # an axis nothing moves along
        for k, name in enumerate(names):
            ax_p.plot(time, columns[f"{name}_p{axis}"], color=colour, lw=1.2,
                      ls=_STYLES[k % len(_STYLES)], label=f"{name} p{axis}")
        ax_p.plot(time, columns[f"p{axis}"], color="black" if axis == "x" else colour, lw=2.4,
                  label=f"total p{axis}")
    ax_p.set_ylabel("momentum [kg m/s]")
    ax_p.legend(fontsize=7, ncol=3)
    ax_p.grid(alpha=0.3)
    total = np.stack([columns["px"], columns["py"], columns["pz"]], axis=1)
    drift = np.linalg.norm(total - total[0], axis=1) / max(summary.momentum_scale, 1e-30)
    balance = momentum_balance_residual(columns, summary.momentum_scale)
    impulse = external_impulse(columns)
    external = impulse is not None and bool(np.any(impulse != 0.0))
    ax_p.set_title(title or ("momentum: gravity and the boundaries change it by exactly their impulse J"
                             if external else "momentum: objects exchange it, the total stays constant"))
    ax_d.semilogy(time, np.maximum(drift, 1e-12), color="tab:gray" if external else "black",
                  lw=1.5, label="|p(t) − p(0)| / Σ|p_k(0)|")
    if external:  # gravity / boundaries act: the drift is physics, the balance is the check
        ax_d.semilogy(time, np.maximum(balance, 1e-12), color="black", lw=1.5,
                      label="|p(t) − p(0) − J(t)| (J: gravity + boundaries)")
    ax_d.axhline(1e-5, color="tab:red", ls="--", lw=1, label="1e-5 target")
    ax_d.set_ylabel("relative")
    ax_d.set_xlabel("time [s]")
    ax_d.legend(fontsize=7)
    ax_d.grid(alpha=0.3)
    _save(fig, path)


def energy_plot(columns: dict[str, np.ndarray], path: Path, title: str = "") -> None:
    """Kinetic / elastic / gravitational energy per object and of the system (paper Fig. 8),
    with the start + 1 % bound."""
    from matplotlib.figure import Figure

    time = columns["time"]
    names = object_names_of(columns)
    fig = Figure(figsize=(8, 6.5))
    ax_o, ax_s = fig.subplots(2, 1, sharex=True)
    for k, name in enumerate(names):
        ax_o.plot(time, columns[f"{name}_kinetic"], color="tab:orange", lw=1.4,
                  ls=_STYLES[k % len(_STYLES)], label=f"{name} kinetic")
    ax_o.set_ylabel("energy [J]")
    ax_o.set_title(title or "kinetic energy per object")
    ax_o.legend(fontsize=7)
    ax_o.grid(alpha=0.3)
    for name, colour in (("kinetic", "tab:orange"), ("elastic", "tab:purple"),
                         ("gravitational", "tab:brown"), ("total_energy", "black")):
        ax_s.plot(time, columns[name], color=colour, lw=2 if name == "total_energy" else 1.4,
                  label=name.replace("_", " "))
    start = float(columns["total_energy"][0])
    ax_s.axhline(start + 0.01 * abs(start), color="tab:red", ls="--", lw=1, label="start + 1 %")
    ax_s.set_xlabel("time [s]")
    ax_s.set_ylabel("energy [J]")
    ax_s.set_title("system")
    ax_s.legend(fontsize=7, ncol=2)
    ax_s.grid(alpha=0.3)
    _save(fig, path)


def diagnostics_plots(sim_dir: Path, out_dir: Path, prefix: str = "") -> tuple[Path, Path,
                                                                             ConservationSummary]:
    """``momentum.png`` and ``energy.png`` of a simulation folder's diagnostics.csv."""
    columns = read_diagnostics_csv(SimLayout(sim_dir).csv_path)
    momentum_path = out_dir / f"{prefix}momentum.png"
    energy_path = out_dir / f"{prefix}energy.png"
    momentum_plot(columns, momentum_path)
    energy_plot(columns, energy_path)
    return momentum_path, energy_path, conservation_summary(columns)


def _label(image: np.ndarray, text: str) -> np.ndarray:
    out = image.copy()
    scale = max(image.shape[0] / 400.0, 0.35)
    thickness = max(1, int(round(scale)))
    origin = (int(6 * scale), int(22 * scale))
    cv2.putText(out, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, (255, 255, 255),
                thickness + 2, cv2.LINE_AA)
    cv2.putText(out, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, (0, 0, 0), thickness,
                cv2.LINE_AA)
    return out


def frame_strip(rows: Sequence[tuple[str, Sequence[np.ndarray], Sequence[str]]], path: Path,
                max_height: int = 200) -> None:
    """Rows of labelled images side by side (one row per run: its name, images, captions),
    written as one PNG; images are scaled to ``max_height`` pixels."""
    lines = []
    width = 0
    for name, images, captions in rows:
        tiles = []
        for image, caption in zip(images, captions):
            scale = max_height / image.shape[0]
            tile = cv2.resize(image, (max(1, round(image.shape[1] * scale)), max_height),
                              interpolation=cv2.INTER_AREA)
            tiles.append(_label(tile, f"{name}: {caption}" if not tiles else caption))
        line = np.concatenate(tiles, axis=1) if tiles else np.full((max_height, 1, 3), 255, np.uint8)
        lines.append(line)
        width = max(width, line.shape[1])
    padded = [np.pad(line, ((0, 0), (0, width - line.shape[1]), (0, 0)), constant_values=255)
              for line in lines]
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(np.concatenate(padded)[..., ::-1]))
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    write_bytes_atomic(Path(path), encoded.tobytes())


def line_plot(x: Sequence[float], series: dict[str, Sequence[float]], path: Path, *, xlabel: str,
              ylabel: str, title: str, logy: bool = False, xlog: bool = False) -> None:
    """Several named series over the same x (sweeps: fractured share per α0, error per N_v)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.2))
    ax = fig.subplots()
    for name, values in series.items():
        ax.plot(x, values, marker="o", lw=1.5, label=name)
    if logy:
        ax.set_yscale("log")
    if xlog:
        ax.set_xscale("symlog")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)
