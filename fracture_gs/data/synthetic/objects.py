"""The catalogue of synthetic objects: geometry, parts and looks, normalised to the unit sphere.

Object coordinates (= world coordinates of the generated dataset): z up, the object's
bounding-box centre at the origin, scaled so its farthest surface point lies on the unit sphere
(``p = (p_natural - center) * scale``; both numbers are stored in ``parts.json``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

from fracture_gs.data.parts import PartSpec, assign_part_ids, transform_part_spec, single_part_spec
from fracture_gs.data.synthetic import shapes, teapot, textures
from fracture_gs.data.synthetic.meshing import (Grid, drop_small_components, mesh_from_sdf,
                                                normalise_to_unit_sphere)


@dataclass(frozen=True)
class PartLook:
    """Material of one part: a solid texture (natural points -> linear RGB) and gloss."""

    texture: Callable[[np.ndarray], np.ndarray]
    roughness: float
    specular: float


@dataclass(frozen=True)
class Recipe:
    """How to build one object: its SDF builder (resolution, seed), parts and looks.

    ``look_spec`` says which look each face gets where that differs from the material parts of
    ``part_spec`` (None: the same rules)."""

    build_sdf: Callable[[int, int], tuple[np.ndarray, Grid]]
    part_spec: PartSpec
    looks: tuple[PartLook, ...]
    description: str
    look_spec: PartSpec | None = None


@dataclass(frozen=True)
class PartPiece:
    """The faces of one part, with their own vertex copies, normals and colours."""

    part: int
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    colors: np.ndarray
    look: PartLook


@dataclass(frozen=True)
class SyntheticObject:
    """A normalised, watertight object mesh with its part spec and looks."""

    name: str
    mesh: trimesh.Trimesh
    part_spec: PartSpec
    face_parts: np.ndarray
    center: np.ndarray
    scale: float
    looks: tuple[PartLook, ...]
    description: str

    def natural_points(self, points: np.ndarray) -> np.ndarray:
        """Object coordinates -> the natural units the shapes and textures are defined in."""
        return points / self.scale + self.center

    def pieces(self) -> list[PartPiece]:
        """One :class:`PartPiece` per part present (for rendering with per-part materials)."""
        normals = np.asarray(self.mesh.vertex_normals)
        pieces = []
        for part, look in enumerate(self.looks):
            faces = self.mesh.faces[self.face_parts == part]
            if len(faces) == 0:
                continue
            used, local_faces = np.unique(faces, return_inverse=True)
            vertices = np.asarray(self.mesh.vertices)[used]
            colors = np.clip(look.texture(self.natural_points(vertices)), 0.0, 1.0)
            pieces.append(PartPiece(part, vertices, local_faces.reshape(-1, 3), normals[used],
                                    colors, look))
        return pieces


def _bowl_texture(points: np.ndarray) -> np.ndarray:
    r = np.hypot(points[:, 0], points[:, 1])
    rim_radius = shapes.bowl_mid_curve()[-1, 0]
    ratio = np.clip(r / shapes.BOWL_RADIUS, 0.0, 1.0)
    mid_z = shapes.BOWL_FLOOR + shapes.BOWL_DEPTH * (1.0 - np.sqrt(1.0 - ratio ** 2))
    inner = (points[:, 2] > mid_z) | (r > rim_radius)
    return textures.glazed_bowl(points, inner)


def _pot_texture(points: np.ndarray) -> np.ndarray:
    return textures.terracotta_pot(points, shapes.SOIL_LEVEL, float(shapes.POT_POLYGON[4, 0]))


RECIPES: dict[str, Recipe] = {
    "teapot": Recipe(lambda resolution, seed: teapot.teapot_sdf(resolution),
                     single_part_spec("porcelain"),
                     (PartLook(textures.porcelain, 0.15, 0.6),),
                     "Utah teapot (Newell's 32 Bezier patches), solid, lid and spout closed"),
    "bowl": Recipe(lambda resolution, seed: shapes.bowl_sdf(resolution), shapes.BOWL_PARTS,
                   (PartLook(_bowl_texture, 0.2, 0.5),),
                   "glazed bowl: surface of revolution, 0.08 thick wall, foot ring"),
    "table": Recipe(lambda resolution, seed: shapes.table_sdf(resolution), shapes.TABLE_PARTS,
                    (PartLook(textures.oak_top, 0.45, 0.4),
                     PartLook(textures.walnut_legs, 0.55, 0.3)),
                    "table: rounded top (part 0) on four tapered legs (part 1)", shapes.TABLE_LOOK_PARTS),
    "ficus": Recipe(shapes.ficus_sdf, shapes.FICUS_PARTS,
                    (PartLook(_pot_texture, 0.8, 0.2), PartLook(textures.bark, 0.85, 0.2),
                     PartLook(textures.foliage, 0.45, 0.4)),
                    "potted ficus: pot with soil (0), trunk and branches (1), leaves (2)"),
}
OBJECT_NAMES = tuple(RECIPES)


def build_object(name: str, resolution: int = 256, seed: int = 0) -> SyntheticObject:
    """Mesh, normalise and label one catalogue object (``resolution`` marching-cubes cells
    along the longest side of its bounding box)."""
    if name not in RECIPES:
        raise ValueError(f"unknown object {name!r}; choose one of {', '.join(OBJECT_NAMES)}")
    recipe = RECIPES[name]
    sdf, grid = recipe.build_sdf(resolution, seed)
    natural_mesh = drop_small_components(mesh_from_sdf(sdf, grid))
    look_spec = recipe.look_spec if recipe.look_spec is not None else recipe.part_spec
    face_parts_natural = assign_part_ids(natural_mesh.triangles_center, look_spec)
    mesh, center, scale = normalise_to_unit_sphere(natural_mesh)
    spec = transform_part_spec(recipe.part_spec, center, scale)
    face_parts = assign_part_ids(mesh.triangles_center, transform_part_spec(look_spec, center, scale))
    if not np.array_equal(face_parts, face_parts_natural):  # rounding at a rule boundary
        face_parts = face_parts_natural
    return SyntheticObject(name, mesh, spec, face_parts.astype(np.int32), center, scale,
                           recipe.looks, recipe.description)
