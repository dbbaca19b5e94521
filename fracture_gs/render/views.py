"""Named cameras to render a scene from: ``orbit:N``, ``train``, ``test`` or a ``cameras.json``.

* ``orbit:N`` — N cameras evenly spaced on a circle around the scene's bounds (axis = the up
  direction, 20° above the centre), all looking at the centre; the same for every frame.
* ``train`` / ``test`` — the cameras of that split of the dataset a trained object was
  reconstructed from, moved with the object's scene transform so that they see the object as in
  the photos (read by :mod:`fracture_gs.pipeline.views`, which knows the datasets; this module
  holds the camera math).
* a path to a ``cameras.json`` in the 3DGS layout (``position`` = camera centre, ``rotation`` =
  camera-to-world rotation with OpenCV axes, ``fx``, ``fy``, ``width``, ``height``), in scene
  coordinates.

Bad specs raise :class:`ViewSpecError` with one line naming the spec or file.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fracture_gs.render.camera import Camera

ORBIT_ELEVATION_DEG = 20.0
ORBIT_FOV_DEG = 40.0
ORBIT_MARGIN = 1.15     # bounding sphere radius → distance margin
# Largest image side rendered: an 8K frame; a larger one does not fit an H.264 video and takes
# gigabytes per image buffer.
MAX_IMAGE_SIDE = 8192


class ViewSpecError(ValueError):
    """An unusable ``--views`` value (one line naming it)."""


@dataclass(frozen=True)
class View:
    """A camera with a file-system friendly name (the sub-folder its images go to)."""

    name: str
    camera: Camera


def check_image_size(width: int, height: int, what: str) -> None:
    """Raise :class:`ViewSpecError` naming ``what`` unless ``width`` x ``height`` is a size that
    can be rendered: both sides in 1..MAX_IMAGE_SIDE."""
    if not (1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE):
        raise ViewSpecError(f"{what}: image size {width}x{height} is outside 1..{MAX_IMAGE_SIDE} "
                            "pixels per side")


def safe_view_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "view"


def orbit_views(count: int, centre: Sequence[float], radius: float, width: int, height: int,
                up: Sequence[float] = (0.0, 0.0, 1.0), elevation_deg: float = ORBIT_ELEVATION_DEG,
                fov_deg: float = ORBIT_FOV_DEG) -> list[View]:
    """``count`` cameras on a circle around ``centre`` that all frame a sphere of ``radius``.

    The circle lies ``elevation_deg`` above the centre (seen along ``up``); the first camera is
    on the side of the least-aligned axis orthogonal to ``up``, the others follow
    counter-clockwise about ``up``. Names: ``orbit_00`` ….
    """
    if count < 1:
        raise ViewSpecError(f"orbit:{count}: the number of cameras must be >= 1")
    check_image_size(width, height, f"orbit:{count}")
    up_v = np.asarray(up, dtype=np.float64)
    up_v = up_v / np.linalg.norm(up_v)
    seed = np.eye(3)[int(np.argmin(np.abs(up_v)))]
    side = seed - up_v * float(seed @ up_v)
    side /= np.linalg.norm(side)
    other = np.cross(up_v, side)
    fov_x = math.radians(fov_deg) if width <= height else \
        2.0 * math.atan(math.tan(math.radians(fov_deg) / 2.0) * width / height)
    fov_small = math.radians(fov_deg)
    distance = ORBIT_MARGIN * max(radius, 1e-6) / math.sin(fov_small / 2.0)
    elevation = math.radians(elevation_deg)
    centre_v = np.asarray(centre, dtype=np.float64)
    views = []
    for index in range(count):
        angle = 2.0 * math.pi * index / count
        horizontal = math.cos(angle) * side + math.sin(angle) * other
        eye = centre_v + distance * (math.cos(elevation) * horizontal + math.sin(elevation) * up_v)
        camera = Camera.look_at(eye.tolist(), centre_v.tolist(), up_v.tolist(), fov_x, width, height)
        views.append(View(f"orbit_{index:02d}", camera))
    return views


def bounds_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre of the axis-aligned bounds of ``points`` (N,3) and the radius that encloses them."""
    lower, upper = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lower + upper)
    return centre, float(np.linalg.norm(points - centre, axis=1).max())


def cameras_from_json(path: str | Path, size: tuple[int, int] | None = None) -> list[View]:
    """Views of a 3DGS ``cameras.json``; ``size`` (W, H) rescales the intrinsics."""
    path = Path(path)
    try:
        entries = json.loads(path.read_text())
    except FileNotFoundError:
        raise ViewSpecError(f"{path}: file not found") from None
    except (OSError, ValueError, RecursionError) as exc:
        raise ViewSpecError(f"{path}: not a readable JSON file ({type(exc).__name__})") from None
    if not isinstance(entries, list) or not entries:
        raise ViewSpecError(f"{path}: expected a non-empty list of cameras (3DGS cameras.json)")
    if size is not None:
        check_image_size(*size, f"{path}")
    views = []
    for index, entry in enumerate(entries):
        try:
            rotation = np.asarray(entry["rotation"], dtype=np.float64)
            position = np.asarray(entry["position"], dtype=np.float64)
            width, height = int(entry["width"]), int(entry["height"])
            fx, fy = float(entry["fx"]), float(entry["fy"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ViewSpecError(f"{path}: camera {index} lacks a valid {exc} "
                                "(needs position, rotation, width, height, fx, fy)") from None
        if rotation.shape != (3, 3) or position.shape != (3,) or \
                not (np.isfinite(rotation).all() and np.isfinite(position).all()):
            raise ViewSpecError(f"{path}: camera {index} has a malformed rotation or position")
        if not (math.isfinite(fx) and math.isfinite(fy) and fx > 0 and fy > 0):
            raise ViewSpecError(f"{path}: camera {index} has fx = {fx:g}, fy = {fy:g}; focal "
                                "lengths must be finite and > 0")
        if size is None:
            check_image_size(width, height, f"{path}: camera {index}")
        camera_to_world = np.eye(4)
        camera_to_world[:3, :3] = rotation
        camera_to_world[:3, 3] = position
        try:
            camera = Camera(torch.as_tensor(np.linalg.inv(camera_to_world), dtype=torch.float32),
                            fx, fy, width / 2.0, height / 2.0, width, height)
        except ValueError as exc:
            raise ViewSpecError(f"{path}: camera {index}: {exc}") from None
        if size is not None:
            camera = resize_camera(camera, *size)
        name = safe_view_name(str(entry.get("img_name", f"cam_{index:03d}")))
        views.append(View(name, camera))
    return unique_view_names(views)


def unique_view_names(views: list[View]) -> list[View]:
    seen: dict[str, int] = {}
    out = []
    for view in views:
        count = seen.get(view.name, 0)
        seen[view.name] = count + 1
        out.append(view if count == 0 else View(f"{view.name}_{count}", view.camera))
    return out


def resize_camera(camera: Camera, width: int, height: int) -> Camera:
    """The same camera for an image of ``width`` x ``height`` (intrinsics scaled)."""
    sx, sy = width / camera.width, height / camera.height
    return Camera(camera.world_to_camera.clone(), camera.fx * sx, camera.fy * sy, camera.cx * sx,
                  camera.cy * sy, width, height, camera.near)


def transform_camera(camera: Camera, rotation: np.ndarray, scale: float,
                     translate: Sequence[float]) -> Camera:
    """The camera that sees ``translate + scale·R·x`` as ``camera`` sees ``x`` (an object's scene
    transform applied to a camera of its model frame)."""
    w2c = camera.world_to_camera.double().numpy()
    rot_cam = w2c[:3, :3] @ rotation.T
    moved = np.eye(4)
    moved[:3, :3] = rot_cam
    moved[:3, 3] = scale * w2c[:3, 3] - rot_cam @ np.asarray(translate, dtype=np.float64)
    return Camera(torch.as_tensor(moved, dtype=torch.float32), camera.fx, camera.fy, camera.cx,
                  camera.cy, camera.width, camera.height, camera.near * scale)
