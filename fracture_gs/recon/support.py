"""The unseen underside of an object photographed standing on a support (a table, the floor).

Cameras that all look from above never see the bottom of the object, and the visual hull there
is only bounded by the silhouette cones of the cameras: a keel hangs below the object, deeper the
wider the object, and the trained object would rest on its tip instead of on its base. The
lowest part of the object the cameras do see tells where the support was: this module finds the
mesh vertices some training camera sees (in front of the camera, facing it and not hidden
behind other parts of the mesh, tested against a point z-buffer per camera) and cuts the SDF by
the plane perpendicular to the up direction through the lowest of them. Objects whose underside
some camera sees (a NeRF-synthetic sphere of cameras) keep their geometry: the cut falls below
them.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from fracture_gs.recon.grid import VoxelGrid
from fracture_gs.render.camera import Camera

FACING_COS = 0.15          # a vertex faces a camera when n · (towards the camera) exceeds this
DEPTH_TOLERANCE = 2.0      # voxels a seen vertex may lie behind the nearest point of its cell
CELL_SPREAD = 1.5          # z-buffer cells span this many projected voxels, so points close up
LOWEST_SHARE = 0.001       # the support height is this quantile of the seen vertices' heights
MIN_KEEL = 2.0             # voxels the mesh must reach below it before anything is cut


@dataclass(frozen=True)
class SupportCut:
    """The plane the SDF was cut by: points with ``x · up < height`` were removed."""

    up: tuple[float, float, float]
    height: float
    depth: float             # how far the mesh reached below the plane before the cut
    seen_share: float        # share of the mesh vertices some camera sees


def seen_vertices(vertices: np.ndarray, normals: np.ndarray, cameras: Sequence[Camera],
                  voxel: float) -> np.ndarray:
    """(V,) bool: vertices that at least one camera sees (module docstring)."""
    points = torch.as_tensor(vertices, dtype=torch.float32)
    seen = np.zeros(len(vertices), dtype=bool)
    for camera in cameras:
        uv, depth = camera.project(points)
        uv, depth = uv.double().numpy(), depth.double().numpy()
        centre = camera.center.double().numpy()
        towards = centre[None, :] - vertices
        towards /= np.linalg.norm(towards, axis=1, keepdims=True)
        inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & \
            (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        facing = inside & (np.einsum("ij,ij->i", normals, towards) > FACING_COS)
        if not facing.any():
            continue
        cell = max(1.0, CELL_SPREAD * voxel * camera.fx / float(np.median(depth[inside])))
        columns = int(np.ceil(camera.width / cell)) + 1
        index = (np.floor(uv[inside, 1] / cell) * columns + np.floor(uv[inside, 0] / cell)).astype(np.int64)
        nearest = np.full(int(index.max()) + 1, np.inf)
        np.minimum.at(nearest, index, depth[inside])
        front = np.zeros(len(vertices), dtype=bool)
        front[inside] = depth[inside] <= nearest[index] + DEPTH_TOLERANCE * voxel
        seen |= facing & front
    return seen


def support_cut(mesh: trimesh.Trimesh, cameras: Sequence[Camera], up: np.ndarray,
                voxel: float) -> SupportCut | None:
    """The cut below the lowest seen part of ``mesh`` (module docstring), or None when the mesh
    reaches no more than ``MIN_KEEL`` voxels below it."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    seen = seen_vertices(vertices, np.asarray(mesh.vertex_normals, dtype=np.float64), cameras, voxel)
    if not seen.any():
        return None
    heights = vertices @ up
    height = float(np.quantile(heights[seen], LOWEST_SHARE))
    depth = height - float(heights.min())
    if depth <= MIN_KEEL * voxel:
        return None
    return SupportCut(tuple(float(v) for v in up), height, depth, float(seen.mean()))


def cut_sdf(sdf: torch.Tensor, grid: VoxelGrid, cut: SupportCut) -> torch.Tensor:
    """``sdf`` intersected with the half-space x · up >= height (the max of the two SDFs)."""
    nodes = grid.node_positions(device=sdf.device, dtype=torch.float64)
    up = torch.tensor(cut.up, dtype=torch.float64, device=sdf.device)
    below = (cut.height - nodes @ up).to(sdf.dtype)
    return torch.maximum(sdf, below)
