"""Output folder of a simulation and the checkpoint behind ``--resume``.

Layout of ``output/sims/<name>/``::

    scene.yaml          the resolved scene (defaults filled in)
    particles.npz       constant per-particle data (mass, rest_volume, obj_id, part_id,
                        is_surface, rest_x, gaussian_index)
    frames/frame_00000.npz   x, v, F_E, alpha, damage (float32), fractured (bool), fragment_id
                        (int32); frame 0 = start. alpha is the material state (NACC's α; for
                        brittle particles their damage d, as in ``damage``, which is 0 elsewhere)
    diagnostics.csv     one row per frame (columns: :func:`diagnostics_columns`)
    diagnostics.png     momentum and energies over time
    checkpoint.npz      the solver's full state after the last complete frame

Every file is written to a temporary name in the same folder and renamed into place, so a
killed run never leaves a half-written file. For each frame the checkpoint is written
*before* the frame file: the checkpoint is therefore never behind the frames, and a resume
rewrites a frame that the checkpoint has but the folder lacks.
"""
from __future__ import annotations

import csv
import io
import math
import os
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from fracture_gs.mpm.types import ParticleSet, SimState

SCENE_FILE = "scene.yaml"
PARTICLES_FILE = "particles.npz"
FRAMES_DIR = "frames"
CHECKPOINT_FILE = "checkpoint.npz"
_SOLVER_PREFIX = "solver/"
DIAGNOSTICS_CSV = "diagnostics.csv"
DIAGNOSTICS_PNG = "diagnostics.png"
FRAME_ARRAYS = ("x", "v", "F_E", "alpha", "fractured")  # every frame has these; new runs add damage
BASE_COLUMNS = ("frame", "time", "steps", "dt_min", "px", "py", "pz", "kinetic", "elastic",
                "gravitational", "total_energy", "fractured")
OBJECT_COLUMNS = ("px", "py", "pz", "kinetic")
TAIL_COLUMNS = ("fragments", "impulse_x", "impulse_y", "impulse_z", "fracture_energy")


def frame_file_name(frame: int) -> str:
    return f"frame_{frame:05d}.npz"


def diagnostics_columns(object_names: Sequence[str]) -> list[str]:
    """CSV header: the columns of docs/file_formats.md §4, then ``<name>_px, _py, _pz, _kinetic`` per object, then
    ``fragments`` (pieces with >= 1 % of their object's particles), ``impulse_x, _y, _z`` (the
    impulse gravity and the boundaries gave since frame 0: p − p(0) equals it up to round-off) and
    ``fracture_energy`` (the energy brittle damage has taken since frame 0: kinetic + elastic +
    gravitational + fracture energy never grows); last, so old readers keep their column positions."""
    return list(BASE_COLUMNS) + [f"{name}_{col}" for name in object_names
                                 for col in OBJECT_COLUMNS] + list(TAIL_COLUMNS)


def _scalar(value: Any) -> float:
    if isinstance(value, torch.Tensor):
        return float(value.detach().cpu().double().item())
    return float(value)


def _vector3(value: Any) -> list[float]:
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().double().numpy()
    array = np.asarray(value, dtype=np.float64).reshape(3)
    return [float(v) for v in array]


def diagnostics_row(frame: int, time: float, steps: int, dt_min: float,
                    diagnostics: Mapping[str, Any]) -> list[float]:
    """One CSV row from ``solver.diagnostics()`` (momentum, kinetic, elastic, gravitational,
    fractured, per_object[{momentum, kinetic, ...}])."""
    kinetic = _scalar(diagnostics["kinetic"])
    elastic = _scalar(diagnostics["elastic"])
    gravitational = _scalar(diagnostics["gravitational"])
    row: list[float] = [frame, float(time), steps, float(dt_min),
                        *_vector3(diagnostics["momentum"]), kinetic, elastic, gravitational,
                        kinetic + elastic + gravitational, int(_scalar(diagnostics["fractured"]))]
    for obj in diagnostics["per_object"]:
        row += [*_vector3(obj["momentum"]), _scalar(obj["kinetic"])]
    row.append(int(_scalar(diagnostics["fragments"])))
    row += _vector3(diagnostics.get("external_impulse", [math.nan] * 3))
    row.append(_scalar(diagnostics.get("fracture_energy", 0.0)))
    return row


def frame_arrays(state: SimState, fragment_id: torch.Tensor | None = None,
                 damage: torch.Tensor | None = None) -> dict[str, np.ndarray]:
    """The per-frame arrays from a solver state (float32, fractured bool), plus ``fragment_id``
    (int32 connected piece of every particle) and ``damage`` (float32 brittle damage, 0 for other
    models) when given."""
    def array(t: torch.Tensor, dtype: Any) -> np.ndarray:
        return t.detach().cpu().numpy().astype(dtype, copy=False)

    arrays = {"x": array(state.x, np.float32), "v": array(state.v, np.float32),
              "F_E": array(state.F_E, np.float32), "alpha": array(state.alpha, np.float32),
              "fractured": array(state.fractured, np.bool_)}
    if fragment_id is not None:
        arrays["fragment_id"] = array(fragment_id, np.int32)
    if damage is not None:
        arrays["damage"] = array(damage, np.float32)
    return arrays


def particle_arrays(particles: ParticleSet) -> dict[str, np.ndarray]:
    """The constant per-particle arrays of ``particles.npz``."""
    def array(t: torch.Tensor) -> np.ndarray:
        return t.detach().cpu().numpy()

    return {"mass": array(particles.mass), "rest_volume": array(particles.rest_volume),
            "obj_id": array(particles.obj_id), "part_id": array(particles.part_id),
            "material_id": array(particles.material_id),
            "is_surface": array(particles.is_surface), "rest_x": array(particles.x),
            "gaussian_index": array(particles.gaussian_index)}


# ----------------------------------------------------------------------------- atomic writes


def atomic_write(path: Path, write: Callable[[io.BufferedWriter], None]) -> None:
    """Write through ``write(handle)`` to a temporary file beside ``path``, fsync, rename."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def save_npz_atomic(path: Path, arrays: Mapping[str, np.ndarray]) -> None:
    atomic_write(path, lambda handle: np.savez(handle, **arrays))


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode())


def write_bytes_atomic(path: Path, data: bytes) -> None:
    atomic_write(path, lambda handle: handle.write(data))


class OutputError(ValueError):
    """A file of an output folder that cannot be used: missing, unreadable, truncated or not
    written by ``simulate.py``. The message is one line naming the file."""


def _damaged(path: Path, reason: str) -> OutputError:
    return OutputError(f"{path}: cannot be read ({reason}); the file is damaged or was not "
                       "written by simulate.py")


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file written by this module; :class:`OutputError` if the file
    is missing, unreadable, truncated or not an arrays archive."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
    except FileNotFoundError:
        raise OutputError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise OutputError(f"{path}: is a folder, expected a file") from None
    except OSError as exc:
        raise _damaged(path, exc.strerror or type(exc).__name__) from None
    if not magic.startswith(b"PK"):
        raise _damaged(path, "empty file" if not magic else "not an .npz archive")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise _damaged(path, str(exc).splitlines()[0] if str(exc) else type(exc).__name__) \
            from None


def check_npz_complete(path: Path) -> None:
    """OutputError unless ``path`` is a complete zip archive (its central directory, at the
    end of the file, is read; the arrays are not)."""
    try:
        with zipfile.ZipFile(path):
            pass
    except FileNotFoundError:
        raise OutputError(f"{path}: file not found") from None
    except (OSError, zipfile.BadZipFile) as exc:
        raise _damaged(path, str(exc)) from None


def load_frame(path: str | Path) -> dict[str, np.ndarray]:
    """Read one frame file into a dict of arrays (:class:`OutputError` if it is damaged)."""
    return read_npz(path)


# ----------------------------------------------------------------------------- checkpoint


@dataclass
class Checkpoint:
    """Everything needed to continue a run exactly after ``frame``."""

    frame: int
    solver_state: dict[str, Any]
    rows: list[list[float]]     # diagnostics rows of frames 0..frame


# ----------------------------------------------------------------------------- the folder


class SimulationOutput:
    """Writes (and, for ``--resume``, reads back) one simulation output folder."""

    def __init__(self, root: str | Path, object_names: Sequence[str]) -> None:
        self.root = Path(root)
        self.object_names = list(object_names)
        self.columns = diagnostics_columns(self.object_names)
        self.rows: list[list[float]] = []

    # paths
    @property
    def scene_path(self) -> Path:
        return self.root / SCENE_FILE

    @property
    def particles_path(self) -> Path:
        return self.root / PARTICLES_FILE

    @property
    def frames_dir(self) -> Path:
        return self.root / FRAMES_DIR

    @property
    def checkpoint_path(self) -> Path:
        return self.root / CHECKPOINT_FILE

    @property
    def csv_path(self) -> Path:
        return self.root / DIAGNOSTICS_CSV

    @property
    def png_path(self) -> Path:
        return self.root / DIAGNOSTICS_PNG

    def frame_path(self, frame: int) -> Path:
        return self.frames_dir / frame_file_name(frame)

    # writing
    def remove_temporaries(self) -> None:
        """Delete temporary files that a killed run left behind (never complete files)."""
        for folder in (self.root, self.frames_dir):
            if folder.is_dir():
                for tmp in folder.glob(".*.tmp"):
                    tmp.unlink(missing_ok=True)

    def start(self, scene: Mapping[str, Any], particles: ParticleSet) -> None:
        """Begin a fresh run: drop the files of an earlier run, write scene and particles."""
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.remove_temporaries()
        for stale in self.frames_dir.glob("frame_*.npz"):
            stale.unlink()
        for name in (CHECKPOINT_FILE, DIAGNOSTICS_CSV, DIAGNOSTICS_PNG):
            (self.root / name).unlink(missing_ok=True)
        self.rows = []
        self.write_scene(scene)
        save_npz_atomic(self.particles_path, particle_arrays(particles))

    def write_scene(self, scene: Mapping[str, Any]) -> None:
        text = yaml.safe_dump(dict(scene), sort_keys=False, default_flow_style=None)
        write_text_atomic(self.scene_path, text)

    def write_frame(self, frame: int, state: SimState, row: list[float],
                    solver_state: Mapping[str, Any], fragment_id: torch.Tensor | None = None,
                    damage: torch.Tensor | None = None) -> None:
        """Commit one frame: checkpoint first, then the frame file, then the CSV."""
        if len(row) != len(self.columns):
            raise ValueError(f"diagnostics row has {len(row)} values, expected "
                             f"{len(self.columns)} ({', '.join(self.columns)})")
        self.rows = [r for r in self.rows if int(r[0]) < frame] + [list(row)]
        payload = {_SOLVER_PREFIX + key: _plain_array(key, value)
                   for key, value in solver_state.items()}
        payload.update(frame=np.int64(frame), rows=np.asarray(self.rows, dtype=np.float64),
                       columns=np.asarray(self.columns, dtype=np.str_))
        save_npz_atomic(self.checkpoint_path, payload)
        save_npz_atomic(self.frame_path(frame), frame_arrays(state, fragment_id, damage))
        self.write_csv()

    def write_csv(self) -> None:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(self.columns)
        for row in self.rows:
            writer.writerow([_csv_value(self.columns[i], v) for i, v in enumerate(row)])
        write_text_atomic(self.csv_path, buffer.getvalue())

    # reading back
    def load_checkpoint(self) -> Checkpoint:
        """Read ``checkpoint.npz``; :class:`OutputError` if it is missing, damaged or does not
        belong to this scene (other diagnostics columns)."""
        data = read_npz(self.checkpoint_path)
        missing = [key for key in ("columns", "frame", "rows") if key not in data]
        if missing:
            raise _damaged(self.checkpoint_path, f"no '{missing[0]}' array")
        columns = [str(c) for c in data["columns"]]
        if columns != self.columns:
            raise OutputError(f"{self.checkpoint_path}: diagnostics columns {columns} differ "
                              f"from the scene's {self.columns}")
        rows = data["rows"]
        frame = int(data["frame"])
        if rows.ndim != 2 or rows.shape[0] != frame + 1 or rows.shape[1] != len(columns):
            raise _damaged(self.checkpoint_path, f"{rows.shape} diagnostics rows for frame {frame}")
        solver_state = {key[len(_SOLVER_PREFIX):]: value for key, value in data.items()
                        if key.startswith(_SOLVER_PREFIX)}
        self.rows = [list(map(float, r)) for r in rows]
        return Checkpoint(frame=frame, solver_state=solver_state, rows=self.rows)

    def frame_complete(self, frame: int) -> bool:
        """Whether the file of ``frame`` exists and is a complete archive."""
        try:
            check_npz_complete(self.frame_path(frame))
        except OutputError:
            return False
        return True

    def check_frames(self, last: int) -> None:
        """OutputError unless frames 0..last-1 are present and complete (frame ``last`` may be
        missing: a resume rewrites it from the checkpoint)."""
        for frame in range(last):
            check_npz_complete(self.frame_path(frame))

    def read_scene(self) -> Any:
        from fracture_gs.config.scene import read_yaml

        return read_yaml(self.scene_path)

    def write_plot(self) -> None:
        """Render ``diagnostics.png`` from the rows so far (no-op without rows)."""
        if self.rows:
            plot_diagnostics(self.columns, self.rows, self.object_names, self.png_path)


def _plain_array(key: str, value: Any) -> np.ndarray:
    """A solver ``state_dict`` entry as a numpy array (tensors moved to the CPU, exact)."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    if isinstance(value, (np.ndarray, np.generic, int, float, bool)):
        return np.asarray(value)
    raise TypeError(f"state_dict['{key}'] is a {type(value).__name__}; checkpoints hold only "
                    "arrays, tensors and numbers")


def _csv_value(column: str, value: float) -> str:
    if column in ("frame", "steps", "fractured"):
        return str(int(value))
    return repr(float(value)) if math.isfinite(value) else "nan"


def read_diagnostics_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a ``diagnostics.csv`` as float arrays."""
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader)
        values = np.array([[float(v) for v in row] for row in reader], dtype=np.float64)
    values = values.reshape(-1, len(header))
    return {name: values[:, i] for i, name in enumerate(header)}


def plot_diagnostics(columns: Sequence[str], rows: Sequence[Sequence[float]],
                     object_names: Sequence[str], path: Path) -> None:
    """Momentum components and energies over time (like the paper's Fig. 7 / 8)."""
    from matplotlib.figure import Figure  # Agg canvas, no pyplot global state

    data = np.asarray(rows, dtype=np.float64).reshape(-1, len(columns))
    col = {name: data[:, i] for i, name in enumerate(columns)}
    time = col["time"]
    fig = Figure(figsize=(8, 7))
    ax_p, ax_e = fig.subplots(2, 1, sharex=True)
    colours = {"x": "tab:red", "y": "tab:green", "z": "tab:blue"}
    for axis, colour in colours.items():
        ax_p.plot(time, col[f"p{axis}"], color=colour, lw=2, label=f"total p{axis}")
        for k, name in enumerate(object_names):
            ax_p.plot(time, col[f"{name}_p{axis}"], color=colour, lw=1,
                      ls=("--", ":", "-.")[k % 3], label=f"{name} p{axis}")
    ax_p.set_ylabel("momentum")
    ax_p.legend(fontsize=7, ncol=3)
    ax_p.grid(alpha=0.3)
    for name, colour in (("kinetic", "tab:orange"), ("elastic", "tab:purple"),
                         ("gravitational", "tab:brown"), ("total_energy", "black")):
        ax_e.plot(time, col[name], color=colour, lw=2, label=name.replace("_", " "))
    fracture = col.get("fracture_energy")
    if fracture is not None and np.nanmax(np.abs(fracture)) > 0:
        ax_e.plot(time, fracture, color="tab:cyan", lw=2, label="fracture energy")
        ax_e.plot(time, col["total_energy"] + fracture, color="black", lw=1.5, ls="--",
                  label="total + fracture")
    for k, name in enumerate(object_names):
        ax_e.plot(time, col[f"{name}_kinetic"], color="tab:orange", lw=1,
                  ls=("--", ":", "-.")[k % 3], label=f"{name} kinetic")
    ax_e.set_xlabel("time [s]")
    ax_e.set_ylabel("energy")
    ax_e.legend(fontsize=7, ncol=2)
    ax_e.grid(alpha=0.3)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    write_bytes_atomic(path, buffer.getvalue())
