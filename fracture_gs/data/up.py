"""The world's up direction of a dataset, estimated from its cameras.

Photographers (and camera robots) hold their cameras level: a camera's x axis (image right) is
horizontal, whatever way it looks. The x axes of cameras around an object then span the
horizontal plane, and up is the direction perpendicular to all of them: the right singular
vector of the stacked x axes with the smallest singular value (nerfstudio's "vertical"
orientation). Its sign is the one that agrees with the cameras' mean up vector (image up, −y in
OpenCV axes), since cameras are not held upside down. Where the x axes do not span a plane (all
cameras face one way), the mean up vector without its part along the shared x axis stands in.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fracture_gs.render.camera import Camera

# The x axes span the horizontal plane when the second singular value is at least this share of
# the first (a spread of the viewing directions of about 10 degrees or more).
SPREAD_RATIO = 0.15


def camera_axes(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) x axes (image right) and (N, 3) up vectors (image up) of the cameras in world
    coordinates."""
    rotations = np.stack([camera.world_to_camera[:3, :3].double().cpu().numpy()
                          for camera in cameras])
    return rotations[:, 0, :], -rotations[:, 1, :]


def camera_up(cameras: Sequence[Camera]) -> tuple[np.ndarray, str]:
    """Unit up vector of the world the cameras stand in, and how it was found (module
    docstring): ``"level cameras"`` or ``"mean camera up"``."""
    if len(cameras) == 0:
        raise ValueError("camera_up: no cameras")
    right, up = camera_axes(cameras)
    mean_up = up.mean(axis=0)
    _, singular, basis = np.linalg.svd(right, full_matrices=True)
    if len(cameras) >= 2 and singular[1] >= SPREAD_RATIO * singular[0]:
        estimate = basis[2]
        method = "level cameras"
    else:
        shared_right = basis[0]
        estimate = mean_up - (mean_up @ shared_right) * shared_right
        method = "mean camera up"
    if np.linalg.norm(estimate) < 1e-9:
        raise ValueError("camera_up: the cameras do not define an up direction")
    estimate = estimate / np.linalg.norm(estimate)
    if estimate @ mean_up < 0:
        estimate = -estimate
    return estimate, method


def level_residual_deg(cameras: Sequence[Camera], up: np.ndarray) -> float:
    """Root-mean-square tilt of the cameras' x axes out of the plane perpendicular to ``up``
    (degrees): how far the cameras are from level about that up."""
    right, _ = camera_axes(cameras)
    sines = np.clip(right @ (np.asarray(up, dtype=np.float64) / np.linalg.norm(up)), -1.0, 1.0)
    return float(np.degrees(np.sqrt(np.mean(np.arcsin(sines) ** 2))))
