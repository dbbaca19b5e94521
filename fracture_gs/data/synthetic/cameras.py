"""Camera poses on a sphere around the object, in the Blender / NeRF-synthetic convention.

``transform_matrix`` is camera-to-world in OpenGL axes: the camera looks along its -z axis,
+y is up in the image, +x to the right. OpenCV (and :class:`fracture_gs.render.camera.Camera`)
looks along +z with +y down: ``c2w_opencv = c2w_opengl @ diag(1, -1, -1, 1)``.
"""
from __future__ import annotations

import numpy as np

NERF_CAMERA_ANGLE_X = 0.6911112070083618   # horizontal field of view of NeRF-synthetic
CAMERA_DISTANCE = 4.0311                   # camera distance from the origin (ditto)
LOWEST_VIEW_Z, HIGHEST_VIEW_Z = -0.5, 0.95  # elevations from -30 deg to +72 deg
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def fibonacci_directions(count: int, z_low: float = LOWEST_VIEW_Z,
                         z_high: float = HIGHEST_VIEW_Z) -> np.ndarray:
    """``count`` evenly spread unit vectors with z in [z_low, z_high] (Fibonacci spiral)."""
    index = np.arange(count) + 0.5
    z = z_high - (z_high - z_low) * index / count
    azimuth = np.pi * (3.0 - np.sqrt(5.0)) * index
    ring = np.sqrt(1.0 - z ** 2)
    return np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)


def random_directions(count: int, rng: np.random.Generator, z_low: float = LOWEST_VIEW_Z,
                      z_high: float = HIGHEST_VIEW_Z) -> np.ndarray:
    """``count`` random unit vectors, uniform on the sphere band z in [z_low, z_high]."""
    z = rng.uniform(z_low, z_high, count)
    azimuth = rng.uniform(0.0, 2 * np.pi, count)
    ring = np.sqrt(1.0 - z ** 2)
    return np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)


def look_at_opengl(eye: np.ndarray, target: np.ndarray = np.zeros(3),
                   up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """OpenGL camera-to-world (4x4) of a camera at ``eye`` looking at ``target``, world ``up``
    pointing up in the image."""
    backward = np.asarray(eye, dtype=np.float64) - target
    backward /= np.linalg.norm(backward)
    right = np.cross(up, backward)
    if np.linalg.norm(right) < 1e-8:
        raise ValueError("look_at_opengl: viewing direction is parallel to up")
    right /= np.linalg.norm(right)
    camera_up = np.cross(backward, right)
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = np.stack([right, camera_up, backward], axis=1)
    camera_to_world[:3, 3] = eye
    return camera_to_world


def opengl_to_opencv_world_to_camera(camera_to_world: np.ndarray) -> np.ndarray:
    """OpenGL camera-to-world -> OpenCV world-to-camera (the project's Camera convention)."""
    return np.linalg.inv(np.asarray(camera_to_world) @ OPENGL_TO_OPENCV)


def sphere_poses(n_train: int, n_test: int, seed: int,
                 distance: float = CAMERA_DISTANCE) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Train poses on a Fibonacci spiral (even coverage), test poses random (seeded), all
    looking at the origin from ``distance``."""
    if n_train < 1 or n_test < 0:
        raise ValueError(f"need n_train >= 1 and n_test >= 0, got {n_train}, {n_test}")
    rng = np.random.default_rng(seed)
    train = [look_at_opengl(distance * d) for d in fibonacci_directions(n_train)]
    test = [look_at_opengl(distance * d) for d in random_directions(n_test, rng)]
    return train, test
