"""Free-space carving of the visual hull with multi-view stereo depth (first part of the
photometric refinement).

Silhouettes cannot see a concavity (a bowl's cavity, the recess inside its foot ring), but the
images can: a pixel that shows a textured surface point in several views proves that the ray
to it is empty. For every reference view (``reference_stride``-th view) a plane sweep finds the
depth of each masked pixel: the neighbour views are warped onto fronto-parallel planes by
homographies (OpenCV) and compared with the reference by normalised cross-correlation over
small windows (the best 2 of the neighbours count, which tolerates occlusion). The sweep runs at
several image scales (``scales``: downscale and window of each): a glaze whose colour varies
only slowly gives no correlation in a small window of the fine image but does in the coarse
ones, and their depth maps are pooled. A depth is kept where the correlation is high
(``ncc_threshold``) and where the correlation window lies wholly inside the mask (a window across
the outline of a part seen edge-on matches the surface behind the part). Its 3D point is then
checked against the nearby reference views' depth maps (multi-view depth fusion):

* *confirmed*: it lands within 1.5 voxels of the depth that at least ``consistent_views`` of
  them measured;
* *single*: one of them confirms it and none sees through it (measures a surface more than 1.5
  voxels behind it). On weakly textured surfaces (the bowl's glaze) most true depths are confirmed
  by one neighbour only; requiring several such depths to agree before they carve keeps the
  occasional false match from cutting into a part.

A grid node inside the hull is carved when at least ``votes`` confirmed depths, or at least
``single_view_votes`` single ones, see it more than ``margin_voxels`` in front of their measured
surface, and at most half as many depths (of either kind) see it at that surface. The carved
solid is turned back into a signed distance field (Euclidean distance transforms, lightly
smoothed) around the carved region; elsewhere the hull's sub-voxel distances are kept.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from scipy import ndimage

from fracture_gs.data.cameras import resized_camera
from fracture_gs.data.dataset import Dataset
from fracture_gs.recon.grid import VoxelGrid
from fracture_gs.render.camera import Camera

LUMINANCE = np.array([0.299, 0.587, 0.114], dtype=np.float32)


@dataclass
class CarveSettings:
    reference_stride: int = 1       # every n-th training view gets a depth map
    scales: tuple[tuple[int, int], ...] = ((2, 7), (4, 9), (6, 9))  # (image downscale, NCC
    #                                 window in pixels) of each sweep; their depth maps are pooled
    neighbours: int = 3             # views compared with each reference
    ncc_threshold: float = 0.8
    plane_spacing: float = 1.5      # sweep plane spacing, in voxels
    consistent_views: int = 2       # nearby depth maps that must agree with a confirmed depth
    votes: int = 1                  # confirmed depths that must see a node as free space
    single_view_votes: int = 3      # ... or single-confirmed depths (none seeing through them)
    margin_voxels: float = 1.0      # how far in front of a measured surface counts as free

    def __post_init__(self) -> None:
        for downscale, window in self.scales:
            if downscale < 1 or window < 3 or window % 2 == 0:
                raise ValueError(f"scales: downscale must be >= 1 and the window odd and >= 3, "
                                 f"got ({downscale}, {window})")
        if not self.scales:
            raise ValueError("scales: give at least one (downscale, window)")


@dataclass
class DepthEvidence:
    """The pooled depth maps of every scale, split by how well nearby views confirm them."""

    confirmed: list["DepthMap"]     # depths at least ``consistent_views`` nearby maps agree with
    single: list["DepthMap"]        # depths one nearby map agrees with and none sees through


@dataclass
class DepthMap:
    view: int
    camera: Camera
    depth: np.ndarray               # (H, W) float32, NaN where unknown


def _intrinsics(camera: Camera) -> np.ndarray:
    """K for OpenCV's pixel convention (pixel centres at integer coordinates)."""
    return np.array([[camera.fx, 0.0, camera.cx - 0.5], [0.0, camera.fy, camera.cy - 0.5],
                     [0.0, 0.0, 1.0]])


def _box(image: np.ndarray, window: int) -> np.ndarray:
    return cv2.boxFilter(image, -1, (window, window), normalize=True,
                         borderType=cv2.BORDER_REFLECT)


def _directions(dataset: Dataset, centre: np.ndarray) -> np.ndarray:
    offsets = dataset.camera_centers().double().numpy() - centre
    return offsets / np.linalg.norm(offsets, axis=1, keepdims=True)


def sweep_depth(reference: int, neighbours: list[int], gray: np.ndarray,
                cameras: list[Camera], mask: np.ndarray, planes: np.ndarray,
                window: int, ncc_threshold: float) -> np.ndarray:
    """Winner-take-all plane-sweep depth (H, W) of one view, NaN where not confident (NCC over
    ``window`` x ``window`` pixels at most ``ncc_threshold``, or the window not wholly masked)."""
    height, width = gray.shape[1:]
    world_to_camera = [c.world_to_camera.double().numpy() for c in cameras]
    ref = gray[reference]
    ref_mean = _box(ref, window)
    ref_var = _box(ref * ref, window) - ref_mean * ref_mean
    inverse = np.linalg.inv(_intrinsics(cameras[reference]))
    scores = np.empty((len(neighbours), len(planes), height, width), dtype=np.float32)
    for slot, other in enumerate(neighbours):
        relative = world_to_camera[other] @ np.linalg.inv(world_to_camera[reference])
        rotation, translation = relative[:3, :3], relative[:3, 3]
        for index, depth in enumerate(planes):
            homography = _intrinsics(cameras[other]) @ (
                rotation + np.outer(translation, [0.0, 0.0, 1.0 / depth])) @ inverse
            warped = cv2.warpPerspective(gray[other], homography, (width, height),
                                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            warped_mean = _box(warped, window)
            warped_var = _box(warped * warped, window) - warped_mean * warped_mean
            covariance = _box(ref * warped, window) - ref_mean * warped_mean
            scores[slot, index] = covariance / np.sqrt(np.maximum(ref_var * warped_var, 1e-6))
    keep = min(2, len(neighbours))
    best_of = np.sort(scores, axis=0)[-keep:].mean(axis=0)
    depth = planes[best_of.argmax(axis=0)]
    # Only windows that lie wholly on the object: a window across its outline compares
    # background too, and on a part seen edge-on (a thin table top) it matches the surface
    # behind the part, a depth that would carve the part.
    inside = cv2.erode(mask.astype(np.uint8), np.ones((window, window), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    confident = (best_of.max(axis=0) > ncc_threshold) & inside & (ref_var > 1e-4)
    return np.where(confident, depth, np.nan).astype(np.float32)


def _project(points: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel column, row (indices of the pixel containing the point) and camera depth."""
    world_to_camera = camera.world_to_camera.double().numpy()
    local = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = local[:, 2]
    safe = np.where(depth > 1e-9, depth, 1e-9)
    column = np.floor(camera.fx * local[:, 0] / safe + camera.cx).astype(np.int64)
    row = np.floor(camera.fy * local[:, 1] / safe + camera.cy).astype(np.int64)
    return column, row, depth


def _lookup(depth_map: DepthMap, column: np.ndarray, row: np.ndarray) -> np.ndarray:
    height, width = depth_map.depth.shape
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    values = np.full(len(column), np.nan, dtype=np.float64)
    values[inside] = depth_map.depth[row[inside], column[inside]]
    return values


def consistent_depths(maps: list[DepthMap], directions: np.ndarray, voxel: float,
                      settings: CarveSettings) -> tuple[list[DepthMap], list[DepthMap]]:
    """Split the depths of ``maps`` by their agreement with the ``neighbours`` + 1 nearest
    other maps: (confirmed by at least ``consistent_views`` of them, confirmed by one of them
    with none seeing through the point); other depths are dropped."""
    confirmed, single = [], []
    for current in maps:
        rows, columns = np.nonzero(np.isfinite(current.depth))
        depth = current.depth[rows, columns].astype(np.float64)
        camera = current.camera
        local = np.stack([(columns + 0.5 - camera.cx) / camera.fx * depth,
                          (rows + 0.5 - camera.cy) / camera.fy * depth, depth], axis=1)
        camera_to_world = np.linalg.inv(camera.world_to_camera.double().numpy())
        points = local @ camera_to_world[:3, :3].T + camera_to_world[:3, 3]
        others = sorted((m for m in maps if m is not current),
                        key=lambda m: -float(directions[m.view] @ directions[current.view]))
        agree = np.zeros(len(depth), dtype=np.int32)
        see_through = np.zeros(len(depth), dtype=np.int32)
        for other in others[:settings.neighbours + 1]:
            column, row, seen_depth = _project(points, other.camera)
            measured = _lookup(other, column, row)
            agree += (np.abs(measured - seen_depth) < 1.5 * voxel).astype(np.int32)
            see_through += (measured > seen_depth + 1.5 * voxel).astype(np.int32)
        is_confirmed = agree >= settings.consistent_views
        is_single = ~is_confirmed & (agree >= 1) & (see_through == 0)
        for keep, out in ((is_confirmed, confirmed), (is_single, single)):
            kept = np.full_like(current.depth, np.nan)
            kept[rows[keep], columns[keep]] = depth[keep]
            out.append(DepthMap(current.view, camera, kept))
    return confirmed, single


def sweep_maps(dataset: Dataset, grid: VoxelGrid, settings: CarveSettings, luminance: np.ndarray,
               masks: np.ndarray, directions: np.ndarray, downscale: int, window: int
               ) -> list[DepthMap]:
    """Plane-sweep depth maps of the reference views at one image scale (downscaled cameras).
    ``luminance`` and ``masks`` (views, H, W) are the full-size grey images and masks,
    ``directions`` (views, 3) the unit vectors from the grid's centre to each camera."""
    scale = max(1, downscale)
    width, height = max(1, dataset.width // scale), max(1, dataset.height // scale)
    gray = np.stack([cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
                     for image in luminance]).astype(np.float32)
    masks = np.stack([cv2.resize(mask, (width, height), interpolation=cv2.INTER_AREA)
                      for mask in masks]) > 0.5
    cameras = [resized_camera(c, width, height) for c in dataset.cameras]
    corners = np.array([[x, y, z] for x in (grid.lower[0], grid.upper[0])
                        for y in (grid.lower[1], grid.upper[1])
                        for z in (grid.lower[2], grid.upper[2])])
    references = list(range(0, len(dataset), max(1, settings.reference_stride)))
    maps = []
    for reference in references:
        order = np.argsort(-(directions @ directions[reference]))
        neighbours = [int(v) for v in order if v != reference][:settings.neighbours]
        _, _, corner_depth = _project(corners, cameras[reference])
        near = max(float(corner_depth.min()), 1e-3)
        planes = np.arange(near, float(corner_depth.max()), settings.plane_spacing * grid.voxel)
        if len(planes) < 2 or not neighbours:
            continue
        depth = sweep_depth(reference, neighbours, gray, cameras, masks[reference], planes,
                            window, settings.ncc_threshold)
        maps.append(DepthMap(reference, cameras[reference], depth))
    return maps


def stereo_depth_maps(dataset: Dataset, grid: VoxelGrid, settings: CarveSettings) -> DepthEvidence:
    """The depth maps of every scale, each scale's checked against its own nearby maps."""
    directions = _directions(dataset, 0.5 * (grid.lower + grid.upper))
    luminance = dataset.images.cpu().numpy() @ LUMINANCE
    masks = dataset.masks.cpu().numpy()
    evidence = DepthEvidence([], [])
    for downscale, window in settings.scales:
        maps = sweep_maps(dataset, grid, settings, luminance, masks, directions, downscale, window)
        confirmed, single = consistent_depths(maps, directions, grid.voxel, settings)
        evidence.confirmed.extend(confirmed)
        evidence.single.extend(single)
    return evidence


def _free_and_surface_votes(positions: np.ndarray, maps: list[DepthMap], margin: float
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Per point: maps that see it more than ``margin`` in front of their surface, and maps
    that see it within ``margin`` of their surface."""
    free = np.zeros(len(positions), dtype=np.int32)
    surface = np.zeros(len(positions), dtype=np.int32)
    for depth_map in maps:
        column, row, depth = _project(positions, depth_map.camera)
        measured = _lookup(depth_map, column, row)
        known = np.isfinite(measured)
        free += (known & (depth < measured - margin)).astype(np.int32)
        surface += (known & (np.abs(depth - measured) <= margin)).astype(np.int32)
    return free, surface


def carve_with_depth(sdf: torch.Tensor, grid: VoxelGrid, maps: list[DepthMap],
                     settings: CarveSettings, single_maps: list[DepthMap] | None = None
                     ) -> tuple[torch.Tensor, int]:
    """The SDF with the free space seen in ``maps`` (confirmed depths) and ``single_maps``
    (single-confirmed depths) removed, and the number of carved nodes (module docstring)."""
    single_maps = single_maps or []
    values = sdf.detach().cpu().numpy().astype(np.float32)
    inside = np.nonzero(values.reshape(-1) < 0)[0]
    if len(inside) == 0 or not (maps or single_maps):
        return sdf.clone(), 0
    positions = grid.node_positions(dtype=torch.float64).reshape(-1, 3).numpy()[inside]
    margin = settings.margin_voxels * grid.voxel
    free, surface = _free_and_surface_votes(positions, maps, margin)
    free_single, surface_single = _free_and_surface_votes(positions, single_maps, margin)
    carve = (((free >= settings.votes) | (free_single >= settings.single_view_votes))
             & (free + free_single > 2 * (surface + surface_single)))
    carved_count = int(carve.sum())
    if carved_count == 0:
        return sdf.clone(), 0
    solid = values < 0
    solid.reshape(-1)[inside[carve]] = False
    distance = np.where(solid, 0.5 - ndimage.distance_transform_edt(solid),
                        ndimage.distance_transform_edt(~solid) - 0.5) * grid.voxel
    distance = ndimage.gaussian_filter(distance, sigma=0.8)
    changed = np.zeros(values.shape, dtype=bool)
    changed.reshape(-1)[inside[carve]] = True
    near_change = ndimage.binary_dilation(changed, iterations=3)
    result = np.where(near_change, distance, values).astype(np.float32)
    return torch.from_numpy(result).to(sdf.device), carved_count


def carve_hull(dataset: Dataset, grid: VoxelGrid, sdf: torch.Tensor,
               settings: CarveSettings | None = None) -> tuple[torch.Tensor, int]:
    """Depth maps of ``dataset`` and the hull SDF carved with them."""
    settings = settings or CarveSettings()
    if len(dataset) < 3:
        return sdf.clone(), 0
    evidence = stereo_depth_maps(dataset, grid, settings)
    return carve_with_depth(sdf, grid, evidence.confirmed, settings, evidence.single)
