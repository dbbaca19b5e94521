"""A ``train.py`` model folder as the renderer reads it (docs/training.md), and a writer for one.

Layout: ``particles.ply`` (x y z volume is_surface part_id gaussian_index, model frame),
``point_cloud/iteration_N/point_cloud.ply`` (3DGS layout; the highest N counts), optionally
``particles.json`` with the rest particle ``spacing`` (model frame).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import plyfile

from fracture_gs.gaussians import GaussianModel, write_ply
from fracture_gs.mpm.output import write_bytes_atomic, write_text_atomic

PARTICLES_PLY = "particles.ply"
PARTICLES_JSON = "particles.json"


class ModelError(ValueError):
    """A model folder (or its binding to the simulation) that cannot be drawn; one line."""


def latest_point_cloud(model_dir: Path) -> Path:
    """``point_cloud/iteration_N/point_cloud.ply`` with the highest N (ModelError if none)."""
    found = []
    root = model_dir / "point_cloud"
    for child in root.iterdir() if root.is_dir() else []:
        if child.name.startswith("iteration_") and child.name[10:].isdigit() and \
                (child / "point_cloud.ply").is_file():
            found.append((int(child.name[10:]), child / "point_cloud.ply"))
    if not found:
        raise ModelError(f"{model_dir}: no point_cloud/iteration_*/point_cloud.ply "
                         "(not a train.py model folder)")
    return max(found)[1]


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
    """Write ``particles.ply``, ``point_cloud/iteration_<iteration>/point_cloud.ply`` and, with
    ``spacing``, ``particles.json`` into ``folder`` (every file atomically). Returns the folder."""
    count = x.shape[0]
    if gaussian_index.max(initial=-1) >= gaussians.num_gaussians:
        raise ValueError(f"gaussian_index reaches {int(gaussian_index.max())}, the model has "
                         f"{gaussians.num_gaussians} Gaussians")
    folder.mkdir(parents=True, exist_ok=True)
    vertex = np.empty(count, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("volume", "<f4"),
                                     ("is_surface", "u1"), ("part_id", "<i4"),
                                     ("gaussian_index", "<i4")])
    vertex["x"], vertex["y"], vertex["z"] = np.asarray(x, dtype=np.float32).T
    vertex["volume"] = volume
    vertex["is_surface"] = is_surface
    vertex["part_id"] = 0 if part_id is None else part_id
    vertex["gaussian_index"] = gaussian_index
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], byte_order="<")
    import io

    buffer = io.BytesIO()
    ply.write(buffer)
    write_bytes_atomic(folder / PARTICLES_PLY, buffer.getvalue())
    write_ply(str(folder / "point_cloud" / f"iteration_{iteration}" / "point_cloud.ply"), gaussians)
    if spacing is not None:
        write_text_atomic(folder / PARTICLES_JSON, json.dumps({"spacing": float(spacing)}) + "\n")
    return folder
