"""Pinhole camera in the OpenCV / gsplat convention (docs/formulas.md §11)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch


@dataclass
class Camera:
    """A pinhole camera.

    ``world_to_camera`` is a 4x4 matrix mapping world points to camera space, where z > 0 is
    forward and y points down; a camera-space point (x, y, z) lands on pixel coordinates
    (fx x/z + cx, fy y/z + cy), and pixel (i, j) has its centre at (i + 0.5, j + 0.5).
    """

    world_to_camera: torch.Tensor
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float = 0.01

    def __post_init__(self) -> None:
        self.world_to_camera = torch.as_tensor(self.world_to_camera, dtype=torch.float32)
        if self.world_to_camera.shape != (4, 4):
            raise ValueError(f"world_to_camera must be 4x4, got {tuple(self.world_to_camera.shape)}")
        if not torch.isfinite(self.world_to_camera).all():
            raise ValueError("world_to_camera contains NaN or Inf")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        for name in ("fx", "fy", "cx", "cy", "near"):
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"{name} must be a finite number, got {getattr(self, name)}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @property
    def camera_to_world(self) -> torch.Tensor:
        return torch.linalg.inv(self.world_to_camera)

    @property
    def center(self) -> torch.Tensor:
        """Camera position in world coordinates."""
        return self.camera_to_world[:3, 3]

    def to(self, device: torch.device | str) -> "Camera":
        return Camera(self.world_to_camera.to(device), self.fx, self.fy, self.cx, self.cy,
                      self.width, self.height, self.near)

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Project world points (N,3) to pixel coordinates (N,2) and camera depth (N,)."""
        w2c = self.world_to_camera.to(points.device, points.dtype)
        cam = points @ w2c[:3, :3].T + w2c[:3, 3]
        z = cam[:, 2]
        uv = torch.stack([self.fx * cam[:, 0] / z + self.cx, self.fy * cam[:, 1] / z + self.cy], -1)
        return uv, z

    @staticmethod
    def from_fov(world_to_camera: torch.Tensor, fov_x_rad: float, width: int, height: int,
                 near: float = 0.01) -> "Camera":
        """Camera with a horizontal field of view and the principal point at the image centre."""
        import math
        fx = 0.5 * width / math.tan(0.5 * fov_x_rad)
        return Camera(world_to_camera, fx, fx, width / 2.0, height / 2.0, width, height, near)

    @staticmethod
    def look_at(eye, target, up, fov_x_rad: float, width: int, height: int,
                near: float = 0.01) -> "Camera":
        """Camera at ``eye`` looking at ``target`` with ``up`` pointing up in the image."""
        eye_t = torch.as_tensor(eye, dtype=torch.float32)
        forward = torch.as_tensor(target, dtype=torch.float32) - eye_t
        forward = forward / forward.norm()
        right = torch.linalg.cross(forward, torch.as_tensor(up, dtype=torch.float32))
        if right.norm() < 1e-8:
            raise ValueError("look_at: up is parallel to the viewing direction")
        right = right / right.norm()
        down = torch.linalg.cross(forward, right)
        rot = torch.stack([right, down, forward], 0)  # rows: camera axes in world
        w2c = torch.eye(4)
        w2c[:3, :3] = rot
        w2c[:3, 3] = -rot @ eye_t
        return Camera.from_fov(w2c, fov_x_rad, width, height, near)


def cameras_json_entry(index: int, name: str, camera: Camera) -> dict[str, Any]:
    """One entry of 3DGS's ``cameras.json`` (camera-to-world position and rotation)."""
    camera_to_world = torch.linalg.inv(camera.world_to_camera.double()).numpy()
    return {"id": index, "img_name": name, "width": camera.width, "height": camera.height,
            "position": camera_to_world[:3, 3].tolist(),
            "rotation": [row.tolist() for row in camera_to_world[:3, :3]],
            "fy": camera.fy, "fx": camera.fx}
