"""Visual hull from object masks as a signed distance field (docs/training.md, Stages: the first step of the SDF).

Each mask becomes a 2D signed distance map (pixels, positive outside the object, sub-pixel
accurate from the anti-aliased alpha). A 3D point's hull distance is the largest of its
per-view distances converted to world units (pixel distance x depth / focal length), over
the views whose image it projects into: the zero level set is exactly the visual hull (a
point is inside iff it projects inside the mask in every view that sees it) and the field
grows like a distance near it, which gives marching cubes and the photometric refinement a
smooth start. The grid is fitted in two passes: a coarse hull in the box every camera sees
gives the object's bounding box, the fine grid covers that box.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from fracture_gs.data.dataset import Dataset
from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.grid import VoxelGrid
from fracture_gs.render.camera import Camera

MASK_THRESHOLD = 0.5
SUPERSAMPLE = 2         # masks are thresholded at 2x resolution for sub-pixel distances
COARSE_RESOLUTION = 64
PADDING_VOXELS = 3      # empty nodes kept around the object on the fine grid
TRUNCATION_VOXELS = 8   # the hull SDF is truncated (clamped) this far outside
VIEW_BLOCK = 8          # views per pass over the still-undecided nodes


def mask_signed_distance(mask: np.ndarray, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """Signed distance (H, W) float32 in pixels to the boundary of ``mask`` > 0.5, positive
    outside, evaluated at pixel centres (computed at ``supersample`` x resolution)."""
    height, width = mask.shape
    fine = cv2.resize(mask.astype(np.float32), (width * supersample, height * supersample),
                      interpolation=cv2.INTER_LINEAR)
    inside = (fine > MASK_THRESHOLD).astype(np.uint8)
    outside_distance = cv2.distanceTransform(1 - inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    inside_distance = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    signed = np.where(inside > 0, 0.5 - inside_distance, outside_distance - 0.5)
    signed = cv2.resize(signed.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
    return (signed / supersample).astype(np.float32)


def distance_maps(masks: torch.Tensor, image_paths: list[str]) -> torch.Tensor:
    """(V, H, W) signed distance maps of all masks; an empty mask is an input error."""
    maps = []
    for mask, path in zip(masks.cpu().numpy(), image_paths):
        if not (mask > MASK_THRESHOLD).any():
            raise ReconstructionError(f"{path}: the object mask is empty (no alpha/mask value "
                                      f"> {MASK_THRESHOLD}); every view must show the object")
        maps.append(mask_signed_distance(mask))
    return torch.from_numpy(np.stack(maps))


@dataclass
class Projector:
    """All views' projections at once: 3x4 matrices K [R | t] stacked (V, 3, 4), the
    distance maps (V, 1, H, W) and per-view focal lengths and near planes."""

    matrices: torch.Tensor
    maps: torch.Tensor
    focal: torch.Tensor
    near: torch.Tensor

    @staticmethod
    def build(cameras: list[Camera], maps: torch.Tensor) -> "Projector":
        matrices = []
        for camera in cameras:
            intrinsics = torch.tensor([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy],
                                       [0.0, 0.0, 1.0]], dtype=torch.float64)
            matrices.append(intrinsics @ camera.world_to_camera.double().cpu()[:3, :4])
        focal = torch.tensor([0.5 * (c.fx + c.fy) for c in cameras], dtype=torch.float32)
        near = torch.tensor([c.near for c in cameras], dtype=torch.float32)
        device = maps.device
        return Projector(torch.stack(matrices).float().to(device), maps[:, None].float(),
                         focal.to(device), near.to(device))

    def views(self, start: int, stop: int) -> "Projector":
        return Projector(self.matrices[start:stop], self.maps[start:stop],
                         self.focal[start:stop], self.near[start:stop])


def hull_distance(points: torch.Tensor, projector: Projector) -> tuple[torch.Tensor, torch.Tensor]:
    """Visual-hull signed distance (P,) at world ``points`` (P, 3) over the projector's views
    (-inf where no view sees a point) and the number of views that see each point."""
    views, _, height, width = projector.maps.shape
    homogeneous = torch.cat([points, torch.ones_like(points[:, :1])], dim=1)
    projected = torch.einsum("vij,pj->vpi", projector.matrices, homogeneous)   # (V, P, 3)
    depth = projected[..., 2]
    safe_depth = depth.clamp_min(1e-6)
    u = projected[..., 0] / safe_depth
    v = projected[..., 1] / safe_depth
    visible = (depth > projector.near[:, None]) & (u >= 0) & (u <= width) & (v >= 0) \
        & (v <= height)
    normalised = torch.stack([2 * u / width - 1, 2 * v / height - 1], dim=-1)
    pixels = F.grid_sample(projector.maps, normalised[:, None], mode="bilinear",
                           padding_mode="border", align_corners=False)[:, 0, 0]  # (V, P)
    world = pixels * safe_depth / projector.focal[:, None]
    world = torch.where(visible, world, torch.full_like(world, -math.inf))
    return world.amax(dim=0), visible.sum(dim=0)


def viewing_box(cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """A cube every camera sees: centred on the point nearest to all optical axes, half-size
    the smallest (distance to it) x sin(half field of view)."""
    centers, axes = [], []
    for camera in cameras:
        camera_to_world = camera.camera_to_world.double().cpu().numpy()
        centers.append(camera_to_world[:3, 3])
        axes.append(camera_to_world[:3, 2])
    centers_array, axes_array = np.array(centers), np.array(axes)
    projector = np.eye(3)[None] - axes_array[:, :, None] * axes_array[:, None, :]
    lhs = projector.sum(axis=0)
    rhs = np.einsum("vij,vj->i", projector, centers_array)
    if np.linalg.cond(lhs) > 1e8:  # all axes parallel: use the centroid of the rig
        center = centers_array.mean(axis=0)
    else:
        center = np.linalg.solve(lhs, rhs)
    half = math.inf
    for camera, position in zip(cameras, centers_array):
        half_fov = math.atan(min(camera.width / (2 * camera.fx), camera.height / (2 * camera.fy)))
        half = min(half, float(np.linalg.norm(position - center)) * math.sin(half_fov))
    return center - half, center + half


def _grid_distance(grid: VoxelGrid, projector: Projector, device: torch.device,
                   truncation: float) -> torch.Tensor:
    """Hull distance at the grid nodes, truncated above at ``truncation``: views are taken in
    blocks and a node leaves the computation once it is farther outside than that. A node
    that fewer than half of the views see counts as outside (with few views, a point that
    only one or two cameras see would otherwise be "inside" far from the object)."""
    positions = grid.node_positions(device).reshape(-1, 3)
    result = torch.full((positions.shape[0],), -math.inf, device=device)
    seen = torch.zeros(positions.shape[0], dtype=torch.long, device=device)
    active = torch.arange(positions.shape[0], device=device)
    views = projector.maps.shape[0]
    for first in range(0, views, VIEW_BLOCK):
        block = projector.views(first, first + VIEW_BLOCK)
        chunk = max(1024, (1 << 23) // block.maps.shape[0])
        for start in range(0, active.numel(), chunk):
            index = active[start:start + chunk]
            distance, count = hull_distance(positions[index], block)
            seen[index] += count
            result[index] = torch.maximum(result[index], distance)
        active = active[result[active] <= truncation]
    enough = seen >= max(1, (views + 1) // 2)
    result = torch.where(enough, result.clamp(max=truncation), torch.full_like(result, truncation))
    return result.reshape(grid.shape)


@dataclass
class VisualHull:
    """The hull SDF on the fitted grid (``sdf`` (nx, ny, nz)), truncated at
    ``TRUNCATION_VOXELS`` voxels outside (also where no view sees)."""

    grid: VoxelGrid
    sdf: torch.Tensor


def object_box(dataset: Dataset, projector: Projector,
               device: torch.device) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of the visual hull, found on a coarse grid over the viewing box."""
    lower, upper = viewing_box(dataset.cameras)
    coarse = VoxelGrid.around(lower, upper, COARSE_RESOLUTION)
    distance = _grid_distance(coarse, projector, device, TRUNCATION_VOXELS * coarse.voxel)
    inside = (distance < 0).cpu().numpy()
    if not inside.any():
        source = os.path.dirname(dataset.image_paths[0]) or "."
        raise ReconstructionError(f"{source}: the visual hull is empty (no point projects inside "
                                  f"the mask of every view); check that the cameras match the "
                                  f"images and masks")
    index = np.argwhere(inside)
    lo_index = np.maximum(index.min(axis=0) - 1, 0)
    hi_index = np.minimum(index.max(axis=0) + 1, np.asarray(coarse.shape) - 1)
    return coarse.lower + lo_index * coarse.voxel, coarse.lower + hi_index * coarse.voxel


def visual_hull(dataset: Dataset, resolution: int, device: torch.device) -> VisualHull:
    """Visual-hull SDF of a masked dataset on a grid with ``resolution`` cells along the
    longest side of the object's bounding box (plus a margin of empty nodes)."""
    if dataset.masks is None:
        raise ValueError("visual_hull needs a dataset with masks")
    projector = Projector.build(dataset.cameras,
                                distance_maps(dataset.masks, dataset.image_paths).to(device))
    lower, upper = object_box(dataset, projector, device)
    margin = PADDING_VOXELS * float((upper - lower).max()) / max(resolution - 2 * PADDING_VOXELS,
                                                                1)
    grid = VoxelGrid.around(lower - margin, upper + margin, resolution)
    return VisualHull(grid, _grid_distance(grid, projector, device,
                                           TRUNCATION_VOXELS * grid.voxel))
