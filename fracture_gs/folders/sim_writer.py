"""Writing a simulation folder (layout: :mod:`fracture_gs.io.sim_layout`) and the checkpoint
behind ``--resume``.

``particles.npz`` holds mass, rest_volume, obj_id, part_id, material_id, is_surface, rest_x and
gaussian_index; a frame file x, v, F_E, alpha, damage (float32), fractured (bool) and
fragment_id (int32); alpha is state field 0 of each particle's material model (NACC's α; for
brittle particles their damage d, as in ``damage``, which is 0 elsewhere). ``diagnostics.csv`` has
the columns of
:func:`diagnostics_columns`.

Every file is written to a temporary name in the same folder and renamed into place, so a
killed run never leaves a half-written file. For each frame the checkpoint is written
*before* the frame file: the checkpoint is therefore never behind the frames, and a resume
rewrites a frame that the checkpoint has but the folder lacks.
"""
from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from fracture_gs.folders.run_record import (RunRecord, RunRecordError, new_run_id, npz_digest,
                                            read_run_record)
from fracture_gs.folders.sim_reader import OutputError, check_npz_complete, damaged_file, read_npz
from fracture_gs.io.atomic import (remove_temporaries, save_npz_atomic, write_bytes_atomic,
                                   write_text_atomic)
from fracture_gs.io.manifest import Manifest, claim_folder, remove_written_tree
from fracture_gs.io.sim_layout import SimLayout, is_simulation_folder

_SOLVER_PREFIX = "solver/"
_RUN_KEY = "run"            # checkpoint.npz: the id of the run it belongs to (run.json's)
KIND = "simulation"         # the manifest kind of a simulation folder

BASE_COLUMNS = ("frame", "time", "steps", "dt_min", "px", "py", "pz", "kinetic", "elastic",
                "gravitational", "total_energy", "fractured")
OBJECT_COLUMNS = ("px", "py", "pz", "kinetic")
TAIL_COLUMNS = ("fragments", "impulse_x", "impulse_y", "impulse_z", "dissipated_energy")


def diagnostics_columns(object_names: Sequence[str]) -> list[str]:
    """CSV header: the columns of docs/file_formats.md §4, then ``<name>_px, _py, _pz, _kinetic`` per object, then
    ``fragments`` (pieces with >= 1 % of their object's particles), ``impulse_x, _y, _z`` (the
    impulse gravity and the boundaries gave since frame 0: p − p(0) equals it up to round-off) and
    ``dissipated_energy`` (the energy the material updates dissipated since frame 0, brittle damage's:
    kinetic + elastic + gravitational + dissipated energy never grows); last, so old readers keep their column positions."""
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
    row.append(_scalar(diagnostics.get("dissipated_energy", 0.0)))
    return row


# ----------------------------------------------------------------------------- checkpoint


@dataclass
class Checkpoint:
    """Everything needed to continue a run exactly after ``frame``."""

    frame: int
    solver_state: dict[str, Any]
    rows: list[list[float]]     # diagnostics rows of frames 0..frame
    run: str | None = None      # the run id it was written with (None: an older version's)


# ----------------------------------------------------------------------------- the folder


class SimulationOutput(SimLayout):
    """Writes (and, for ``--resume``, reads back) one simulation output folder; every file it
    writes is recorded in the folder's manifest (:mod:`fracture_gs.io.manifest`) and every frame
    in ``run.json`` (:mod:`fracture_gs.folders.run_record`)."""

    def __init__(self, root: str | Path, object_names: Sequence[str]) -> None:
        super().__init__(root)
        self.object_names = list(object_names)
        self.columns = diagnostics_columns(self.object_names)
        self.rows: list[list[float]] = []
        self.manifest = Manifest.load(self.root)
        self.record: RunRecord | None = None

    def claim(self, frames: int) -> None:
        """FolderTaken unless a fresh run of ``frames`` frames overwrites and mixes with no
        file the tools did not write in this folder (a user's folder, a copied run)."""
        numbers = set(self.frames_on_disk()) | set(range(frames + 1))
        self.manifest = claim_folder(self.root, KIND, [
            *self.output_files(), *(self.frame_path(f) for f in sorted(numbers))])

    # writing
    def remove_temporaries(self) -> None:
        """Delete temporary files that a killed run left behind (never complete files)."""
        for folder in (self.root, self.frames_dir):
            remove_temporaries(folder)

    def clear_earlier_run(self) -> int:
        """Remove the files the tools wrote for an earlier run in this folder: its frames,
        checkpoint and diagnostics, and the renders and evaluation made of it; a file they did
        not write stays. Returns how many files were removed."""
        self.remove_temporaries()
        removed = 0
        if self.manifest.exists():
            removed = len(remove_written_tree(self.root, separate=is_simulation_folder))
        self.manifest = Manifest(self.root, kind=KIND)
        return removed

    def start(self, scene: Mapping[str, Any], particles: Mapping[str, np.ndarray],
              record: RunRecord) -> None:
        """Begin a fresh run (after :meth:`clear_earlier_run`): write the scene, the constant
        particle arrays and the run record."""
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.rows = []
        self.record = record
        self.manifest.add(*self.output_files())
        self.manifest.save()
        self.write_scene(scene)
        save_npz_atomic(self.particles_path, particles)
        record.write(self.run_path)

    def adopt_frames(self, last: int) -> None:
        """Record the files of a resumed run (frames 0..``last``) in the manifest: a folder
        written before the tools kept one gets one."""
        if not self.manifest.exists():
            self.manifest = Manifest(self.root, kind=KIND)
            self.manifest.add(*self.output_files())
            self.manifest.add(*(self.frame_path(f) for f in range(last + 1)
                                if self.frame_path(f).is_file()))
            self.manifest.save()
        elif self.run_path not in self.manifest:
            self.manifest.add(self.run_path)
            self.manifest.save()

    def read_record(self) -> RunRecord | None:
        """The folder's ``run.json`` (None for a run of an older version); OutputError when it
        is damaged."""
        try:
            return read_run_record(self.run_path)
        except RunRecordError as exc:
            raise OutputError(str(exc)) from None

    def resume_record(self, checkpoint: Checkpoint, models: dict[str, dict[str, Any]]) -> None:
        """Take up the run record for a resume from ``checkpoint``: OutputError when the
        checkpoint or the frames before it belong to another run; a run of an older version
        gets a record of the frames it has."""
        record = self.read_record()
        if record is None:
            record = RunRecord(run=checkpoint.run or new_run_id(), models=models)
            for frame in range(checkpoint.frame):
                record.record_frame(frame, self.digest(frame))
        else:
            if checkpoint.run != record.run:
                raise OutputError(f"{self.checkpoint_path}: belongs to another run than the "
                                  f"frames (its run id is not the one in {self.run_path.name})")
            if not record.last_frame <= checkpoint.frame <= record.last_frame + 1:
                raise OutputError(f"{self.checkpoint_path}: holds frame {checkpoint.frame}, but "
                                  f"the run's frames end at {record.last_frame}")
            for frame in range(checkpoint.frame):
                if self.digest(frame) != record.frames[frame]:
                    raise OutputError(f"{self.frame_path(frame)}: was not written by this run "
                                      f"(its digest differs from {self.run_path.name})")
        self.record = record

    def digest(self, frame: int) -> str:
        """:func:`npz_digest` of frame ``frame`` (OutputError when it is missing or damaged)."""
        try:
            return npz_digest(self.frame_path(frame))
        except RunRecordError as exc:
            raise OutputError(str(exc)) from None

    def frame_recorded(self, frame: int) -> bool:
        """Whether ``run.json`` holds frame ``frame`` as the file now on disk has it."""
        if self.record is None or frame > self.record.last_frame:
            return False
        try:
            return self.digest(frame) == self.record.frames[frame]
        except OutputError:
            return False

    def write_scene(self, scene: Mapping[str, Any]) -> None:
        text = yaml.safe_dump(dict(scene), sort_keys=False, default_flow_style=None)
        write_text_atomic(self.scene_path, text)

    def write_frame(self, frame: int, arrays: Mapping[str, np.ndarray], row: list[float],
                    solver_state: Mapping[str, Any]) -> None:
        """Commit one frame (its arrays, the diagnostics row and the solver state for the
        checkpoint): checkpoint first, then the frame file, then the CSV."""
        if len(row) != len(self.columns):
            raise ValueError(f"diagnostics row has {len(row)} values, expected "
                             f"{len(self.columns)} ({', '.join(self.columns)})")
        self.rows = [r for r in self.rows if int(r[0]) < frame] + [list(row)]
        payload = {_SOLVER_PREFIX + key: _plain_array(key, value)
                   for key, value in solver_state.items()}
        payload.update(frame=np.int64(frame), rows=np.asarray(self.rows, dtype=np.float64),
                       columns=np.asarray(self.columns, dtype=np.str_))
        if self.record is not None:
            payload[_RUN_KEY] = np.asarray(self.record.run, dtype=np.str_)
        save_npz_atomic(self.checkpoint_path, payload)
        if self.frame_path(frame) not in self.manifest:   # recorded before the file appears
            self.manifest.add(self.frame_path(frame))
            self.manifest.save()
        save_npz_atomic(self.frame_path(frame), arrays)
        self.write_csv()
        if self.record is not None:
            self.record.record_frame(frame, self.digest(frame))
            self.record.write(self.run_path)

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
            raise damaged_file(self.checkpoint_path, f"no '{missing[0]}' array")
        columns = [str(c) for c in data["columns"]]
        if columns != self.columns:
            raise OutputError(f"{self.checkpoint_path}: diagnostics columns {columns} differ "
                              f"from the scene's {self.columns}")
        rows = data["rows"]
        frame = int(data["frame"])
        if rows.ndim != 2 or rows.shape[0] != frame + 1 or rows.shape[1] != len(columns):
            raise damaged_file(self.checkpoint_path, f"{rows.shape} diagnostics rows for frame {frame}")
        solver_state = {key[len(_SOLVER_PREFIX):]: value for key, value in data.items()
                        if key.startswith(_SOLVER_PREFIX)}
        self.rows = [list(map(float, r)) for r in rows]
        run = str(data[_RUN_KEY]) if _RUN_KEY in data else None
        return Checkpoint(frame=frame, solver_state=solver_state, rows=self.rows, run=run)

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
    dissipated = col.get("dissipated_energy")
    if dissipated is not None and np.nanmax(np.abs(dissipated)) > 0:
        ax_e.plot(time, dissipated, color="tab:cyan", lw=2, label="dissipated energy")
        ax_e.plot(time, col["total_energy"] + dissipated, color="black", lw=1.5, ls="--",
                  label="total + dissipated")
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
