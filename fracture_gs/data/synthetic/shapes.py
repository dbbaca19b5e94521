"""Signed distance fields of the bowl, the table and the ficus-like potted plant.

All in "natural" units (metres-like, z up, resting on z = 0); negative inside. Each builder
returns ``(sdf, grid)`` for :func:`fracture_gs.data.synthetic.meshing.mesh_from_sdf`, and each
object has a part spec in the same units (:data:`TABLE_PARTS`, :data:`FICUS_PARTS`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from fracture_gs.data.parts import BoxRule, HalfSpaceRule, PartSpec, single_part_spec
from fracture_gs.data.synthetic.meshing import Grid, SdfFunction, union_into

FAR = 1.0e3  # "no surface near here" value of an empty field


# ----------------------------------------------------------------------------- 2D helpers
def polyline_distance_2d(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Unsigned distance (N,) from 2D points (N,2) to an open polyline (M,2)."""
    best = np.full(len(points), np.inf)
    for start, end in zip(polyline[:-1], polyline[1:]):
        edge = end - start
        t = np.clip((points - start) @ edge / max(edge @ edge, 1e-30), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - start - t[:, None] * edge, axis=1))
    return best


def polygon_sdf_2d(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) from 2D points to a simple closed polygon (M,2)."""
    closed = np.concatenate([polygon, polygon[:1]])
    distance = polyline_distance_2d(points, closed)
    inside = np.zeros(len(points), dtype=bool)
    for start, end in zip(closed[:-1], closed[1:]):
        crosses = (start[1] > points[:, 1]) != (end[1] > points[:, 1])
        x_cross = start[0] + (points[:, 1] - start[1]) * (end[0] - start[0]) / (
            end[1] - start[1] + 1e-300)
        inside ^= crosses & (points[:, 0] < x_cross)
    return np.where(inside, -distance, distance)


def radial(points: np.ndarray) -> np.ndarray:
    """(r, z) coordinates (N,2) of 3D points about the z axis."""
    return np.stack([np.hypot(points[:, 0], points[:, 1]), points[:, 2]], axis=1)


# ----------------------------------------------------------------------------- 3D primitives
def round_box_sdf(points: np.ndarray, center: np.ndarray, half_size: np.ndarray,
                  rounding: float) -> np.ndarray:
    """Box with edges rounded by ``rounding`` (outer size = 2 * half_size)."""
    q = np.abs(points - center) - (np.asarray(half_size) - rounding)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0) - rounding


def tapered_capsule_sdf(points: np.ndarray, start: np.ndarray, end: np.ndarray,
                        radius_start: float, radius_end: float) -> np.ndarray:
    """Segment swept by a sphere whose radius goes linearly from start to end (approximate
    distance, exact zero level for slowly varying radius)."""
    axis = end - start
    t = np.clip((points - start) @ axis / (axis @ axis), 0.0, 1.0)
    radius = radius_start + t * (radius_end - radius_start)
    return np.linalg.norm(points - start - t[:, None] * axis, axis=1) - radius


@dataclass(frozen=True)
class Leaf:
    """An elliptic, slightly folded leaf: centre, unit length axis, unit normal, semi-axes."""

    center: np.ndarray
    length_axis: np.ndarray
    normal: np.ndarray
    semi_length: float
    semi_width: float
    half_thickness: float = 0.006
    rounding: float = 0.005
    fold: float = 3.0

    def sdf(self, points: np.ndarray) -> np.ndarray:
        width_axis = np.cross(self.normal, self.length_axis)
        local = points - self.center
        a = local @ self.length_axis
        b = local @ width_axis
        c = local @ self.normal - self.fold * b ** 2  # V-shaped fold along the midrib
        in_plane = (np.hypot(a / self.semi_length, b / self.semi_width) - 1.0) * self.semi_width
        across = np.abs(c) - self.half_thickness
        q = np.stack([in_plane, across], axis=1)
        return (np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
                - self.rounding)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        reach = self.semi_length + self.rounding + 0.02
        return self.center - reach, self.center + reach


def evaluate_on_grid(grid: Grid, sdf: SdfFunction, slab: int = 16) -> np.ndarray:
    """``sdf`` (a function of (N,3) points) on every grid node, in slabs to bound memory."""
    volume = np.empty(grid.shape)
    for start in range(0, grid.shape[0], slab):
        box = (slice(start, min(start + slab, grid.shape[0])), slice(0, grid.shape[1]),
               slice(0, grid.shape[2]))
        points = grid.node_points(box)
        volume[box] = sdf(points.reshape(-1, 3)).reshape(points.shape[:3])
    return volume


# ----------------------------------------------------------------------------- bowl
BOWL_RADIUS, BOWL_DEPTH, BOWL_FLOOR, BOWL_HALF_THICKNESS = 1.0, 0.6, 0.12, 0.04
BOWL_RIM_ANGLE = 0.47 * np.pi
# Foot ring: a rounded box in (r, z) of this centre and half size, edges rounded by this radius.
BOWL_FOOT_CENTER, BOWL_FOOT_HALF, BOWL_FOOT_ROUNDING = (0.40, 0.06), (0.04, 0.06), 0.015
BOWL_PARTS = single_part_spec("bowl")


def bowl_mid_curve(count: int = 400) -> np.ndarray:
    """(r, z) mid-surface profile of the bowl wall: a quarter ellipse from the axis to the rim."""
    angle = np.linspace(0.0, BOWL_RIM_ANGLE, count)
    return np.stack([BOWL_RADIUS * np.sin(angle),
                     BOWL_FLOOR + BOWL_DEPTH * (1.0 - np.cos(angle))], axis=1)


def bowl_profile_sdf(rz: np.ndarray) -> np.ndarray:
    """2D signed distance of the bowl's cross-section: a wall of constant thickness around the
    mid curve (rounded rim) united with a foot ring."""
    wall = polyline_distance_2d(rz, bowl_mid_curve()) - BOWL_HALF_THICKNESS
    q = np.abs(rz - np.array(BOWL_FOOT_CENTER)) - (np.array(BOWL_FOOT_HALF) - BOWL_FOOT_ROUNDING)
    foot = (np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
            - BOWL_FOOT_ROUNDING)
    return np.minimum(wall, foot)


def bowl_sdf(resolution: int) -> tuple[np.ndarray, Grid]:
    """Bowl: a surface of revolution with a 0.08 thick wall and a foot ring (watertight)."""
    rim = bowl_mid_curve()[-1]
    extent = rim[0] + BOWL_HALF_THICKNESS
    grid = Grid.around(np.array([-extent, -extent, 0.0]),
                       np.array([extent, extent, rim[1] + BOWL_HALF_THICKNESS]), resolution)
    # The field only depends on (r, z): tabulate it finely in 2D and interpolate.
    table_spacing = 0.5 * grid.spacing
    r_axis = np.arange(0.0, np.sqrt(2.0) * grid.shape[0] * grid.spacing, table_spacing)
    z_axis = grid.axis(2, 0, grid.shape[2])
    z_axis = np.arange(z_axis[0] - table_spacing, z_axis[-1] + 2 * table_spacing, table_spacing)
    rr, zz = np.meshgrid(r_axis, z_axis, indexing="ij")
    table = bowl_profile_sdf(np.stack([rr.ravel(), zz.ravel()], 1)).reshape(rr.shape)
    lookup = RegularGridInterpolator((r_axis, z_axis), table, bounds_error=False,
                                     fill_value=FAR)
    return evaluate_on_grid(grid, lambda p: lookup(radial(p))), grid


# ----------------------------------------------------------------------------- table
TABLE_TOP_CENTER = np.array([0.0, 0.0, 0.75])
TABLE_TOP_HALF = np.array([0.6, 0.4, 0.03])
TABLE_LEG_XY = np.array([0.52, 0.32])
TABLE_TOP_UNDERSIDE = float(TABLE_TOP_CENTER[2] - TABLE_TOP_HALF[2])
# The top/legs plane lies a quarter of the top's thickness below its underside, in the legs: a
# plane on the underside itself would give every particle of that large face whichever part the
# reconstruction's millimetre error puts it in (train.py's part_id check), while the
# legs cross it with a small section only.
TABLE_PARTS_PLANE = TABLE_TOP_UNDERSIDE - 0.5 * float(TABLE_TOP_HALF[2])
TABLE_PARTS = PartSpec(part_names=("top", "legs"), default_part=1, rules=(
    HalfSpaceRule(0, (0.0, 0.0, TABLE_PARTS_PLANE), (0.0, 0.0, 1.0)),))
# Where the top's wood gives way to the legs' in the pictures: at the underside.
TABLE_LOOK_PARTS = PartSpec(part_names=("top", "legs"), default_part=1, rules=(
    HalfSpaceRule(0, (0.0, 0.0, TABLE_TOP_UNDERSIDE - 1e-3), (0.0, 0.0, 1.0)),))


def table_field(points: np.ndarray) -> np.ndarray:
    top = round_box_sdf(points, TABLE_TOP_CENTER, TABLE_TOP_HALF, 0.012)
    legs = np.full(len(points), FAR)
    height = TABLE_TOP_UNDERSIDE + 0.01
    # Legs taper from 0.06 (top) to 0.044 (floor): scale x, y by the local half width.
    half_width = 0.022 + 0.008 * np.clip(points[:, 2] / height, 0.0, 1.0)
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            local = points - np.array([sx * TABLE_LEG_XY[0], sy * TABLE_LEG_XY[1], 0.5 * height])
            scaled = local * np.stack([0.03 / half_width, 0.03 / half_width,
                                       np.ones_like(half_width)], axis=1)
            legs = np.minimum(legs, round_box_sdf(scaled, np.zeros(3),
                                                  np.array([0.03, 0.03, 0.5 * height]), 0.006))
    return np.minimum(top, legs)


def table_sdf(resolution: int) -> tuple[np.ndarray, Grid]:
    """Table: a rounded top slab (part 0) on four tapered legs (part 1)."""
    upper = TABLE_TOP_CENTER + TABLE_TOP_HALF
    grid = Grid.around(np.array([-upper[0], -upper[1], 0.0]), upper, resolution)
    return evaluate_on_grid(grid, table_field), grid


# ----------------------------------------------------------------------------- ficus
POT_TOP, SOIL_LEVEL, CROWN_BOTTOM = 0.50, 0.44, 1.12
POT_POLYGON = np.array([[0.0, 0.0], [0.30, 0.0], [0.40, POT_TOP], [0.37, POT_TOP],
                        [0.3628, SOIL_LEVEL], [0.0, SOIL_LEVEL]])
POT_LIP_CENTER, POT_LIP_RADIUS = np.array([0.395, POT_TOP]), 0.028
CROWN_CENTER, CROWN_RADII = np.array([0.0, 0.0, 1.42]), np.array([0.48, 0.48, 0.30])
TRUNK = np.array([[0.0, 0.0, 0.30], [0.02, 0.01, 0.60], [-0.015, 0.02, 0.85],
                  [0.0, 0.0, 1.02]])
# Part rules, first match wins: trunk near the soil -> branches; everything up to the pot's
# lip -> pot; everything below the crown -> branches; the rest (the crown) -> leaves.
FICUS_PARTS = PartSpec(part_names=("pot", "branches", "leaves"), default_part=2, rules=(
    BoxRule(1, (-0.08, -0.08, SOIL_LEVEL + 0.005), (0.08, 0.08, CROWN_BOTTOM)),
    # 5 cm above the lip (nothing but the trunk, caught by the rule above, crosses it below the
    # branches at z >= 0.94): reconstruction error on the lip cannot move it across.
    HalfSpaceRule(0, (0.0, 0.0, POT_TOP + POT_LIP_RADIUS + 0.05), (0.0, 0.0, -1.0)),
    BoxRule(1, (-2.0, -2.0, -1.0), (2.0, 2.0, CROWN_BOTTOM)),
))


@dataclass(frozen=True)
class Plant:
    """Branch segments (start, end, radius_start, radius_end) and leaves of the plant."""

    segments: tuple[tuple[np.ndarray, np.ndarray, float, float], ...]
    leaves: tuple[Leaf, ...]


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _curve(start: np.ndarray, end: np.ndarray, bulge: np.ndarray,
           count: int | np.ndarray) -> np.ndarray:
    """Quadratic Bézier from start to end pulled towards (start+end)/2 + bulge, at ``count``
    even parameters or at the given parameter array."""
    t = (np.linspace(0.0, 1.0, count) if np.isscalar(count) else np.asarray(count))[:, None]
    middle = 0.5 * (start + end) + bulge
    return (1 - t) ** 2 * start + 2 * (1 - t) * t * middle + t ** 2 * end


def grow_plant(seed: int = 0) -> Plant:
    """A standard-trained ficus: trunk, five main branches fanning into an ellipsoidal crown,
    four twigs per branch, leaves along the twigs (only inside the crown, above
    :data:`CROWN_BOTTOM`, so the box part rules separate branches from leaves)."""
    rng = np.random.default_rng(seed)
    segments: list[tuple[np.ndarray, np.ndarray, float, float]] = []

    def add_polyline(points: np.ndarray, radius_start: float, radius_end: float) -> None:
        radii = np.linspace(radius_start, radius_end, len(points))
        for i in range(len(points) - 1):
            segments.append((points[i], points[i + 1], float(radii[i]), float(radii[i + 1])))

    add_polyline(TRUNK, 0.034, 0.024)
    leaves: list[Leaf] = []
    for branch in range(5):
        azimuth = 2 * np.pi * branch / 5 + rng.uniform(-0.3, 0.3)
        outward = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        start = TRUNK[-1] - np.array([0.0, 0.0, rng.uniform(0.0, 0.08)])
        end = CROWN_CENTER + 0.27 * outward + np.array([0.0, 0.0, rng.uniform(-0.05, 0.08)])
        branch_points = _curve(start, end, np.array([0.0, 0.0, -0.05]) + 0.05 * outward, 8)
        add_polyline(branch_points, 0.018, 0.011)
        for _ in range(4):
            direction = _unit(outward + rng.normal(0.0, 0.6, 3) + np.array([0.0, 0.0, 0.5]))
            target = CROWN_CENTER + 0.92 * CROWN_RADII * direction
            twig_start = branch_points[rng.integers(5, 8)]
            bulge = rng.normal(0.0, 0.03, 3)
            add_polyline(_curve(twig_start, target, bulge, 6), 0.009, 0.005)
            leaf_positions = _curve(twig_start, target, bulge, 0.35 + 0.13 * np.arange(6))
            for t_index, position in enumerate(leaf_positions):
                tangent = _unit(target - twig_start)
                side = _unit(np.cross(tangent, np.array([0.0, 0.0, 1.0])) + 1e-6)
                sign = 1.0 if t_index % 2 == 0 else -1.0
                length_axis = _unit(tangent + 1.2 * sign * side
                                    + np.array([0.0, 0.0, -0.35]) + rng.normal(0.0, 0.2, 3))
                normal = _unit(np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.35, 3))
                normal = _unit(normal - (normal @ length_axis) * length_axis)
                semi_length = rng.uniform(0.060, 0.078)
                leaf = Leaf(center=position + length_axis * (semi_length - 0.004),
                            length_axis=length_axis, normal=normal, semi_length=semi_length,
                            semi_width=0.46 * semi_length)
                low, _ = leaf.bounds()
                if low[2] > CROWN_BOTTOM + 0.005:
                    leaves.append(leaf)
    return Plant(tuple(segments), tuple(leaves))


def pot_field(points: np.ndarray) -> np.ndarray:
    rz = radial(points)
    body = polygon_sdf_2d(rz, POT_POLYGON)
    lip = np.linalg.norm(rz - POT_LIP_CENTER, axis=1) - POT_LIP_RADIUS
    return np.minimum(body, lip)


def ficus_sdf(resolution: int, seed: int = 0) -> tuple[np.ndarray, Grid]:
    """Potted plant: terracotta pot filled with soil (part 0), trunk and branches (part 1),
    leaves (part 2)."""
    plant = grow_plant(seed)
    lower = np.array([-0.75, -0.75, 0.0])
    upper = np.array([0.75, 0.75, CROWN_CENTER[2] + CROWN_RADII[2] + 0.15])
    grid = Grid.around(lower, upper, resolution)
    volume = np.full(grid.shape, FAR)
    reach = POT_LIP_CENTER[0] + POT_LIP_RADIUS + 0.02
    union_into(volume, grid, np.array([-reach, -reach, -0.02]),
               np.array([reach, reach, POT_TOP + 0.05]), pot_field)
    for start, end, radius_start, radius_end in plant.segments:
        margin = max(radius_start, radius_end) + 2 * grid.spacing
        union_into(volume, grid, np.minimum(start, end) - margin, np.maximum(start, end) + margin,
                   lambda p, a=start, b=end, ra=radius_start, rb=radius_end:
                   tapered_capsule_sdf(p, a, b, ra, rb))
    for leaf in plant.leaves:
        low, high = leaf.bounds()
        union_into(volume, grid, low, high, leaf.sdf)
    return volume, grid
