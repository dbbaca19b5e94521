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


# Intrinsics a transforms file may give at its top level or per frame: the field of view
# (NeRF-synthetic) or focal lengths and principal point in pixels (nerfstudio), and the image
# size they refer to.
INTRINSIC_KEYS = ("camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h")
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
FOCAL_KEYS = ("camera_angle_x", "fl_x")


def _intrinsic_values(entry: dict, where: str, transforms_path: str) -> dict[str, float]:
    """The intrinsics and distortion fields of one JSON object, checked to be numbers."""
    values = {}
    for key in INTRINSIC_KEYS + DISTORTION_KEYS:
        if key not in entry:
            continue
        value = entry[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value):
            raise DatasetError(f"{transforms_path}: {where}'{key}' is not a finite number")
        values[key] = float(value)
    return values


def _frames_of(transforms_path: str, source_path: str) -> list[tuple[str, np.ndarray, dict]]:
    """(image file, OpenCV world-to-camera, intrinsics fields) of every frame of one json file;
    a frame's own fields override the file's."""
    content = _read_json(transforms_path)
    if "frames" not in content or not isinstance(content["frames"], list):
        raise DatasetError(f"{transforms_path}: missing key 'frames' (a list)")
    shared = _intrinsic_values(content, "", transforms_path)
    if not any(key in shared for key in FOCAL_KEYS):
        unset = [n for n, frame in enumerate(content["frames"])
                 if not (isinstance(frame, dict) and any(key in frame for key in FOCAL_KEYS))]
        if unset:
            raise DatasetError(f"{transforms_path}: missing key 'camera_angle_x' (or 'fl_x'; "
                               f"frame {unset[0]} has neither)")
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
        intrinsics = {**shared, **_intrinsic_values(frame, f"frame {number} ", transforms_path)}
        views.append((image_path,
                      opengl_camera_to_world_to_opencv_world_to_camera(camera_to_world),
                      intrinsics))
    return views


def pinhole_from_fields(fields: dict[str, float], width: int, height: int,
                        where: str) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels of an image ``width`` x ``height`` from a frame's fields.

    The focal length comes from ``fl_x`` (``fl_y`` defaults to it) or from ``camera_angle_x``
    (0.5 W / tan(angle / 2) on both axes); the principal point from ``cx``, ``cy``, else the
    image centre. nerfstudio's ``cx``, ``cy`` put the centre of the top-left pixel at (0.5, 0.5),
    as :class:`Camera` does, so they are used unchanged. ``w`` and ``h``, when given, must be the
    image's size; non-zero distortion is refused.
    """
    for key, size in (("w", width), ("h", height)):
        if key in fields and int(round(fields[key])) != size:
            raise DatasetError(f"{where}: '{key}' is {fields[key]:g} but the image is "
                               f"{width}x{height} (intrinsics must be given for the image files)")
    distorted = {k: v for k, v in fields.items() if k in DISTORTION_KEYS and abs(v) > 1e-9}
    if distorted:
        raise DatasetError(f"{where}: non-zero lens distortion {distorted}; undistort the "
                           f"images first (e.g. COLMAP's image_undistorter)")
    if "fl_x" in fields:
        fx = fields["fl_x"]
        fy = fields.get("fl_y", fx)
        if not (fx > 0 and fy > 0):
            raise DatasetError(f"{where}: focal lengths fl_x={fx:g}, fl_y={fy:g} must be > 0")
    elif "camera_angle_x" in fields:
        fov_x = fields["camera_angle_x"]
        if not 0.0 < fov_x < math.pi:
            raise DatasetError(f"{where}: camera_angle_x={fov_x} is not in (0, pi)")
        fx = fy = 0.5 * width / math.tan(0.5 * fov_x)
    else:
        raise DatasetError(f"{where}: missing key 'camera_angle_x' (or 'fl_x')")
    return fx, fy, fields.get("cx", width / 2.0), fields.get("cy", height / 2.0)


def load_blender(source_path: str, split: str = "train", downscale: int = 1,
                 white_background: bool = False) -> Dataset:
    """Load a NeRF-synthetic style scene.

    Frames come from ``transforms_<split>.json`` ("all" = train then test); their
    ``transform_matrix`` is camera-to-world in OpenGL axes and becomes an OpenCV
    world-to-camera matrix. Intrinsics: :func:`pinhole_from_fields` (NeRF-synthetic's
    ``camera_angle_x``, or nerfstudio's ``fl_x``, ``fl_y``, ``cx``, ``cy``, in the file or per
    frame). The alpha channel is the mask.
    """
    if split not in SPLIT_FILES:
        raise ValueError(f"split must be one of {sorted(SPLIT_FILES)}, got {split!r}")
    views = []
    for name in SPLIT_FILES[split]:
        path = os.path.join(source_path, name)
        views += [(image, pose, fields, path) for image, pose, fields in _frames_of(path, source_path)]
    if not views:
        raise DatasetError(f"{os.path.join(source_path, SPLIT_FILES[split][0])}: no frames")
    width, height = _image_size(views[0][0])
    cameras = []
    for image_path, world_to_camera, fields, transforms_path in views:
        fx, fy, cx, cy = pinhole_from_fields(fields, width, height,
                                             f"{transforms_path} ({os.path.basename(image_path)})")
        cameras.append(make_camera(world_to_camera, fx, fy, cx, cy, width, height, image_path))
    return assemble_dataset(cameras, [v[0] for v in views], None, downscale=downscale,
                            white_background=white_background, format="blender")
