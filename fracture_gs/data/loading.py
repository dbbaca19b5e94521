"""Format detection and the one entry point every stage uses to read a scene."""
from __future__ import annotations

import os

from fracture_gs.data.blender import load_blender
from fracture_gs.data.colmap import find_sparse_folder, load_colmap
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.dtu import CAMERAS_FILE, load_dtu


def detect_format(source_path: str) -> str:
    """``"blender"`` (transforms_train.json), ``"colmap"`` (sparse/0/) or ``"dtu"``
    (cameras_sphere.npz), checked in that order."""
    if os.path.exists(source_path) and not os.path.isdir(source_path):
        raise DatasetError(f"{source_path}: is a file, expected a dataset folder")
    if not os.path.isdir(source_path):
        raise DatasetError(f"{source_path}: dataset folder not found")
    if os.path.isfile(os.path.join(source_path, "transforms_train.json")):
        return "blender"
    if find_sparse_folder(source_path) is not None:
        return "colmap"
    if os.path.isfile(os.path.join(source_path, CAMERAS_FILE)):
        return "dtu"
    raise DatasetError(f"{source_path}: unknown dataset format (expected transforms_train.json, "
                       f"sparse/0/cameras.bin|txt or {CAMERAS_FILE})")


def load_dataset(source_path: str, split: str = "train", downscale: int = 1,
                 white_background: bool = False, holdout_every: int = 0) -> Dataset:
    """Load the views of ``split`` from a Blender, COLMAP or DTU/NeuS folder.

    Args:
        source_path: the dataset folder; its format is detected by :func:`detect_format`.
        split: "train", "test" or "all". Blender uses its transforms files; COLMAP and DTU
            put every view in "train" unless ``holdout_every`` = k > 0 moves views
            0, k, 2k, ... to "test".
        downscale: 3DGS's ``-r``: integer factor, or -1 to cap the width at 1600 pixels.
        white_background: composite RGBA images (and images with masks) on white instead
            of black.
        holdout_every: COLMAP and DTU only (a DatasetError for a Blender folder).

    Raises:
        DatasetError: one line naming the offending file and the problem.
    """
    data_format = detect_format(source_path)
    if data_format == "blender":
        if holdout_every:
            raise DatasetError(f"{source_path}: a Blender/NeRF folder has its own test split "
                               f"(transforms_test.json); holding out every {holdout_every}th "
                               f"view applies to COLMAP and DTU folders only")
        return load_blender(source_path, split, downscale, white_background)
    if data_format == "colmap":
        return load_colmap(source_path, split, downscale, white_background, holdout_every)
    return load_dtu(source_path, split, downscale, white_background, holdout_every)


def has_test_split(source_path: str, holdout_every: int = 0) -> bool:
    """Whether ``load_dataset(source_path, "test", holdout_every=holdout_every)`` has views:
    a Blender folder's ``transforms_test.json``, or a hold-out (``holdout_every`` > 0) of a
    COLMAP or DTU folder."""
    if detect_format(source_path) == "blender":
        return os.path.isfile(os.path.join(source_path, "transforms_test.json"))
    return holdout_every > 0
