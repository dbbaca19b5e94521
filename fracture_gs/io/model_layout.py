"""The ``-m`` model folder of train.py (3DGS-compatible) and its files.

Layout::

    cfg_args                                   the run's options as 3DGS writes them
    cameras.json                               3DGS camera list (test views, then train)
    input.ply                                  initial point cloud (x y z nx ny nz red green blue)
    point_cloud/iteration_N/point_cloud.ply    Gaussians, standard 3DGS attributes
    sdf.npz                                    sdf (nx,ny,nz), hull_sdf, origin, voxel
    mesh.ply                                   marching-cubes mesh of the SDF
    particles.ply                              x y z volume is_surface part_id gaussian_index
    particles.json                             spacing and counts (for the renderer)
    object.json                                box, centre and up direction (for placing it)
    train_log.csv                              per-iteration loss / PSNR of both stages
    timings.json                               wall and CPU seconds per stage
    chkpnt<N>.pth                              resumable state of the Gaussian stage
    train/ours_N/, test/ours_N/                render.py -m's renders and ground truth
    evaluation/                                evaluate.py -m's report

The folder holds the Gaussians of one training run: a run that finishes removes the
``point_cloud/iteration_N`` of earlier runs and the renders and reports made of them, so
readers (which take the highest N, as 3DGS does) never pair old Gaussians with new particles.
Every file is written atomically (:mod:`fracture_gs.io.atomic`).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

CFG_ARGS_FILE = "cfg_args"
CAMERAS_FILE = "cameras.json"
INPUT_PLY = "input.ply"
SDF_FILE = "sdf.npz"
MESH_FILE = "mesh.ply"
PARTICLES_FILE = "particles.ply"
PARTICLES_JSON = "particles.json"
OBJECT_FILE = "object.json"
TRAIN_LOG_FILE = "train_log.csv"
TIMINGS_FILE = "timings.json"
POINT_CLOUD_DIR = "point_cloud"
POINT_CLOUD_FILE = "point_cloud.ply"
RENDER_SPLITS = ("train", "test")
EVALUATION_DIR = "evaluation"
RENDERED_DIR = "renders"        # in <split>/ours_<N>/: render.py -m's images
GROUND_TRUTH_DIR = "gt"         # in <split>/ours_<N>/: the dataset's images beside them
LOCK_NAME = ".train.lock"
CHECKPOINT_PATTERN = re.compile(r"chkpnt(\d+)\.pth$")
_ITERATION_PATTERN = re.compile(r"iteration_(\d+)")


class ModelError(ValueError):
    """A model folder (or its binding to the simulation) that cannot be drawn; one line."""


def point_cloud_path(model_path: str, iteration: int) -> str:
    """``<model>/point_cloud/iteration_<iteration>/point_cloud.ply``."""
    return os.path.join(model_path, POINT_CLOUD_DIR, f"iteration_{iteration}", POINT_CLOUD_FILE)


def split_render_dir(model_path: str, split: str, iteration: int) -> str:
    """``<model>/<split>/ours_<iteration>``: render.py -m's renders and ground truth."""
    return os.path.join(model_path, split, f"ours_{iteration}")


def view_image_name(index: int) -> str:
    """File name of view ``index`` in the renders and ground-truth folders."""
    return f"{index:05d}.png"


def iterations(model_path: str) -> list[int]:
    """The N of every ``point_cloud/iteration_N`` that holds a point_cloud.ply, ascending."""
    folder = os.path.join(model_path, POINT_CLOUD_DIR)
    if not os.path.isdir(folder):
        return []
    return sorted(int(m.group(1)) for name in os.listdir(folder)
                  if (m := _ITERATION_PATTERN.fullmatch(name))
                  and os.path.isfile(os.path.join(folder, name, POINT_CLOUD_FILE)))


def latest_iteration(model_path: str) -> int | None:
    """Largest N of ``point_cloud/iteration_N`` (3DGS's ``searchForMaxIteration``)."""
    found = iterations(model_path)
    return found[-1] if found else None


def latest_point_cloud(model_dir: Path) -> Path:
    """``point_cloud/iteration_N/point_cloud.ply`` with the highest N (ModelError if none)."""
    iteration = latest_iteration(str(model_dir))
    if iteration is None:
        raise ModelError(f"{model_dir}: no point_cloud/iteration_*/point_cloud.ply "
                         "(not a train.py model folder)")
    return Path(point_cloud_path(str(model_dir), iteration))


def checkpoints(model_path: str) -> list[tuple[int, str]]:
    """(iteration, path) of the chkpnt files in the folder, oldest first."""
    if not os.path.isdir(model_path):
        return []
    found = [(int(m.group(1)), os.path.join(model_path, name))
             for name in os.listdir(model_path) if (m := CHECKPOINT_PATTERN.fullmatch(name))]
    return sorted(found)


