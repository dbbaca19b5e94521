"""Camera conversions shared by the dataset loaders (all end in the OpenCV convention)."""
from __future__ import annotations

import cv2
import numpy as np
import torch

from fracture_gs.data.dataset import DatasetError
from fracture_gs.render.camera import Camera


def require_finite(matrix: np.ndarray, what: str, path: str) -> np.ndarray:
    """Return ``matrix`` as float64, or raise naming ``path`` if it has NaN / Inf entries."""
    values = np.asarray(matrix, dtype=np.float64)
    if not np.isfinite(values).all():
        raise DatasetError(f"{path}: {what} contains NaN or Inf")
    return values


def opengl_camera_to_world_to_opencv_world_to_camera(camera_to_world: np.ndarray) -> np.ndarray:
    """Convert a NeRF/Blender camera-to-world matrix (OpenGL camera axes: x right, y up,
    z backward) to an OpenCV world-to-camera matrix (x right, y down, z forward)."""
    c2w = np.array(camera_to_world, dtype=np.float64)
    c2w[:3, 1:3] *= -1.0  # flip the camera's y and z axes
    return np.linalg.inv(c2w)


def quaternion_to_rotation(qvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z); the quaternion is normalised first."""
    w, x, y, z = np.asarray(qvec, dtype=np.float64) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def decompose_projection(projection: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a 3x4 projection matrix P = K [R | t] into K (3x3, K[2,2] = 1) and the 4x4
    world-to-camera matrix, with OpenCV's RQ decomposition (as NeuS / IDR do)."""
    intrinsics, rotation, center_h = cv2.decomposeProjectionMatrix(projection[:3, :4])[:3]
    intrinsics = intrinsics / intrinsics[2, 2]
    center = (center_h[:3] / center_h[3])[:, 0]
    world_to_camera = np.eye(4)
    world_to_camera[:3, :3] = rotation
    world_to_camera[:3, 3] = -rotation @ center
    return intrinsics, world_to_camera


def make_camera(world_to_camera: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                width: int, height: int, path: str) -> Camera:
    """Build a :class:`Camera`, turning its validation errors into one-line DatasetErrors."""
    require_finite(world_to_camera, "camera pose", path)
    if not np.isfinite([fx, fy, cx, cy]).all():
        raise DatasetError(f"{path}: camera intrinsics contain NaN or Inf")
    try:
        return Camera(torch.as_tensor(world_to_camera, dtype=torch.float32), float(fx), float(fy),
                      float(cx), float(cy), int(width), int(height))
    except ValueError as error:
        raise DatasetError(f"{path}: invalid camera: {error}") from None


def resized_camera(camera: Camera, width: int, height: int) -> Camera:
    """The same camera for the image resized to ``width`` x ``height``.

    With pixel centres at (i + 0.5) a continuous image coordinate scales exactly by the
    resize ratio, so fx and cx scale by width ratio, fy and cy by the height ratio.
    """
    sx = width / camera.width
    sy = height / camera.height
    return Camera(camera.world_to_camera.clone(), camera.fx * sx, camera.fy * sy,
                  camera.cx * sx, camera.cy * sy, width, height, camera.near)
