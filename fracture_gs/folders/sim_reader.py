"""Reading a simulation folder (layout: :mod:`fracture_gs.io.sim_layout`; written by
:mod:`fracture_gs.folders.sim_writer`; docs/file_formats.md §4).

```python
sim = Simulation.open("output/sims/two_spheres")     # SimulationError: one line naming the file
sim.frames                                            # [0, 1, ..., 24]
frame = sim.load_frame(12, device)                    # x, F_E, fractured, ... as tensors
```
Every problem with the folder raises :class:`SimulationError` with a one-line message that names
the file or option at fault, so command-line tools can print it and exit with status 2.
"""
from __future__ import annotations

import csv
import re
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fracture_gs.config.scene import SceneConfig, SceneError, parse_scene, read_yaml
from fracture_gs.folders.run_record import (RunRecordError, hash_files, model_change, npz_digest,
                                            read_run_record)
from fracture_gs.io.manifest import Manifest
from fracture_gs.io.sim_layout import (OPTIONAL_FRAME_ARRAYS, PARTICLE_ARRAYS, PARTICLES_FILE,
                                       RENDER_ARRAYS, SCENE_FILE, SimLayout)


class OutputError(ValueError):
    """A file of an output folder that cannot be used: missing, unreadable, truncated or not
    written by ``simulate.py``. The message is one line naming the file."""


def damaged_file(path: Path, reason: str) -> OutputError:
    """The OutputError of a file that cannot be read for ``reason``."""
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
        raise damaged_file(path, exc.strerror or type(exc).__name__) from None
    if not magic.startswith(b"PK"):
        raise damaged_file(path, "empty file" if not magic else "not an .npz archive")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise damaged_file(path, str(exc).splitlines()[0] if str(exc) else type(exc).__name__) \
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
        raise damaged_file(path, str(exc)) from None


def load_frame(path: str | Path) -> dict[str, np.ndarray]:
    """Read one frame file into a dict of arrays (:class:`OutputError` if it is damaged)."""
    return read_npz(path)


def read_diagnostics_csv(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a ``diagnostics.csv`` as float arrays."""
    with open(path, newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader)
        values = np.array([[float(v) for v in row] for row in reader], dtype=np.float64)
    values = values.reshape(-1, len(header))
    return {name: values[:, i] for i, name in enumerate(header)}


class SimulationError(ValueError):
    """A simulation folder (or a request on it) that cannot be used; the message is one line
    naming the file or option at fault."""


@dataclass(frozen=True)
class SimParticles:
    """Constant per-particle data of a run (``particles.npz``), N rows in frame order."""

    rest_x: np.ndarray          # (N,3) float32 world positions at frame 0
    obj_id: np.ndarray          # (N,) int32
    is_surface: np.ndarray      # (N,) bool
    gaussian_index: np.ndarray  # (N,) int64, row in the object's point_cloud.ply or -1
    rest_volume: np.ndarray     # (N,) float32
    part_id: np.ndarray | None = None  # (N,) int32 part within the object (None in older runs)

    def __len__(self) -> int:
        return int(self.rest_x.shape[0])


@dataclass(frozen=True)
class SimFrame:
    """One frame of a run as tensors on one device."""

    index: int
    x: torch.Tensor          # (N,3) float32
    F_E: torch.Tensor        # (N,3,3) float32 elastic deformation gradient
    fractured: torch.Tensor  # (N,) bool, latched fracture flag
    fragment_id: torch.Tensor | None = None  # (N,) int64 connected piece, None in older runs
    damage: torch.Tensor | None = None       # (N,) float32 brittle damage (0 elsewhere), None in older runs

    def to(self, device: torch.device) -> "SimFrame":
        return SimFrame(self.index, self.x.to(device), self.F_E.to(device),
                        self.fractured.to(device),
                        self.fragment_id.to(device) if self.fragment_id is not None else None,
                        self.damage.to(device) if self.damage is not None else None)


def _load_npz(path: Path, names: tuple[str, ...],
              optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Arrays ``names`` (and those of ``optional`` that are present) of an ``.npz``;
    SimulationError naming the file when it cannot be read or lacks one of ``names``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [name for name in names if name not in data.files]
            if missing:
                raise SimulationError(f"{path}: missing array '{missing[0]}'")
            return {name: data[name] for name in names + optional if name in data.files}
    except FileNotFoundError:
        raise SimulationError(f"{path}: file not found") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        if isinstance(exc, SimulationError):
            raise
        raise SimulationError(f"{path}: not a readable .npz file ({type(exc).__name__})") from None


def _check_one_run(layout: SimLayout, frames: list[int], scene: SceneConfig) -> None:
    """SimulationError unless the frame files are those the folder's run wrote: each frame its
    ``run.json`` records present, unchanged, and no other frame file (a missing last frame is
    refused as a missing middle one is), and the scene's models unchanged since. A run of an
    older version (no ``run.json``) is checked by its frame numbers, its diagnostics rows and
    its manifest."""
    try:
        record = read_run_record(layout.run_path)
    except RunRecordError as exc:
        raise SimulationError(str(exc)) from None
    if record is None:
        _check_one_older_run(layout, frames)
        return
    expected = record.last_frame
    missing = next((f for f in range(expected + 1) if f not in set(frames)), None)
    if missing is not None:
        raise SimulationError(f"{layout.frame_path(missing)} is missing (the run wrote frames "
                              f"0..{expected}); the run is incomplete or damaged: simulate it again")
    for frame in frames:
        try:
            same = frame <= expected and npz_digest(layout.frame_path(frame)) == record.frames[frame]
        except RunRecordError as exc:
            raise SimulationError(str(exc)) from None
        if not same:
            raise SimulationError(f"{layout.frame_path(frame)} was not written by the run in "
                                  f"{layout.root} (frames of two runs are mixed): simulate it "
                                  "again")
    for index, obj in enumerate(scene.objects):
        recorded = record.models.get(obj.name)
        if obj.model is not None and recorded is not None:
            change = model_change(obj.name, recorded, obj.model)
            if change is not None:
                raise SimulationError(f"{layout.scene_path}: objects[{index}].model: {change}; "
                                      "simulate the scene again")


def _check_one_older_run(layout: SimLayout, frames: list[int]) -> None:
    """:func:`_check_one_run` for a run without ``run.json``."""
    present = set(frames)
    last = frames[-1]
    try:
        rows = read_diagnostics_csv(layout.csv_path)["frame"] if layout.csv_path.is_file() else []
        last = max(last, int(max(rows, default=last)))
    except (OSError, ValueError, StopIteration):
        pass   # an unreadable CSV tells nothing about the frames
    gap = next((f for f in range(last + 1) if f not in present), None)
    if gap is not None:
        missing = layout.frame_path(gap)
        raise SimulationError(f"{missing} is missing (the run has frames up to {last}); "
                              "the run is incomplete or damaged: simulate it again")
    manifest = Manifest.load(layout.root)
    if manifest.exists():
        foreign = [f for f in frames if layout.frame_path(f) not in manifest]
        if foreign:
            raise SimulationError(f"{layout.frame_path(foreign[0])} was not written by the run in "
                                  f"{layout.root} (frames of two runs are mixed): simulate it "
                                  "again")


class Simulation:
    """An opened simulation folder: its resolved scene, constant particle data and frames."""

    def __init__(self, root: Path, scene: SceneConfig, particles: SimParticles,
                 frames: list[int]) -> None:
        self.root = root
        self.scene = scene
        self.particles = particles
        self.frames = frames

    @classmethod
    def open(cls, path: str | Path) -> "Simulation":
        """Check and open a folder written by ``simulate.py``.

        Raises SimulationError when the folder, ``scene.yaml`` (or a ``model`` folder it
        names), ``particles.npz`` or every frame is missing, or the files disagree.
        """
        root = Path(path)
        if not root.is_dir():
            raise SimulationError(f"{root}: no such simulation folder")
        layout = SimLayout(root)
        scene_path = layout.scene_path
        if not scene_path.is_file():
            raise SimulationError(f"{scene_path}: file not found (not a simulate.py output folder)")
        try:
            scene = parse_scene(read_yaml(scene_path), base_dir=root, source=scene_path)
        except SceneError as exc:
            message = str(exc) if str(scene_path) in str(exc) else f"{scene_path}: {exc}"
            raise SimulationError(message) from None
        arrays = _load_npz(root / PARTICLES_FILE, PARTICLE_ARRAYS, optional=("part_id",))
        particles = SimParticles(
            rest_x=arrays["rest_x"].astype(np.float32), obj_id=arrays["obj_id"].astype(np.int32),
            is_surface=arrays["is_surface"].astype(bool),
            gaussian_index=arrays["gaussian_index"].astype(np.int64),
            rest_volume=arrays["rest_volume"].astype(np.float32),
            part_id=arrays["part_id"].astype(np.int32) if "part_id" in arrays else None)
        count = len(particles)
        for name in PARTICLE_ARRAYS:
            if arrays[name].shape[0] != count:
                raise SimulationError(f"{root / PARTICLES_FILE}: '{name}' has "
                                      f"{arrays[name].shape[0]} rows, rest_x has {count}")
        if count and (particles.obj_id.min() < 0 or particles.obj_id.max() >= len(scene.objects)):
            raise SimulationError(f"{root / PARTICLES_FILE}: obj_id outside 0..{len(scene.objects) - 1}"
                                  f" (the scene has {len(scene.objects)} objects)")
        frames = layout.frames_on_disk()
        if not frames:
            raise SimulationError(f"{layout.frames_dir}: no frame_*.npz files (the run wrote no frames)")
        _check_one_run(layout, frames, scene)
        return cls(root, scene, particles, frames)

    def fingerprint(self) -> str:
        """SHA-256 (hex) of ``scene.yaml`` and ``particles.npz``: the same for every copy of one
        run and different for a run of another scene or other particles (SimulationError when a
        file cannot be read)."""
        try:
            return hash_files([self.root / SCENE_FILE, self.root / PARTICLES_FILE])
        except OSError as exc:
            raise SimulationError(f"{exc.filename}: cannot be read ({exc.strerror or exc})") \
                from None

    def run_id(self) -> str | None:
        """The id of the run that wrote the frames (its ``run.json``), None for a run of an
        older version."""
        try:
            record = read_run_record(SimLayout(self.root).run_path)
        except RunRecordError as exc:
            raise SimulationError(str(exc)) from None
        return record.run if record is not None else None

    @property
    def object_names(self) -> list[str]:
        return [obj.name for obj in self.scene.objects]

    def frame_path(self, index: int) -> Path:
        return SimLayout(self.root).frame_path(index)

    def select_frames(self, spec: str | None) -> list[int]:
        """Frames named by ``spec``: None (all), ``a`` (one), ``a:b`` (a up to but not including
        b, as in Python), ``a:`` or ``:b``. SimulationError when the range leaves the run or
        a frame inside it is missing."""
        if spec is None:
            return list(self.frames)
        first, last = self.frames[0], self.frames[-1]
        run = f"the run has frames {first}..{last}"
        match = re.fullmatch(r"\s*(\d*)\s*(:?)\s*(\d*)\s*", spec)
        if match is None or (match.group(2) == "" and match.group(3) != "") or \
                not (match.group(1) or match.group(3)):
            raise SimulationError(f"--frames {spec}: expected a, a:b, a: or :b (frame numbers)")
        start = int(match.group(1)) if match.group(1) else first
        if match.group(2):
            stop = int(match.group(3)) if match.group(3) else last + 1
        else:
            stop = start + 1
        if start < first or start > last or stop - 1 > last:
            raise SimulationError(f"--frames {spec}: outside the run ({run})")
        if stop <= start:
            raise SimulationError(f"--frames {spec}: empty range")
        available = set(self.frames)
        missing = [f for f in range(start, stop) if f not in available]
        if missing:
            raise SimulationError(f"--frames {spec}: {self.frame_path(missing[0])} is missing")
        return list(range(start, stop))

    def load_frame(self, index: int, device: torch.device | None = None) -> SimFrame:
        """Frame ``index`` as tensors (SimulationError naming the file if it is unusable)."""
        path = self.frame_path(index)
        arrays = _load_npz(path, RENDER_ARRAYS, OPTIONAL_FRAME_ARRAYS)
        count = len(self.particles)
        shapes = {"x": (count, 3), "F_E": (count, 3, 3), "fractured": (count,), "fragment_id": (count,),
                  "damage": (count,)}
        for name, shape in shapes.items():
            if name in arrays and arrays[name].shape != shape:
                raise SimulationError(f"{path}: '{name}' has shape {arrays[name].shape}, expected "
                                      f"{shape} ({count} particles in {PARTICLES_FILE})")
        x, F_E = arrays["x"].astype(np.float32), arrays["F_E"].astype(np.float32)
        if not (np.isfinite(x).all() and np.isfinite(F_E).all()):
            raise SimulationError(f"{path}: positions or F_E contain NaN or Inf")
        fragment_id = None
        if "fragment_id" in arrays:
            labels = arrays["fragment_id"]
            if labels.dtype.kind not in "iu" or (count and not (0 <= labels.min() and labels.max() < count)):
                raise SimulationError(f"{path}: 'fragment_id' must hold integer labels in [0, {count})")
            fragment_id = torch.from_numpy(labels.astype(np.int64))
        damage = None
        if "damage" in arrays:
            values = arrays["damage"].astype(np.float32)
            if not (np.isfinite(values).all() and (values >= 0).all() and (values <= 1).all()):
                raise SimulationError(f"{path}: 'damage' must hold values in [0, 1]")
            damage = torch.from_numpy(values)
        device = device if device is not None else torch.device("cpu")
        return SimFrame(index, torch.from_numpy(x).to(device), torch.from_numpy(F_E).to(device),
                        torch.from_numpy(arrays["fractured"].astype(bool)).to(device),
                        fragment_id.to(device) if fragment_id is not None else None,
                        damage.to(device) if damage is not None else None)
