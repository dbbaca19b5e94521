"""Reading and writing the files of a train.py model folder (layout and rules:
:mod:`fracture_gs.io.model_layout`)."""
from __future__ import annotations

import ast
import contextlib
import csv
import json
import os
import shutil
import zipfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import plyfile
import torch
import trimesh

from fracture_gs.gaussians import GaussianModel, write_ply
from fracture_gs.io.atomic import atomic_path, write_text_atomic
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import remove_written_tree
from fracture_gs.io.model_layout import (EVALUATION_DIR, LOCK_NAME, PARTICLES_FILE, PARTICLES_JSON,
                                         RENDER_SPLITS, ModelError, iterations, point_cloud_path)
from fracture_gs.io.particles_ply import write_particles_ply

def write_text(path: str, text: str) -> None:
    """Write a text file of the folder (atomically)."""
    write_text_atomic(path, text)


def write_json(path: str, content: Any) -> None:
    write_text(path, json.dumps(content, indent=2) + "\n")


class OutputFolder:
    """The model folder of one run; remembers what this run created so that a run stopped by
    bad input can leave the folder as it found it (a crash or Ctrl-C keeps everything, so
    the last checkpoint stays usable)."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.existed = os.path.isdir(path)
        self.created: list[str] = []

    def file(self, *parts: str) -> str:
        """Absolute path of a file in the folder (recorded as created by this run if new)."""
        path = os.path.join(self.path, *parts)
        if not os.path.exists(path):
            self.created.append(path)
        return path

    def discard(self) -> None:
        """Remove what this run created (the whole folder if the run created it)."""
        if not self.existed:
            shutil.rmtree(self.path, ignore_errors=True)
            return
        for path in reversed(self.created):
            if os.path.isfile(path):
                os.remove(path)
            elif os.path.isdir(path):
                shutil.rmtree(path, ignore_errors=True)


@contextlib.contextmanager
def run_lock(path: str) -> Iterator[None]:
    """Hold the lock of the model folder ``path`` (its ``.train.lock``) for one train.py run
    (:func:`fracture_gs.io.lock.folder_lock`: FolderBusy naming the folder when another run
    holds it, since two runs writing one folder would mix their files). The lock file is removed
    when the run ends; a run killed outright leaves it behind, harmlessly."""
    with folder_lock(path, LOCK_NAME, "train.py", "model folder"):
        yield


# ----------------------------------------------------------------------------- cfg_args


def write_cfg_args(path: str, options: dict[str, Any]) -> None:
    """Write ``Namespace(key=value, ...)`` as 3DGS's train.py does."""
    arguments = ", ".join(f"{key}={value!r}" for key, value in options.items())
    write_text(path, f"Namespace({arguments})")


def read_cfg_args(path: str) -> dict[str, Any]:
    """Parse a 3DGS ``cfg_args`` file (a ``Namespace(...)`` repr) without evaluating code."""
    with open(path, encoding="utf-8") as handle:
        text = handle.read().strip()
    try:
        call = ast.parse(text, mode="eval").body
        if not (isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Namespace"):
            raise ValueError("not a Namespace(...) call")
        return {keyword.arg: ast.literal_eval(keyword.value) for keyword in call.keywords}
    except (SyntaxError, ValueError) as error:
        raise ValueError(f"{path}: not a cfg_args file ({error})") from None


def write_input_ply(path: str, position: np.ndarray, normal: np.ndarray,
                    color: np.ndarray) -> None:
    """3DGS's ``input.ply`` layout: x y z nx ny nz (float32) red green blue (uint8)."""
    vertices = np.empty(len(position), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                               ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                                               ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for axis, name in enumerate("xyz"):
        vertices[name] = position[:, axis]
        vertices["n" + name] = normal[:, axis]
    rgb = np.clip(np.rint(color * 255.0), 0, 255).astype(np.uint8)
    for channel, name in enumerate(("red", "green", "blue")):
        vertices[name] = rgb[:, channel]
    with atomic_path(path) as temporary:
        plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")]).write(str(temporary))


# ----------------------------------------------------------------------------- sdf, mesh


def write_sdf(path: str, sdf: torch.Tensor, hull_sdf: torch.Tensor, origin: tuple,
              voxel: float) -> None:
    with atomic_path(path) as temporary:
        with open(temporary, "wb") as handle:
            np.savez_compressed(handle, sdf=sdf.cpu().numpy().astype(np.float32),
                                hull_sdf=hull_sdf.cpu().numpy().astype(np.float32),
                                origin=np.asarray(origin, dtype=np.float64),
                                voxel=np.float64(voxel))


def read_sdf(path: str) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float], float]:
    """``sdf``, ``hull_sdf``, grid origin and voxel edge of an ``sdf.npz`` written by
    :func:`write_sdf`; a ``ValueError`` naming what is wrong otherwise."""
    try:
        with np.load(path, allow_pickle=False) as content:
            sdf, hull_sdf = content["sdf"], content["hull_sdf"]
            origin, voxel = content["origin"], float(content["voxel"])
    except EOFError:
        raise ValueError("not an sdf.npz of train.py (the file is empty)") from None
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile) as error:
        reason = str(error).splitlines()[0] if str(error) else "damaged"
        raise ValueError(f"not an sdf.npz of train.py ({type(error).__name__}: {reason})") \
            from None
    if sdf.ndim != 3 or hull_sdf.shape != sdf.shape or origin.shape != (3,) or not voxel > 0:
        raise ValueError(f"inconsistent sdf.npz (sdf {sdf.shape}, hull_sdf {hull_sdf.shape}, "
                         f"origin {origin.shape}, voxel {voxel})")
    return sdf, hull_sdf, tuple(float(v) for v in origin), voxel


def write_mesh(path: str, mesh: trimesh.Trimesh) -> None:
    with atomic_path(path) as temporary:
        mesh.export(str(temporary), file_type="ply")


# ----------------------------------------------------------------------------- log


def write_log_csv(path: str, rows: list[dict[str, Any]]) -> None:
    """train_log.csv with the union of the rows' keys as columns."""
    columns: list[str] = []
    for row in rows:
        columns += [key for key in row if key not in columns]
    with atomic_path(path) as temporary:
        with open(temporary, "w", newline="", encoding="utf-8") as handle:
            writer = csv.DictWriter(handle, fieldnames=columns)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v)
                                 for k, v in row.items()})


# ----------------------------------------------------------------------------- iterations


def remove_earlier_runs(model_path: str, kept: set[int]) -> None:
    """After a run wrote the iterations ``kept``: remove the point clouds of every other
    iteration (an earlier run's; their folders too once empty) and the renders and reports the
    tools made of the earlier model. Files the tools did not write stay."""
    for iteration in iterations(model_path):
        if iteration not in kept:
            cloud = Path(point_cloud_path(model_path, iteration))
            cloud.unlink()
            with contextlib.suppress(OSError):
                cloud.parent.rmdir()
    for name in (*RENDER_SPLITS, EVALUATION_DIR):
        remove_written_tree(Path(model_path) / name)


def model_spacing(model_dir: Path | None) -> float | None:
    """Rest particle spacing (model frame) from ``particles.json``, or None without one.

    Two layouts are read: ``{"spacing": s}`` (written by :func:`write_model_folder`) and the one
    ``train.py`` writes, with ``surface_spacing`` (Poisson-disk radius of the surface particles)
    and ``interior_particle_size`` (mean spacing of the interior samples, ``n_interior`` of them).
    For the latter the larger of the two counts: d_c = 1.5 × spacing must connect the sparser
    of the two particle sets, or intact bodies would fall apart into hidden "fragments".
    """
    if model_dir is None:
        return None
    path = model_dir / PARTICLES_JSON
    if not path.is_file():
        return None
    try:
        content = json.loads(path.read_text())
        if "spacing" in content:
            spacing = float(content["spacing"])
        else:
            spacing = float(content["surface_spacing"])
            if int(content.get("n_interior", 0)) > 0:
                spacing = max(spacing, float(content["interior_particle_size"]))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ModelError(f"{path}: no valid 'spacing' or 'surface_spacing' "
                         f"({type(exc).__name__})") from None
    if not spacing > 0:
        raise ModelError(f"{path}: spacing must be > 0, got {spacing}")
    return spacing


def estimated_spacing(points: np.ndarray) -> float:
    """Median distance from each point to its nearest neighbour (1e-3 for < 2 points)."""
    from scipy.spatial import cKDTree

    if points.shape[0] < 2:
        return 1e-3
    distance, _ = cKDTree(points).query(points, k=2)
    return float(np.median(distance[:, 1]))


def write_model_folder(folder: Path, x: np.ndarray, volume: np.ndarray, is_surface: np.ndarray,
                       gaussian_index: np.ndarray, gaussians: GaussianModel, *,
                       part_id: np.ndarray | None = None, spacing: float | None = None,
                       iteration: int = 0) -> Path:
    """A minimal model folder (not trained: scenes and benchmarks build their objects in code):
    ``particles.ply``, ``point_cloud/iteration_<iteration>/point_cloud.ply`` and, with
    ``spacing``, ``particles.json`` (every file atomically). Returns the folder."""
    if gaussian_index.max(initial=-1) >= gaussians.num_gaussians:
        raise ValueError(f"gaussian_index reaches {int(gaussian_index.max())}, the model has "
                         f"{gaussians.num_gaussians} Gaussians")
    folder.mkdir(parents=True, exist_ok=True)
    write_particles_ply(folder / PARTICLES_FILE, np.asarray(x, dtype=np.float32), volume,
                        is_surface, 0 if part_id is None else part_id, gaussian_index)
    write_ply(point_cloud_path(str(folder), iteration), gaussians)
    if spacing is not None:
        write_text_atomic(folder / PARTICLES_JSON, json.dumps({"spacing": float(spacing)}) + "\n")
    return folder
