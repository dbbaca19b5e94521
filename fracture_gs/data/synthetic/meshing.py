"""Signed-distance grids → watertight triangle meshes, and object normalisation.

Every synthetic object is defined as a signed distance field (negative inside) sampled on the
nodes of a regular grid, and meshed with marching cubes (PyMCubes). A field that is positive on
the whole grid border gives a closed, consistently oriented surface.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mcubes
import numpy as np
import trimesh
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Grid:
    """Regular grid of nodes ``origin + spacing * (i, j, k)``, ``0 <= (i, j, k) < shape``."""

    origin: np.ndarray
    spacing: float
    shape: tuple[int, int, int]

    @staticmethod
    def around(lower: np.ndarray, upper: np.ndarray, resolution: int,
               padding: int = 3) -> "Grid":
        """Grid covering the box [lower, upper] with ``resolution`` cells along its longest side
        and ``padding`` extra nodes on every side."""
        if resolution < 8:
            raise ValueError(f"grid resolution must be >= 8, got {resolution}")
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        spacing = float(np.max(upper - lower)) / resolution
        counts = np.ceil((upper - lower) / spacing).astype(int) + 1 + 2 * padding
        return Grid(lower - padding * spacing, spacing, tuple(int(c) for c in counts))

    def axis(self, dim: int, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Node coordinates along one axis."""
        stop = self.shape[dim] if stop is None else stop
        return self.origin[dim] + self.spacing * np.arange(start, stop)

    def node_box(self, lower: np.ndarray, upper: np.ndarray) -> tuple[slice, slice, slice]:
        """Index slices of the nodes inside the box [lower, upper] (clipped to the grid)."""
        start = np.floor((np.asarray(lower) - self.origin) / self.spacing).astype(int)
        stop = np.ceil((np.asarray(upper) - self.origin) / self.spacing).astype(int) + 1
        start = np.clip(start, 0, self.shape)
        stop = np.clip(stop, 0, self.shape)
        slices = tuple(slice(int(a), int(b)) for a, b in zip(start, stop))
        return slices  # type: ignore[return-value]

    def node_points(self, box: tuple[slice, slice, slice] | None = None) -> np.ndarray:
        """Coordinates (a, b, c, 3) of the nodes of ``box`` (default: all nodes)."""
        box = box or tuple(slice(0, n) for n in self.shape)
        axes = [self.axis(d, box[d].start, box[d].stop) for d in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


SdfFunction = Callable[[np.ndarray], np.ndarray]


def union_into(volume: np.ndarray, grid: Grid, lower: np.ndarray, upper: np.ndarray,
               sdf: SdfFunction) -> None:
    """volume = min(volume, sdf) on the nodes inside [lower, upper] only (local evaluation for
    small primitives; ``sdf`` must be positive outside that box)."""
    box = grid.node_box(lower, upper)
    if any(s.stop <= s.start for s in box):
        return
    points = grid.node_points(box)
    values = sdf(points.reshape(-1, 3)).reshape(points.shape[:3])
    np.minimum(volume[box], values, out=volume[box])


def mesh_from_sdf(sdf: np.ndarray, grid: Grid) -> trimesh.Trimesh:
    """Marching cubes of the zero level of ``sdf`` (negative inside): an outward-oriented mesh."""
    if sdf.shape != grid.shape:
        raise ValueError(f"sdf shape {sdf.shape} does not match grid shape {grid.shape}")
    border = np.concatenate([sdf[[0, -1]].ravel(), sdf[:, [0, -1]].ravel(),
                             sdf[:, :, [0, -1]].ravel()])
    if np.any(border <= 0):
        raise ValueError("the object touches the grid border: its surface would be open")
    # Nodes exactly on the level set would make distinct MC vertices coincide; nudge them out.
    field = np.where(sdf == 0.0, 1e-12, sdf)
    vertices, faces = mcubes.marching_cubes(-field, 0.0)
    if len(faces) == 0:
        raise ValueError("marching cubes found no surface (the field has no negative values)")
    # PyMCubes already shares vertices between cells; merging coincident vertices again would
    # glue sheets that only touch and break manifoldness, so the mesh is taken as is.
    mesh = trimesh.Trimesh(vertices * grid.spacing + grid.origin, faces.astype(np.int64),
                           process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def solid_sdf_from_surface_samples(points: np.ndarray, normals: np.ndarray,
                                   grid: Grid) -> np.ndarray:
    """Signed distance of the solid enclosed by a closed (possibly self-intersecting) surface,
    given dense samples of it (spacing well below ``grid.spacing``) with unoriented normals.

    1. Voxels holding a sample (dilated once) are walls; the outside is the wall-free region
       6-connected to the grid corner (a flood fill), the inside is everything else.
    2. Samples whose both sides (±3 voxels along the normal) are not outside lie buried inside
       the solid (e.g. the ends of the teapot's handle) and are dropped; the others get their
       normal turned towards the outside.
    3. Near the surface the field is the distance to the tangent plane of the nearest kept
       sample (accurate well below the sample spacing); farther away it is ± the distance to
       the nearest sample, with the sign from the flood fill.
    """
    spacing = grid.spacing
    shape = np.asarray(grid.shape)
    cells = np.floor((points - grid.origin) / spacing + 0.5).astype(int)
    if np.any(cells < 1) or np.any(cells >= shape - 1):
        raise ValueError("surface samples reach the grid border: enlarge the grid padding")
    wall = np.zeros(grid.shape, dtype=bool)
    wall[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    wall = ndimage.binary_dilation(wall, structure=np.ones((3, 3, 3), dtype=bool))
    labels, _ = ndimage.label(~wall)  # 6-connectivity
    outside = labels == labels[0, 0, 0]

    def is_outside(query: np.ndarray) -> np.ndarray:
        index = np.clip(np.floor((query - grid.origin) / spacing + 0.5).astype(int), 0, shape - 1)
        return outside[index[:, 0], index[:, 1], index[:, 2]]

    unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    plus = is_outside(points + 3.0 * spacing * unit)
    minus = is_outside(points - 3.0 * spacing * unit)
    keep = plus | minus
    oriented = np.where((plus | ~minus)[:, None], unit, -unit)[keep]
    kept_points = points[keep]

    # Far field: sign from the flood fill, magnitude clamped (only the zero level matters).
    band_width = 4.0 * spacing
    sdf = np.where(outside, band_width, -band_width).astype(np.float64)
    band = ndimage.binary_dilation(wall, iterations=2)
    band_index = np.argwhere(band)
    band_points = grid.origin + spacing * band_index
    distance, nearest = cKDTree(kept_points).query(band_points, distance_upper_bound=band_width,
                                                   workers=-1)
    found = np.isfinite(distance)
    plane_distance = np.einsum("ij,ij->i", band_points[found] - kept_points[nearest[found]],
                               oriented[nearest[found]])
    far_sign = np.where(outside[tuple(band_index[found].T)], 1.0, -1.0)
    values = np.where(distance[found] < 2.0 * spacing, plane_distance,
                      far_sign * distance[found])
    sdf[tuple(band_index[found].T)] = values
    return keep_largest_solid(sdf)


def keep_largest_solid(sdf: np.ndarray) -> np.ndarray:
    """Remove inside islands other than the largest one and fill enclosed outside bubbles
    (flips the field's sign there), so marching cubes gives a single closed surface."""
    inside = sdf < 0
    labels, count = ndimage.label(inside)
    cleaned = sdf.copy()
    if count > 1:
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        islands = (labels > 0) & (labels != np.argmax(sizes))
        cleaned[islands] = np.abs(cleaned[islands]) + 1e-9
    outside_labels, _ = ndimage.label(cleaned >= 0)
    bubbles = (cleaned >= 0) & (outside_labels != outside_labels[0, 0, 0])
    cleaned[bubbles] = -np.abs(cleaned[bubbles]) - 1e-9
    return cleaned


def _vertex_components(mesh: trimesh.Trimesh) -> tuple[int, np.ndarray]:
    edges = mesh.edges_unique
    n = len(mesh.vertices)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    count, labels = connected_components(graph, directed=False)
    return int(count), labels


def connected_component_count(mesh: trimesh.Trimesh) -> int:
    """Number of vertex-connected pieces of a mesh (fast, via a sparse graph)."""
    return _vertex_components(mesh)[0]


def drop_small_components(mesh: trimesh.Trimesh, min_fraction: float = 0.002) -> trimesh.Trimesh:
    """Remove closed pieces with fewer than ``min_fraction`` of the faces (marching-cubes specks
    where a thin feature, e.g. a leaf tip, is thinner than the grid)."""
    count, labels = _vertex_components(mesh)
    if count == 1:
        return mesh
    face_labels = labels[mesh.faces[:, 0]]
    sizes = np.bincount(face_labels, minlength=count)
    keep = sizes[face_labels] >= min_fraction * len(mesh.faces)
    cleaned = trimesh.Trimesh(mesh.vertices, mesh.faces[keep], process=False)
    cleaned.remove_unreferenced_vertices()
    return cleaned


def normalise_to_unit_sphere(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, float]:
    """Centre the mesh at its bounding-box centre and scale it so its farthest vertex lies on
    the unit sphere. Returns (new mesh, centre, scale): ``p_new = (p - centre) * scale``."""
    center = 0.5 * (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0))
    radius = float(np.max(np.linalg.norm(mesh.vertices - center, axis=1)))
    if radius <= 0:
        raise ValueError("cannot normalise a mesh with zero extent")
    scale = 1.0 / radius
    normalised = trimesh.Trimesh((mesh.vertices - center) * scale, mesh.faces, process=False)
    return normalised, center, scale
