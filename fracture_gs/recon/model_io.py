"""The ``-m`` model folder of train.py (3DGS-compatible, docs/file_formats.md §2) and its files.

Layout::

    cfg_args                                   the run's options as 3DGS writes them
    cameras.json                               3DGS camera list (test views, then train)
    input.ply                                  initial point cloud (x y z nx ny nz red green blue)
    point_cloud/iteration_N/point_cloud.ply    Gaussians, standard 3DGS attributes
    sdf.npz                                    sdf (nx,ny,nz), hull_sdf, origin, voxel
    mesh.ply                                   marching-cubes mesh of the SDF
    particles.ply                              x y z volume is_surface part_id gaussian_index
    particles.json                             spacing and counts (for the renderer)
    train_log.csv                              per-iteration loss / PSNR of both stages
    timings.json                               wall and CPU seconds per stage
    chkpnt<N>.pth                              resumable state of the Gaussian stage

Every file is written to a temporary name in the folder and renamed when complete.
"""
from __future__ import annotations

import ast
import contextlib
import csv
import json
import os
import re
import shutil
import tempfile
import zipfile
from argparse import Namespace
from typing import Any, Iterator

import numpy as np
import plyfile
import torch
import trimesh

from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.render.camera import Camera

PARTICLES_FILE = "particles.ply"
PARTICLES_JSON = "particles.json"
POINT_CLOUD_DIR = "point_cloud"
CHECKPOINT_PATTERN = re.compile(r"chkpnt(\d+)\.pth$")


@contextlib.contextmanager
def atomic_path(path: str) -> Iterator[str]:
    """Yield a temporary path next to ``path``; it replaces ``path`` only on success."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=".tmp_", suffix=os.path.splitext(path)[1],
                                         dir=folder)
    os.close(handle)
    try:
        yield temporary
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(temporary, 0o666 & ~umask)  # mkstemp creates 0600 files
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def write_text(path: str, text: str) -> None:
    with atomic_path(path) as temporary:
        with open(temporary, "w", encoding="utf-8") as handle:
            handle.write(text)


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


LOCK_NAME = ".train.lock"


@contextlib.contextmanager
def run_lock(path: str) -> Iterator[None]:
    """Hold an advisory lock on the model folder ``path`` (its ``.train.lock``) for one train.py
    run; the system releases it when the run ends or its process dies, so it never goes stale.
    ReconstructionError naming the folder when another run holds it (two runs writing one folder
    would mix their files). Where ``fcntl`` is missing (Windows) it does nothing."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover
        yield
        return
    os.makedirs(path, exist_ok=True)
    with open(os.path.join(path, LOCK_NAME), "a+", encoding="utf-8") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ReconstructionError(f"{path}: another train.py run is writing this model folder "
                                      "(it holds .train.lock); wait for it or give another -m") from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield


# ----------------------------------------------------------------------------- cfg_args


def write_cfg_args(path: str, options: dict[str, Any]) -> None:
    """Write ``Namespace(key=value, ...)`` like 3DGS's train.py does."""
    write_text(path, repr(Namespace(**options)))


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


# ----------------------------------------------------------------------------- cameras


def camera_entry(index: int, name: str, camera: Camera) -> dict[str, Any]:
    """One entry of 3DGS's cameras.json (camera-to-world position and rotation)."""
    camera_to_world = torch.linalg.inv(camera.world_to_camera.double()).numpy()
    return {"id": index, "img_name": name, "width": camera.width, "height": camera.height,
            "position": camera_to_world[:3, 3].tolist(),
            "rotation": [row.tolist() for row in camera_to_world[:3, :3]],
            "fy": camera.fy, "fx": camera.fx}


def write_cameras_json(path: str, views: list[tuple[str, Camera]]) -> None:
    write_json(path, [camera_entry(i, name, camera) for i, (name, camera) in enumerate(views)])


# ----------------------------------------------------------------------------- particles


def write_particles_ply(path: str, position: np.ndarray, volume: np.ndarray,
                        is_surface: np.ndarray, part_id: np.ndarray,
                        gaussian_index: np.ndarray, comments: dict[str, float]) -> None:
    """particles.ply: x y z volume (float32), is_surface (uint8), part_id, gaussian_index
    (int32); ``comments`` become ``comment key value`` header lines."""
    vertices = np.empty(len(position), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                               ("volume", "<f4"), ("is_surface", "u1"),
                                               ("part_id", "<i4"), ("gaussian_index", "<i4")])
    for axis, name in enumerate("xyz"):
        vertices[name] = position[:, axis]
    vertices["volume"] = volume
    vertices["is_surface"] = is_surface.astype(np.uint8)
    vertices["part_id"] = part_id
    vertices["gaussian_index"] = gaussian_index
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")], byte_order="<",
                          comments=[f"{key} {value!r}" for key, value in comments.items()])
    with atomic_path(path) as temporary:
        ply.write(temporary)


def read_particles_ply(path: str) -> dict[str, np.ndarray]:
    """The columns of a particles.ply plus its header comments (``comments``: dict)."""
    ply = plyfile.PlyData.read(path)
    data = ply["vertex"].data
    columns = {name: np.asarray(data[name]) for name in data.dtype.names}
    comments = {}
    for line in ply.comments:
        key, _, value = line.partition(" ")
        with contextlib.suppress(ValueError):
            comments[key] = float(value)
    columns["comments"] = comments
    return columns


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
        plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")]).write(temporary)


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
        mesh.export(temporary, file_type="ply")


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


def point_cloud_path(model_path: str, iteration: int) -> str:
    return os.path.join(model_path, POINT_CLOUD_DIR, f"iteration_{iteration}", "point_cloud.ply")


def latest_iteration(model_path: str) -> int | None:
    """Largest N of ``point_cloud/iteration_N`` (3DGS's ``searchForMaxIteration``)."""
    folder = os.path.join(model_path, POINT_CLOUD_DIR)
    if not os.path.isdir(folder):
        return None
    found = [int(m.group(1)) for name in os.listdir(folder)
             if (m := re.fullmatch(r"iteration_(\d+)", name))
             and os.path.isfile(os.path.join(folder, name, "point_cloud.ply"))]
    return max(found) if found else None


def checkpoints(model_path: str) -> list[tuple[int, str]]:
    """(iteration, path) of the chkpnt files in the folder, oldest first."""
    if not os.path.isdir(model_path):
        return []
    found = [(int(m.group(1)), os.path.join(model_path, name))
             for name in os.listdir(model_path) if (m := CHECKPOINT_PATTERN.fullmatch(name))]
    return sorted(found)
