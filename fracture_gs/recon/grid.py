"""A regular lattice of nodes over an axis-aligned box and trilinear interpolation on it.

Every field of the reconstruction (visual-hull SDF, refined SDF, colour features) lives on
the nodes of a :class:`VoxelGrid`: node (i, j, k) sits at ``origin + (i, j, k) * voxel``.
The interpolation is written with gathers so that its backward pass is a scatter into the
node values only (no dense gradient work beyond the gathered corners).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class VoxelGrid:
    """Node lattice: ``shape`` nodes per axis, cubic cells of edge ``voxel``."""

    origin: tuple[float, float, float]
    voxel: float
    shape: tuple[int, int, int]

    @staticmethod
    def around(lower: np.ndarray, upper: np.ndarray, resolution: int) -> "VoxelGrid":
        """Grid with ``resolution`` cells along the longest side of the box [lower, upper];
        the other sides get as many cells as they need (at least 2), centred on the box."""
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        if resolution < 2:
            raise ValueError(f"grid resolution must be >= 2, got {resolution}")
        extent = upper - lower
        if not np.all(extent > 0):
            raise ValueError(f"empty box {lower.tolist()} .. {upper.tolist()}")
        voxel = float(extent.max() / resolution)
        cells = np.maximum(np.ceil(extent / voxel - 1e-6).astype(int), 2)
        origin = 0.5 * (lower + upper) - 0.5 * cells * voxel
        return VoxelGrid(tuple(float(v) for v in origin), voxel,
                         tuple(int(c) + 1 for c in cells))

    @property
    def num_nodes(self) -> int:
        return int(np.prod(self.shape))

    @property
    def lower(self) -> np.ndarray:
        return np.asarray(self.origin)

    @property
    def upper(self) -> np.ndarray:
        return np.asarray(self.origin) + (np.asarray(self.shape) - 1) * self.voxel

    def node_positions(self, device: torch.device | None = None,
                       dtype: torch.dtype = torch.float32) -> torch.Tensor:
        """(nx, ny, nz, 3) world positions of all nodes."""
        axes = [torch.arange(n, dtype=torch.float64, device=device) * self.voxel + o
                for n, o in zip(self.shape, self.origin)]
        return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).to(dtype)

    def refined(self, factor: int) -> "VoxelGrid":
        """The same box with ``factor`` times as many cells per axis."""
        return VoxelGrid(self.origin, self.voxel / factor,
                         tuple((n - 1) * factor + 1 for n in self.shape))

    def to_dict(self) -> dict:
        return {"origin": list(self.origin), "voxel": self.voxel, "shape": list(self.shape)}


@dataclass
class Corners:
    """The 8 lattice corners around each query point and their interpolation weights.

    Corner c = 4 i + 2 j + k is the node base + (i, j, k). ``weights`` (P, 4, 8) holds the
    trilinear weights (row 0) and their derivatives along x, y, z (rows 1-3, per unit
    length), so that one batched product gives a value and its spatial gradient."""

    index: torch.Tensor      # (P, 8) int64 flat node indices
    weights: torch.Tensor    # (P, 4, 8)
    inside: torch.Tensor     # (P,) bool: the point lies in the grid's box

    @property
    def weight(self) -> torch.Tensor:
        """(P, 8) trilinear weights."""
        return self.weights[:, 0]


def _outer(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """(P, 8) products x_i y_j z_k of per-axis pairs (P, 2)."""
    return (x[:, :, None, None] * y[:, None, :, None] * z[:, None, None, :]).reshape(-1, 8)


def cell_corners(grid: VoxelGrid, points: torch.Tensor, with_gradient: bool = True) -> Corners:
    """Corners and weights of ``points`` (P, 3); points outside are clamped to the box."""
    device, dtype = points.device, points.dtype
    upper = torch.tensor([n - 1 for n in grid.shape], dtype=dtype, device=device)
    coords = (points - torch.tensor(grid.origin, dtype=dtype, device=device)) / grid.voxel
    inside = ((coords >= 0) & (coords <= upper)).all(dim=1)
    coords = torch.minimum(coords.clamp_min(0.0), upper)
    base = torch.minimum(torch.floor(coords), upper - 1)
    fraction = coords - base
    base = base.long()
    ny, nz = grid.shape[1], grid.shape[2]
    flat = (base[:, 0] * ny + base[:, 1]) * nz + base[:, 2]
    offsets = torch.tensor([(i * ny + j) * nz + k for i in (0, 1) for j in (0, 1)
                            for k in (0, 1)], device=device)
    wx, wy, wz = (torch.stack([1.0 - fraction[:, a], fraction[:, a]], dim=1) for a in range(3))
    rows = [_outer(wx, wy, wz)]
    if with_gradient:
        slope = torch.tensor([-1.0 / grid.voxel, 1.0 / grid.voxel], dtype=dtype,
                             device=device).expand(points.shape[0], 2)
        rows += [_outer(slope, wy, wz), _outer(wx, slope, wz), _outer(wx, wy, slope)]
    return Corners(flat[:, None] + offsets, torch.stack(rows, dim=1), inside)


def gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``values[index]`` for a (N,) or (N, C) table through ``index_select`` (faster than
    advanced indexing on CPU, and its backward is an ``index_add``)."""
    flat = torch.index_select(values, 0, index.reshape(-1))
    return flat.reshape(*index.shape, *values.shape[1:])


def interpolate(values: torch.Tensor, corners: Corners) -> torch.Tensor:
    """Trilinear interpolation of node values ``values`` (num_nodes,) or (num_nodes, C)."""
    return combine(gather(values, corners.index), corners)


def combine(gathered: torch.Tensor, corners: Corners) -> torch.Tensor:
    """Trilinear combination of gathered corner values (P, 8) -> (P,) or (P, 8, C) -> (P, C)."""
    if gathered.ndim == 2:
        return (gathered * corners.weight).sum(dim=1)
    return torch.bmm(corners.weight[:, None, :], gathered)[:, 0]


def combine_with_gradient(gathered: torch.Tensor,
                          corners: Corners) -> tuple[torch.Tensor, torch.Tensor]:
    """Value (P,) and spatial gradient (P, 3) of the trilinear interpolant of gathered scalar
    corner values (P, 8)."""
    both = torch.bmm(corners.weights, gathered[:, :, None])[..., 0]       # (P, 4)
    return both[:, 0], both[:, 1:]


def interpolate_gradient(values: torch.Tensor, corners: Corners) -> torch.Tensor:
    """Analytic spatial gradient (P, 3) of the trilinear interpolant of scalar node values."""
    return combine_with_gradient(gather(values, corners.index), corners)[1]


def sample_dense(volume: torch.Tensor, grid: VoxelGrid, points: torch.Tensor) -> torch.Tensor:
    """Trilinear samples of a dense volume (nx, ny, nz) -> (P,) or (C, nx, ny, nz) -> (P, C)
    at ``points`` (P, 3), clamped to the box (not differentiable in ``points``)."""
    channels = volume[None] if volume.ndim == 3 else volume
    scale = torch.tensor([2.0 / (n - 1) for n in grid.shape], dtype=points.dtype,
                         device=points.device)
    origin = torch.tensor(grid.origin, dtype=points.dtype, device=points.device)
    normalised = ((points - origin) / grid.voxel * scale - 1.0).flip(-1)   # (k, j, i) order
    out = []
    chunk = 1 << 20
    for start in range(0, points.shape[0], chunk):
        part = normalised[start:start + chunk].to(volume.dtype)
        sampled = torch.nn.functional.grid_sample(
            channels[None], part[None, None, None], mode="bilinear", padding_mode="border",
            align_corners=True)[0, :, 0, 0]                                  # (C, P)
        out.append(sampled)
    result = torch.cat(out, dim=1) if out else channels.new_zeros(channels.shape[0], 0)
    return result[0] if volume.ndim == 3 else result.T


def resample(volume: torch.Tensor, source: VoxelGrid, target: VoxelGrid) -> torch.Tensor:
    """The dense volume (nx, ny, nz) or (C, nx, ny, nz) of ``source`` interpolated at the
    nodes of ``target``."""
    positions = target.node_positions(volume.device, volume.dtype).reshape(-1, 3)
    sampled = sample_dense(volume, source, positions)
    if volume.ndim == 3:
        return sampled.reshape(target.shape)
    return sampled.T.reshape(volume.shape[0], *target.shape)
