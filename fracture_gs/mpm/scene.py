"""SceneConfig → particles, material table and solver settings (docs/scenes.md, docs/file_formats.md §2).

Objects come either from an analytic primitive (box / sphere / cylinder), sampled
jittered-uniformly with ``particles_per_cell`` particles per grid cell, or from a particles
``.ply`` written by ``train.py`` (properties ``x y z volume is_surface part_id
gaussian_index``). Each object's transform is ``x_world = translate + scale · R · x`` with
``R = Rz·Ry·Rx`` (extrinsic X, then Y, then Z rotations by ``rotate_deg``); volumes of model
particles scale by ``scale³``. Every (object, part) pair becomes one row of the material
table and ``material_id`` points each particle at its row.

Problems that need the particles (a part without a material, an object outside the domain)
raise :class:`~fracture_gs.config.scene.SceneError` naming the key path.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from fracture_gs.config.scene import (Boundary, ContactSettings, Domain, GroundBoundary, MaterialConfig,
                                      ObjectConfig, PrimitiveConfig, SceneConfig, SceneError, TransformConfig)
from fracture_gs.mpm.density import density_warnings
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.types import ParticleSet

WALL_CELLS = 3  # thickness of the box walls; objects must start inside this margin
# Share of an object's particles lying inside another object above which the scene is reported
# as suspicious: objects are meant to start apart or touching, and overlapping material is
# pushed apart violently in the first substeps.
OVERLAP_WARNING_SHARE = 0.10


@dataclass
class ObjectParticles:
    """Particles of one object in its own frame (before the scene transform)."""

    x: np.ndarray               # (n,3) float64
    rest_volume: np.ndarray     # (n,) float64
    is_surface: np.ndarray      # (n,) bool
    part_id: np.ndarray         # (n,) int32
    gaussian_index: np.ndarray  # (n,) int64, -1 where there is no Gaussian


@dataclass
class BuiltScene:
    """Everything the solver needs, built from a :class:`SceneConfig`."""

    particles: ParticleSet
    materials: list[Any]                  # one material (fracture_gs.materials) per table row
    material_keys: list[tuple[int, int]]  # (object index, part id) of each table row
    object_names: list[str]
    domain: Domain
    contact: ContactSettings
    boundaries: list[Boundary]
    gravity: tuple[float, float, float]
    cfl: float
    seed: int = 0                         # the scene's seed (brittle strengths hash it with the row)
    rigid_objects: tuple[int, ...] = ()   # indices of the objects that move as rigid bodies
    warnings: tuple[str, ...] = ()        # legal but suspicious set-ups (overlapping objects)

    @property
    def step_rows(self) -> list[int]:
        """Material rows whose wave speed limits the time step: those of the deforming objects."""
        return [row for row, (obj, _) in enumerate(self.material_keys) if obj not in self.rigid_objects]


# ----------------------------------------------------------------------------- geometry


def rotation_matrix_xyz(rotate_deg: tuple[float, float, float]) -> np.ndarray:
    """R = Rz(γ)·Ry(β)·Rx(α) for ``rotate_deg = [α, β, γ]`` (extrinsic X, Y, Z, degrees)."""
    return Rotation.from_euler("xyz", rotate_deg, degrees=True).as_matrix()


def apply_transform(x: np.ndarray, transform: TransformConfig) -> np.ndarray:
    """World positions ``translate + scale · R · x`` of object-frame points ``x`` (n,3)."""
    rotation = rotation_matrix_xyz(transform.rotate_deg)
    return transform.scale * (x @ rotation.T) + np.asarray(transform.translate)


def primitive_signed_distance(primitive: PrimitiveConfig, x: np.ndarray,
                              scale: float = 1.0) -> np.ndarray:
    """Signed distance (negative inside) of points ``x`` to the primitive scaled by ``scale``.

    Exact for box and sphere; for the cylinder the max of the radial and axial distances
    (exact inside, a lower bound outside), which is all the sampling needs.
    """
    if primitive.shape == "sphere":
        assert primitive.radius is not None
        return np.linalg.norm(x, axis=1) - scale * primitive.radius
    if primitive.shape == "box":
        assert primitive.size is not None
        q = np.abs(x) - 0.5 * scale * np.asarray(primitive.size)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        return outside + inside
    assert primitive.radius is not None and primitive.height is not None
    radial = np.linalg.norm(x[:, :2], axis=1) - scale * primitive.radius
    axial = np.abs(x[:, 2]) - 0.5 * scale * primitive.height
    return np.maximum(radial, axial)


def _half_extent(primitive: PrimitiveConfig) -> np.ndarray:
    if primitive.shape == "box":
        assert primitive.size is not None
        return 0.5 * np.asarray(primitive.size, dtype=np.float64)
    assert primitive.radius is not None
    if primitive.shape == "sphere":
        return np.full(3, primitive.radius)
    assert primitive.height is not None
    return np.array([primitive.radius, primitive.radius, 0.5 * primitive.height])


def primitive_lattice(primitive: PrimitiveConfig, dx: float, scale: float
                      ) -> tuple[float, np.ndarray]:
    """Sub-cell edge ``h = dx / ppc^(1/3)`` and the (3,) sub-cells per axis of the box around
    the primitive that :func:`sample_primitive` fills: one candidate particle per sub-cell."""
    spacing = dx / primitive.particles_per_cell ** (1.0 / 3.0)
    half = scale * _half_extent(primitive)
    return spacing, np.ceil(2.0 * half / spacing).astype(np.int64)


def sample_primitive(primitive: PrimitiveConfig, dx: float, scale: float,
                     rng: np.random.Generator) -> ObjectParticles:
    """Jittered-uniform particles of the primitive scaled by ``scale`` (object frame, centred).

    Space is cut into sub-cells of edge ``h = dx / ppc^(1/3)`` (so each grid cell holds
    ``particles_per_cell`` of them on average) and one particle is placed uniformly at random
    in each sub-cell; those inside the shape are kept. ``rest_volume = h³ = dx³ / ppc``.
    Particles closer than ``h`` to the boundary are marked ``is_surface``.
    """
    spacing, counts = primitive_lattice(primitive, dx, scale)
    axes = [(np.arange(n) - 0.5 * (n - 1)) * spacing for n in counts]  # centred lattice
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    x = centres + rng.uniform(-0.5, 0.5, size=centres.shape) * spacing
    distance = primitive_signed_distance(primitive, x, scale)
    inside = distance <= 0.0
    x = x[inside]
    n = x.shape[0]
    return ObjectParticles(x=x, rest_volume=np.full(n, spacing ** 3),
                           is_surface=distance[inside] > -spacing,
                           part_id=np.zeros(n, dtype=np.int32),
                           gaussian_index=np.full(n, -1, dtype=np.int64))


# ----------------------------------------------------------------------------- particles.ply


def load_particles_ply(path: str | Path, key_path: str = "model") -> ObjectParticles:
    """Read a ``particles.ply`` (docs/file_formats.md §2): x y z volume [is_surface part_id gaussian_index].

    Missing optional properties default to not-surface, part 0 and no Gaussian (-1).
    """
    from fracture_gs.io.particles_ply import ParticlesPlyError, read_particles_ply

    path = Path(path)
    try:
        data = read_particles_ply(path)
    except ParticlesPlyError as exc:
        raise SceneError(key_path, str(exc)) from None
    names = set(data) - {"comments"}
    for required in ("x", "y", "z", "volume"):
        if required not in names:
            raise SceneError(key_path, f"'{path}' lacks the particle property '{required}'")
    n = len(data["x"])
    if n == 0:
        raise SceneError(key_path, f"'{path}' holds no particles")
    x = np.stack([np.asarray(data[a], dtype=np.float64) for a in "xyz"], axis=1)
    volume = np.asarray(data["volume"], dtype=np.float64)
    if not np.isfinite(x).all():
        raise SceneError(key_path, f"'{path}' has non-finite particle positions")
    if not (np.isfinite(volume).all() and (volume > 0).all()):
        raise SceneError(key_path, f"'{path}' has particle volumes that are not > 0")

    def optional(name: str, dtype: Any, default: Any) -> np.ndarray:
        if name in names:
            return np.asarray(data[name]).astype(dtype)
        return np.full(n, default, dtype=dtype)

    part_id = optional("part_id", np.int64, 0)
    if (part_id < 0).any():
        raise SceneError(key_path, f"'{path}' has negative part_id values")
    return ObjectParticles(x=x, rest_volume=volume,
                           is_surface=optional("is_surface", np.int64, 0) != 0,
                           part_id=part_id.astype(np.int32),
                           gaussian_index=optional("gaussian_index", np.int64, -1))


# ----------------------------------------------------------------------------- materials


def initial_velocities(obj: ObjectConfig, x: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """(n, 3) initial velocity of an object's particles: v(x) = velocity + ω × (x − c) + L (x − c),
    c the object's centre of mass."""
    centre = (mass[:, None] * x).sum(axis=0) / mass.sum()
    offset = x - centre
    return (np.asarray(obj.velocity, dtype=np.float64)
            + np.cross(np.asarray(obj.angular_velocity, dtype=np.float64), offset)
            + offset @ np.asarray(obj.velocity_gradient, dtype=np.float64).T)


# ----------------------------------------------------------------------------- assembly


def object_particles(config: SceneConfig, index: int) -> ObjectParticles:
    """World-frame particles of ``config.objects[index]`` (transform applied, volumes scaled)."""
    obj = config.objects[index]
    path = f"objects[{index}]"
    if obj.primitive is not None:
        rng = np.random.default_rng([config.seed, index])
        local = sample_primitive(obj.primitive, config.domain.dx, obj.transform.scale, rng)
        if local.x.shape[0] == 0:
            raise SceneError(f"{path}.primitive", "the shape is too small to hold a particle "
                             f"at this grid (dx = {config.domain.dx:g})")
        unit = TransformConfig(scale=1.0, rotate_deg=obj.transform.rotate_deg,
                               translate=obj.transform.translate)
        local.x = apply_transform(local.x, unit)  # already sampled at world scale
        return local
    assert obj.particles_file is not None
    loaded = load_particles_ply(obj.particles_file, f"{path}.model")
    loaded.x = apply_transform(loaded.x, obj.transform)
    loaded.rest_volume = loaded.rest_volume * obj.transform.scale ** 3
    return loaded


def check_inside_domain(config: SceneConfig, index: int, x: np.ndarray) -> None:
    """Raise SceneError unless all of an object's particles lie inside the domain walls
    (``WALL_CELLS`` cells from the faces) and above the ground."""
    obj: ObjectConfig = config.objects[index]
    key = f"objects[{index}].transform"
    margin = WALL_CELLS * config.domain.dx
    lo, hi = x.min(axis=0), x.max(axis=0)
    for axis, name in enumerate("xyz"):
        inner_lo = config.domain.lower[axis] + margin
        inner_hi = config.domain.upper[axis] - margin
        if lo[axis] < inner_lo:
            raise SceneError(key, f"object '{obj.name}' reaches {name} = {lo[axis]:.4g}, outside "
                             f"the domain interior [{inner_lo:.4g}, {inner_hi:.4g}] "
                             f"(domain minus {WALL_CELLS} wall cells)")
        if hi[axis] > inner_hi:
            raise SceneError(key, f"object '{obj.name}' reaches {name} = {hi[axis]:.4g}, outside "
                             f"the domain interior [{inner_lo:.4g}, {inner_hi:.4g}] "
                             f"(domain minus {WALL_CELLS} wall cells)")
    for boundary in config.boundaries:
        if isinstance(boundary, GroundBoundary) and lo[2] < boundary.height:
            raise SceneError(key, f"object '{obj.name}' reaches z = {lo[2]:.4g}, below the "
                             f"ground at height {boundary.height:g}")


def inside_object(config: SceneConfig, index: int, particles: ObjectParticles,
                  x: np.ndarray) -> np.ndarray:
    """(n,) bool: which world points ``x`` lie inside ``config.objects[index]``, whose world-frame
    particles are ``particles``. Exact for a primitive (its signed distance); for a model object
    a point is inside when a particle of the object lies within one particle spacing of it."""
    obj = config.objects[index]
    if obj.primitive is not None:
        rotation = rotation_matrix_xyz(obj.transform.rotate_deg)
        local = (x - np.asarray(obj.transform.translate)) @ rotation  # R^T (x - t)
        return primitive_signed_distance(obj.primitive, local, obj.transform.scale) <= 0.0
    from scipy.spatial import cKDTree

    spacing = float(np.median(particles.rest_volume)) ** (1.0 / 3.0)
    distance, _ = cKDTree(particles.x).query(x, distance_upper_bound=spacing)
    return np.isfinite(distance)


def overlap_warnings(config: SceneConfig, objects: list[ObjectParticles]) -> list[str]:
    """One line per pair of objects of which one has more than ``OVERLAP_WARNING_SHARE`` of its
    particles inside the other (``objects``: the world-frame particles of every object)."""
    lines = []
    bounds = [(parts.x.min(axis=0), parts.x.max(axis=0)) for parts in objects]
    for i in range(len(objects)):
        for j in range(i + 1, len(objects)):
            shares = []
            for inner, outer in ((i, j), (j, i)):
                lower, upper = bounds[outer]
                x = objects[inner].x
                near = np.all((x >= lower - config.domain.dx) & (x <= upper + config.domain.dx),
                              axis=1)
                inside = inside_object(config, outer, objects[outer], x[near]).sum() if \
                    near.any() else 0
                shares.append((int(inside) / len(x), inner, outer))
            share, inner, outer = max(shares, key=lambda entry: entry[0])
            if share > OVERLAP_WARNING_SHARE:
                a, b = config.objects[inner].name, config.objects[outer].name
                lines.append(f"objects '{a}' and '{b}' overlap: {100 * share:.0f}% of the particles "
                             f"of '{a}' lie inside '{b}' (objects should start apart or touching; "
                             "overlapping material is pushed apart violently)")
    return lines


def _material_rows(config: SceneConfig, index: int, parts: np.ndarray
                   ) -> dict[int, MaterialConfig]:
    obj = config.objects[index]
    by_part = {m.part: m for m in obj.materials}
    present = sorted(int(p) for p in np.unique(parts))
    for part in present:
        if part not in by_part:
            raise SceneError(f"objects[{index}].materials",
                             f"part {part} of object '{obj.name}' has no material entry "
                             f"(parts present: {', '.join(map(str, present))})")
    for j, mat in enumerate(obj.materials):
        if mat.part not in present:
            raise SceneError(f"objects[{index}].materials[{j}].part",
                             f"object '{obj.name}' has no part {mat.part} "
                             f"(parts present: {', '.join(map(str, present))})")
    return by_part


def build_scene(config: SceneConfig, device: torch.device | None = None) -> BuiltScene:
    """Sample / load every object, check it, and assemble the ParticleSet and materials."""
    device = device if device is not None else torch.device("cpu")
    columns: dict[str, list[np.ndarray]] = {k: [] for k in (
        "x", "v", "mass", "rest_volume", "obj_id", "part_id", "material_id", "is_surface",
        "gaussian_index")}
    materials: list[Any] = []
    keys: list[tuple[int, int]] = []
    objects = [object_particles(config, index) for index in range(len(config.objects))]
    for index, (obj, parts) in enumerate(zip(config.objects, objects)):
        check_inside_domain(config, index, parts.x)
        by_part = _material_rows(config, index, parts.part_id)
        n = parts.x.shape[0]
        material_id = np.empty(n, dtype=np.int32)
        mass = np.empty(n, dtype=np.float64)
        for part, mat in sorted(by_part.items()):
            row = len(materials)
            materials.append(mat.material)
            keys.append((index, part))
            mask = parts.part_id == part
            material_id[mask] = row
            mass[mask] = mat.density * parts.rest_volume[mask]
        columns["x"].append(parts.x)
        columns["v"].append(initial_velocities(obj, parts.x, mass))
        columns["mass"].append(mass)
        columns["rest_volume"].append(parts.rest_volume)
        columns["obj_id"].append(np.full(n, index, dtype=np.int32))
        columns["part_id"].append(parts.part_id)
        columns["material_id"].append(material_id)
        columns["is_surface"].append(parts.is_surface)
        columns["gaussian_index"].append(parts.gaussian_index)
    dtypes = {"x": torch.float32, "v": torch.float32, "mass": torch.float32,
              "rest_volume": torch.float32, "obj_id": torch.int32, "part_id": torch.int32,
              "material_id": torch.int32, "is_surface": torch.bool,
              "gaussian_index": torch.int64}
    tensors = {k: torch.as_tensor(np.concatenate(v)).to(device=device, dtype=dtypes[k])
               for k, v in columns.items()}
    particles = ParticleSet(**tensors)
    domain = config.domain
    # Objects stay contiguous; inside each, particles of one grid block sit together (faster
    # transfers). gaussian_index keeps the link to the trained Gaussians.
    particles = particles.take(spatial_order(particles.x, particles.obj_id, domain))
    return BuiltScene(particles=particles, materials=materials,
                      material_keys=keys, object_names=[o.name for o in config.objects],
                      domain=domain,
                      contact=config.contact,
                      boundaries=list(config.boundaries), gravity=config.gravity,
                      cfl=config.cfl, seed=config.seed,
                      rigid_objects=tuple(i for i, o in enumerate(config.objects) if o.rigid),
                      warnings=tuple(overlap_warnings(config, objects) + density_warnings(
                          config.objects, [parts.x for parts in objects], config.domain)))
