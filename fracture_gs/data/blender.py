"""Blender / NeRF-synthetic loader: ``transforms_{train,test}.json`` + RGBA PNGs (docs/file_formats.md §1)."""
from __future__ import annotations

import math
import os

import numpy as np

from fracture_gs.data.cameras import (make_camera,
                                      opengl_camera_to_world_to_opencv_world_to_camera,
                                      require_finite)
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.files import read_json
from fracture_gs.data.images import find_image_file, read_image
from fracture_gs.data.views import assemble_dataset

SPLIT_FILES = {"train": ("transforms_train.json",), "test": ("transforms_test.json",),
               "all": ("transforms_train.json", "transforms_test.json")}


def _read_json(path: str) -> dict:
    content = read_json(path)
    if not isinstance(content, dict):
        raise DatasetError(f"{path}: expected a JSON object at the top level")
    return content


def _image_size(path: str) -> tuple[int, int]:
    """Width and height of an image file."""
    rgb, _ = read_image(path)
    return rgb.shape[1], rgb.shape[0]


def _frames_of(transforms_path: str, source_path: str) -> list[tuple[str, np.ndarray, float]]:
    """(image file, OpenCV world-to-camera, horizontal FOV) of every frame of one json file."""
    content = _read_json(transforms_path)
    if "frames" not in content or not isinstance(content["frames"], list):
        raise DatasetError(f"{transforms_path}: missing key 'frames' (a list)")
    if "camera_angle_x" not in content:
        raise DatasetError(f"{transforms_path}: missing key 'camera_angle_x'")
    try:
        fov_x = float(content["camera_angle_x"])
    except (TypeError, ValueError):
        raise DatasetError(f"{transforms_path}: 'camera_angle_x' is not a number") from None
    if not (0.0 < fov_x < math.pi):
        raise DatasetError(f"{transforms_path}: camera_angle_x={fov_x} is not in (0, pi)")
    views = []
    for number, frame in enumerate(content["frames"]):
        for key in ("file_path", "transform_matrix"):
            if not isinstance(frame, dict) or key not in frame:
                raise DatasetError(f"{transforms_path}: frame {number} is missing key '{key}'")
        try:
            camera_to_world = np.array(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise DatasetError(f"{transforms_path}: frame {number} transform_matrix is not "
                               f"numeric") from None
        if camera_to_world.shape != (4, 4):
            raise DatasetError(f"{transforms_path}: frame {number} transform_matrix has shape "
                               f"{camera_to_world.shape}, expected (4, 4)")
        require_finite(camera_to_world, f"frame {number} transform_matrix", transforms_path)
        if abs(np.linalg.det(camera_to_world[:3, :3])) < 1e-8:
            raise DatasetError(f"{transforms_path}: frame {number} transform_matrix is singular")
        stem = os.path.normpath(os.path.join(source_path, str(frame["file_path"])))
        image_path = find_image_file(stem)
        if image_path is None:
            raise DatasetError(f"{stem}: image of frame {number} in {transforms_path} not found "
                               f"(tried with and without .png/.jpg)")
        views.append((image_path,
                      opengl_camera_to_world_to_opencv_world_to_camera(camera_to_world), fov_x))
    return views


def load_blender(source_path: str, split: str = "train", downscale: int = 1,
                 white_background: bool = False) -> Dataset:
    """Load a NeRF-synthetic style scene.

    Frames come from ``transforms_<split>.json`` ("all" = train then test); their
    ``transform_matrix`` is camera-to-world in OpenGL axes and becomes an OpenCV
    world-to-camera matrix. Focal length 0.5 W / tan(camera_angle_x / 2) on both axes,
    principal point at the image centre. The alpha channel is the mask.
    """
    if split not in SPLIT_FILES:
        raise ValueError(f"split must be one of {sorted(SPLIT_FILES)}, got {split!r}")
    views = []
    for name in SPLIT_FILES[split]:
        views += _frames_of(os.path.join(source_path, name), source_path)
    if not views:
        raise DatasetError(f"{os.path.join(source_path, SPLIT_FILES[split][0])}: no frames")
    width, height = _image_size(views[0][0])
    cameras = []
    for image_path, world_to_camera, fov_x in views:
        focal = 0.5 * width / math.tan(0.5 * fov_x)
        cameras.append(make_camera(world_to_camera, focal, focal, width / 2.0, height / 2.0,
                                   width, height, image_path))
    return assemble_dataset(cameras, [v[0] for v in views], None, downscale=downscale,
                            white_background=white_background, format="blender")
