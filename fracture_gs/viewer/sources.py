"""What the viewer shows: the frames of a simulation folder, or a trained model as one frame.

Both sources turn "frame t (with or without FPGO)" into a :class:`~fracture_gs.viewer.splats.
SplatFrame`. A simulation goes through the renderer's own code path — :class:`~fracture_gs.io.
sim_reader.Simulation` to read the frame and :class:`~fracture_gs.render.frame_gaussians.
SceneGaussians` to deform the Gaussians and run FPGO — so the viewer shows what ``render.py``
renders. Opening checks the folder exactly as ``render.py`` does and raises the same one-line
errors (:class:`~fracture_gs.folders.sim_reader.SimulationError`,
:class:`~fracture_gs.folders.model_folder.ModelError`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.gaussians import PlyFormatError, read_ply
from fracture_gs.mpm.fragments import piece_ranks
from fracture_gs.io.sim_layout import DIAGNOSTICS_CSV
from fracture_gs.folders.sim_reader import read_diagnostics_csv
from fracture_gs.render.frame_gaussians import FrameGaussians, SceneGaussians
from fracture_gs.io.model_layout import ModelError, latest_point_cloud
from fracture_gs.folders.sim_reader import Simulation
from fracture_gs.viewer.splats import SplatFrame, object_splats, unit_scale_for


@dataclass(frozen=True)
class SceneBounds:
    """Where the scene is (world units) and which way is up, for the initial camera."""

    lower: np.ndarray
    upper: np.ndarray
    up: np.ndarray


class FrameSource(Protocol):
    """Frames the viewer can show."""

    frames: list[int]
    object_names: list[str]
    bounds: SceneBounds
    has_fracture: bool          # FPGO and the fractured highlight mean something
    has_pieces: bool            # the frames carry fragment_id ("colour by piece")
    has_damage: bool            # the frames carry a brittle damage ("colour by damage")

    def prepare(self, frame: int, fpgo: bool) -> SplatFrame:
        """The splats of ``frame`` (FPGO on or off)."""

    def diagnostics(self, frame: int) -> dict[str, float]:
        """Momentum / energy numbers of ``frame`` (empty when unknown)."""


DIAGNOSTIC_FIELDS = ("time", "kinetic", "elastic", "gravitational", "total_energy", "fractured")


def _frame_diagnostics(columns: dict[str, np.ndarray] | None, frame: int) -> dict[str, float]:
    """One ``diagnostics.csv`` row as GUI numbers: |p|, px, py, pz and the energies."""
    if columns is None or "frame" not in columns:
        return {}
    rows = np.nonzero(columns["frame"] == frame)[0]
    if rows.size == 0:
        return {}
    row = int(rows[-1])
    values = {name: float(columns[name][row]) for name in DIAGNOSTIC_FIELDS if name in columns}
    if all(f"p{axis}" in columns for axis in "xyz"):
        momentum = [float(columns[f"p{axis}"][row]) for axis in "xyz"]
        values.update(px=momentum[0], py=momentum[1], pz=momentum[2],
                      momentum=math.sqrt(sum(p * p for p in momentum)))
    return values


class SimulationSource:
    """The frames of a ``simulate.py`` output folder, prepared like ``render.py`` prepares them."""

    has_fracture = True

    def __init__(self, folder: str | Path, device: torch.device,
                 settings: FPGOSettings | None = None, backend: str = "auto") -> None:
        self.sim = Simulation.open(folder)
        self.scene = SceneGaussians.from_simulation(self.sim, device, settings)
        self.device = device
        self.backend = backend
        self.frames = list(self.sim.frames)
        self.object_names = list(self.sim.object_names)
        last_frame = self.sim.load_frame(self.frames[-1])
        self.has_pieces = last_frame.fragment_id is not None
        self.has_damage = last_frame.damage is not None and any(
            material.model == "brittle" for obj in self.sim.scene.objects for material in obj.materials)
        self._obj_id = torch.from_numpy(self.sim.particles.obj_id.astype(np.int64))
        last = last_frame.x.numpy()
        points = np.concatenate([self.sim.particles.rest_x, last])
        gravity = np.asarray(self.sim.scene.gravity, np.float64)
        up = -gravity / np.linalg.norm(gravity) if np.linalg.norm(gravity) > 0 else \
            np.array([0.0, 0.0, 1.0])
        self.bounds = SceneBounds(points.min(0), points.max(0), up)
        self.unit_scale = unit_scale_for(self.bounds.lower, self.bounds.upper)
        csv_path = self.sim.root / DIAGNOSTICS_CSV
        try:
            self._diagnostics = read_diagnostics_csv(csv_path) if csv_path.is_file() else None
        except (OSError, ValueError, StopIteration):
            self._diagnostics = None   # the GUI then shows no numbers; the frames still work

    def prepare(self, frame: int, fpgo: bool) -> SplatFrame:
        started = time.perf_counter()
        loaded = self.sim.load_frame(frame, self.device)
        gaussians = self.scene.frame(loaded, fpgo=fpgo, backend=self.backend)
        ranks = None
        if loaded.fragment_id is not None:
            ranks = piece_ranks(loaded.fragment_id.cpu(), self._obj_id)
        splats = object_splats(gaussians, len(self.object_names), self.unit_scale,
                               loaded.fractured, ranks, loaded.damage.cpu() if loaded.damage is not None else None)
        return SplatFrame(index=frame, objects=splats, unit_scale=self.unit_scale,
                          gaussians=len(gaussians), fpgo_gaussians=int(gaussians.is_fpgo.sum()),
                          fractured_particles=int(loaded.fractured.sum()),
                          prepare_ms=(time.perf_counter() - started) * 1e3)

    def diagnostics(self, frame: int) -> dict[str, float]:
        return _frame_diagnostics(self._diagnostics, frame)


def model_gaussians(model_dir: Path, device: torch.device) -> FrameGaussians:
    """The Gaussians of a trained model's newest ``point_cloud.ply`` as a static frame
    (model frame = world frame, no particles). ModelError naming the folder or file."""
    if not model_dir.is_dir():
        raise ModelError(f"{model_dir}: no such model folder")
    ply = latest_point_cloud(model_dir)
    try:
        model = read_ply(str(ply), device=device)
    except PlyFormatError as exc:
        raise ModelError(str(exc)) from None
    count = model.num_gaussians
    if count == 0:
        raise ModelError(f"{ply}: the model has no Gaussians")
    with torch.no_grad():
        return FrameGaussians(
            means=model.means.detach().float(), covariances=model.covariances().detach().float(),
            opacities=model.opacities.detach().float().reshape(-1),
            sh=model.sh.detach().float(),
            view_rotations=torch.eye(3, device=device).expand(count, 3, 3),
            exclusive=torch.full((count,), -1, dtype=torch.int64, device=device),
            object_id=torch.zeros(count, dtype=torch.int32, device=device),
            is_fpgo=torch.zeros(count, dtype=torch.bool, device=device),
            particle=torch.full((count,), -1, dtype=torch.int64, device=device))


class ModelSource:
    """A trained model folder (``train.py`` output) shown as a single, static frame."""

    has_fracture = False
    has_pieces = False
    has_damage = False

    def __init__(self, folder: str | Path, device: torch.device) -> None:
        root = Path(folder)
        self.object_names = [root.resolve().name or "model"]
        self.frames = [0]
        self._gaussians = model_gaussians(root, device)
        means = self._gaussians.means.cpu().numpy()
        self.bounds = SceneBounds(means.min(0), means.max(0), np.array([0.0, 0.0, 1.0]))
        self.unit_scale = unit_scale_for(self.bounds.lower, self.bounds.upper)

    def prepare(self, frame: int, fpgo: bool) -> SplatFrame:
        started = time.perf_counter()
        splats = object_splats(self._gaussians, 1, self.unit_scale)
        return SplatFrame(index=frame, objects=splats, unit_scale=self.unit_scale,
                          gaussians=len(self._gaussians), fpgo_gaussians=0, fractured_particles=0,
                          prepare_ms=(time.perf_counter() - started) * 1e3)

    def diagnostics(self, frame: int) -> dict[str, float]:
        return {}


__all__ = ["DIAGNOSTIC_FIELDS", "FrameSource", "ModelSource", "SceneBounds", "SimulationSource",
           "model_gaussians"]
