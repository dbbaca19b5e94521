"""Camera rays of training pixels, stacked over all views for batched sampling."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fracture_gs.render.camera import Camera


@dataclass
class RigTensors:
    """Per-view camera data as tensors: ``rotation`` (V, 3, 3) camera-to-world rotation,
    ``center`` (V, 3), ``intrinsics`` (V, 4) = fx fy cx cy."""

    rotation: torch.Tensor
    center: torch.Tensor
    intrinsics: torch.Tensor

    @staticmethod
    def from_cameras(cameras: list[Camera], device: torch.device) -> "RigTensors":
        world_to_camera = torch.stack([c.world_to_camera.double() for c in cameras])
        camera_to_world = torch.linalg.inv(world_to_camera)
        intrinsics = torch.tensor([[c.fx, c.fy, c.cx, c.cy] for c in cameras],
                                  dtype=torch.float32)
        return RigTensors(camera_to_world[:, :3, :3].float().to(device),
                          camera_to_world[:, :3, 3].float().to(device), intrinsics.to(device))

    def rays(self, view: torch.Tensor, column: torch.Tensor,
             row: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Origins and unit directions (R, 3) through the centres of pixels (column, row) of
        views ``view`` (all (R,) integer tensors)."""
        fx, fy, cx, cy = self.intrinsics[view].unbind(-1)
        local = torch.stack([(column.float() + 0.5 - cx) / fx, (row.float() + 0.5 - cy) / fy,
                             torch.ones_like(fx)], dim=-1)
        direction = torch.einsum("rij,rj->ri", self.rotation[view], local)
        return self.center[view], direction / direction.norm(dim=-1, keepdim=True)


def box_intersection(origin: torch.Tensor, direction: torch.Tensor, lower: np.ndarray,
                     upper: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances (R,) of rays with an axis-aligned box (near >= 0);
    rays that miss get near >= far."""
    lo = torch.as_tensor(lower, dtype=origin.dtype, device=origin.device)
    hi = torch.as_tensor(upper, dtype=origin.dtype, device=origin.device)
    safe = torch.where(direction.abs() < 1e-9, torch.full_like(direction, 1e-9), direction)
    t0 = (lo - origin) / safe
    t1 = (hi - origin) / safe
    near = torch.minimum(t0, t1).amax(dim=1).clamp_min(0.0)
    far = torch.maximum(t0, t1).amin(dim=1)
    return near, far
