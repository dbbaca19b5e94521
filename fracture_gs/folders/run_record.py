"""``run.json`` of a simulation folder: which run wrote its frames and from which models.

``simulate.py`` writes the file when a run starts and again after each frame::

    {"format": "fracture_gs/run-v1", "run": "<random hex id of this run>",
     "models": {"teapot": {"folder": "/abs/output/teapot", "particles": "<sha256>",
                           "point_cloud": "point_cloud/iteration_800/point_cloud.ply",
                           "gaussians": "<sha256>"}},
     "frames": ["<digest of frame 0>", "<digest of frame 1>", ...]}

A frame's digest is the SHA-256 of the names, CRC-32s and sizes of the arrays in its ``.npz``
(read from the archive's directory, so checking every frame of a run reads a few hundred bytes
per frame, not the frames): a frame from another run, a damaged frame and a missing frame (the
last one included) are found before a reader uses any. The run id is also stored in
``checkpoint.npz`` (its ``run`` entry), so a checkpoint of another run is not resumed. The models'
SHA-256s are of their ``particles.ply`` and of the point cloud the renderer draws (the highest
iteration): a model retrained after the simulation is refused instead of binding the old
particles to new Gaussians. The frame files themselves are unchanged by all this.
"""
from __future__ import annotations

import hashlib
import json
import os
import uuid
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.model_layout import PARTICLES_FILE, latest_iteration, point_cloud_path

RUN_FORMAT = "fracture_gs/run-v1"


class RunRecordError(ValueError):
    """A ``run.json`` or a file it describes that cannot be used; one line naming the file."""


def new_run_id() -> str:
    """A fresh random run id."""
    return uuid.uuid4().hex


def hash_files(paths: Iterable[Path]) -> str:
    """SHA-256 (hex) of the files' contents, one after another (OSError when one cannot be
    read)."""
    digest = hashlib.sha256()
    for path in paths:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def npz_digest(path: Path) -> str:
    """Digest of an ``.npz`` from its directory: names, CRC-32s and sizes of its arrays
    (RunRecordError naming the file when it is missing or not a complete archive)."""
    try:
        with zipfile.ZipFile(path) as archive:
            entries = sorted((info.filename, info.CRC, info.file_size)
                             for info in archive.infolist())
    except FileNotFoundError:
        raise RunRecordError(f"{path}: file not found") from None
    except (OSError, zipfile.BadZipFile) as exc:
        raise RunRecordError(f"{path}: cannot be read ({exc}); the file is damaged or was not "
                             "written by simulate.py") from None
    text = ";".join(f"{name}:{crc:08x}:{size}" for name, crc, size in entries)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def model_identity(model: Path) -> dict[str, Any]:
    """What a scene object's ``model`` (a model folder, or a ``particles.ply`` file) is made of
    now: SHA-256 of its particles and of the point cloud of its highest iteration (OSError when a
    file cannot be read)."""
    if not model.is_dir():
        return {"folder": str(model), "particles": hash_files([model]),
                "point_cloud": None, "gaussians": None}
    iteration = latest_iteration(str(model))
    cloud = Path(point_cloud_path(str(model), iteration)) if iteration is not None else None
    return {"folder": str(model), "particles": hash_files([model / PARTICLES_FILE]),
            "point_cloud": cloud.relative_to(model).as_posix() if cloud else None,
            "gaussians": hash_files([cloud]) if cloud else None}


def model_change(name: str, recorded: dict[str, Any], model: Path) -> str | None:
    """How the model of object ``name`` differs from ``recorded`` (a one-line reason), or None
    when it is the same."""
    try:
        now = model_identity(model)
    except OSError as exc:
        return f"{model}: cannot be read ({exc.strerror or exc})"
    if now["particles"] != recorded.get("particles"):
        what = model / PARTICLES_FILE if model.is_dir() else model
        return f"{what} changed since the simulation (the model was retrained or replaced)"
    if (now["point_cloud"], now["gaussians"]) != (recorded.get("point_cloud"),
                                                  recorded.get("gaussians")):
        return (f"{model}: its Gaussians ({now['point_cloud']}) are not those the run was "
                f"simulated with ({recorded.get('point_cloud')}): the model was retrained since")
    return None


@dataclass
class RunRecord:
    """The content of ``run.json``."""

    run: str
    models: dict[str, dict[str, Any]] = field(default_factory=dict)
    frames: list[str] = field(default_factory=list)

    def write(self, path: Path) -> None:
        """Write the record (atomically)."""
        content = {"format": RUN_FORMAT, "run": self.run, "models": self.models,
                   "frames": self.frames}
        write_text_atomic(path, json.dumps(content, indent=1) + "\n")

    def record_frame(self, frame: int, digest: str) -> None:
        """Frame ``frame`` was written with ``digest``; later frames are forgotten."""
        self.frames = self.frames[:frame] + [digest]

    @property
    def last_frame(self) -> int:
        """The last frame written (-1 before frame 0)."""
        return len(self.frames) - 1


def read_run_record(path: Path) -> RunRecord | None:
    """The record in ``path``; None when there is none (a run of an older version);
    RunRecordError when it is not one."""
    if not os.path.lexists(path):
        return None
    try:
        content = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RunRecordError(f"{path}: not a readable JSON file ({type(exc).__name__})") from None
    if not isinstance(content, dict) or content.get("format") != RUN_FORMAT:
        raise RunRecordError(f"{path}: not written by simulate.py (format is not {RUN_FORMAT})")
    run, models, frames = content.get("run"), content.get("models"), content.get("frames")
    if not isinstance(run, str) or not isinstance(models, dict) or not isinstance(frames, list) \
            or not all(isinstance(f, str) for f in frames) \
            or not all(isinstance(m, dict) for m in models.values()):
        raise RunRecordError(f"{path}: damaged (expected 'run', 'models' and 'frames')")
    return RunRecord(run=run, models=models, frames=frames)
