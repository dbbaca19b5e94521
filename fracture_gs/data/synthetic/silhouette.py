"""Exact silhouettes of a triangle mesh: which pixel centres does some triangle cover?

For a mesh entirely in front of the camera, the ray through a pixel centre hits the mesh iff
the centre lies inside one of the projected triangles, so this is ray casting (any hit) done
as vectorised point-in-triangle tests. Used to check rendered masks against ``gt_mesh.ply``.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fracture_gs.render.camera import Camera


def rasterize_silhouette(pixels: np.ndarray, faces: np.ndarray, width: int, height: int,
                         max_candidates: int = 2_000_000) -> np.ndarray:
    """Boolean (height, width) mask of pixel centres (i + 0.5, j + 0.5) covered by triangles.

    ``pixels`` (N,2) are projected vertex positions in pixel units (x right, y down), ``faces``
    (F,3) vertex indices. Triangles are processed in chunks of similar pixel-bounding-box size.
    """
    corners = pixels[faces]  # (F, 3, 2)
    low = np.ceil(corners.min(axis=1) - 0.5).astype(np.int64)
    high = np.floor(corners.max(axis=1) - 0.5).astype(np.int64)
    low = np.maximum(low, 0)
    high = np.minimum(high, np.array([width - 1, height - 1]))
    size = high - low + 1
    first, second = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area2 = np.abs(first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0])
    keep = np.all(size > 0, axis=1) & (area2 > 1e-12)
    corners, low, size = corners[keep], low[keep], size[keep]
    order = np.argsort(size[:, 0] * size[:, 1], kind="stable")
    mask = np.zeros((height, width), dtype=bool)
    start = 0
    while start < len(order):
        # Grow the chunk while (count * largest box) stays under the candidate budget.
        box = size[order[start]]
        stop = start + 1
        while stop < len(order):
            box_next = np.maximum(box, size[order[stop]])
            if (stop - start + 1) * box_next[0] * box_next[1] > max_candidates:
                break
            box, stop = box_next, stop + 1
        chunk = order[start:stop]
        offset_x, offset_y = np.meshgrid(np.arange(box[0]), np.arange(box[1]), indexing="ij")
        px = low[chunk, 0, None] + offset_x.ravel()[None]          # (C, K)
        py = low[chunk, 1, None] + offset_y.ravel()[None]
        inside_box = (px < (low[chunk, 0] + size[chunk, 0])[:, None]) & (
            py < (low[chunk, 1] + size[chunk, 1])[:, None])
        centre_x, centre_y = px + 0.5, py + 0.5
        tri = corners[chunk]
        signs = []
        for k in range(3):
            a, b = tri[:, k], tri[:, (k + 1) % 3]
            signs.append((b[:, 0, None] - a[:, 0, None]) * (centre_y - a[:, 1, None])
                         - (b[:, 1, None] - a[:, 1, None]) * (centre_x - a[:, 0, None]))
        edge = np.stack(signs)
        covered = inside_box & (np.all(edge >= 0, axis=0) | np.all(edge <= 0, axis=0))
        mask[py[covered], px[covered]] = True
        start = stop
    return mask


def mask_iou(first: np.ndarray, second: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    union = np.logical_or(first, second).sum()
    return 1.0 if union == 0 else float(np.logical_and(first, second).sum() / union)


def mask_mesh_ious(cameras: Sequence[Camera], masks: Sequence[np.ndarray], vertices: np.ndarray,
                   faces: np.ndarray) -> list[float]:
    """IoU of each view's (mask > 0.5) with the ray-cast silhouette of the mesh through that
    view's camera. ValueError when the mesh is not entirely in front of a camera."""
    import torch

    points = torch.as_tensor(np.asarray(vertices), dtype=torch.float64)
    ious = []
    for index, (camera, mask) in enumerate(zip(cameras, masks)):
        uv, depth = camera.project(points)
        if float(depth.min()) <= 0:
            raise ValueError(f"view {index}: the mesh is not entirely in front of the camera")
        silhouette = rasterize_silhouette(uv.numpy(), np.asarray(faces), camera.width,
                                          camera.height)
        ious.append(mask_iou(np.asarray(mask) > 0.5, silhouette))
    return ious
