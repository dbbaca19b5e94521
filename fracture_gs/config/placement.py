"""An object's ``placement`` in a scene (docs/scenes.md): size and orientation in the world,
resolved into the ``transform`` (scale, rotation, translation) that puts it there.

A trained object lies in its dataset's coordinates, which are seldom z-up and never in metres.
``placement`` states what the scene wants instead::

    placement: {size: 0.3, up: model, yaw_deg: 0, centre: [0.5, 0.5], bottom: ground}

The rotation turns the object's up direction (``up: model``: the one ``train.py`` recorded in
the model's ``object.json``; or a direction in model coordinates) onto +z by the smallest
rotation, then about +z so that the longest horizontal principal axis of the particles lies
along +x, then by ``yaw_deg`` about +z. The scale makes the longest side of the rotated
object's box ``size`` metres (or its extent along z ``height`` metres; neither keeps the model's
units). The translation puts the box's centre at ``centre`` (x, y) and the lowest particle at
``bottom`` (``ground``: the height of the scene's ground boundary, the default when it has one).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from fracture_gs.io.model_layout import OBJECT_FILE, PARTICLES_FILE
from fracture_gs.io.object_frame import read_object_frame
from fracture_gs.io.particles_ply import ParticlesPlyError, read_particles_ply
from fracture_gs.keys import SceneError, check_keys, check_number, join, mapping, number, vec3

PLACEMENT_KEYS = ("size", "height", "up", "yaw_deg", "centre", "bottom")
# Lowest particle this far above the stated bottom, so that rounding in the transform never puts
# it below the ground (metres).
CLEARANCE = 1e-7

Transform = tuple[float, tuple[float, float, float], tuple[float, float, float]]


def rotation_onto_z(up: np.ndarray) -> np.ndarray:
    """The smallest rotation that turns the unit vector ``up`` onto +z (a half turn about x
    when ``up`` is -z)."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sine, cosine = np.linalg.norm(axis), float(up[2])
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    return Rotation.from_rotvec(axis / sine * math.atan2(sine, cosine)).as_matrix()


def upright_rotation(points: np.ndarray, up: np.ndarray, yaw_deg: float) -> np.ndarray:
    """The rotation of the module docstring: ``up`` onto +z, the longest horizontal principal
    axis of ``points`` onto +x (the axis's sign: the one pointing toward +x after the first
    rotation), then ``yaw_deg`` about +z."""
    tilt = rotation_onto_z(up)
    upright = np.asarray(points, dtype=np.float64) @ tilt.T
    flat = upright[:, :2] - upright[:, :2].mean(axis=0)
    _, _, axes = np.linalg.svd(flat[:: max(1, len(flat) // 20000)], full_matrices=False)
    axis = axes[0]
    if axis[0] < 0 or (axis[0] == 0 and axis[1] < 0):
        axis = -axis
    heading = math.atan2(axis[1], axis[0])
    turn = Rotation.from_euler("z", math.radians(yaw_deg) - heading).as_matrix()
    return turn @ tilt


def place(points: np.ndarray, rotation: np.ndarray, centre: tuple[float, float], bottom: float,
          size: float | None = None, height: float | None = None) -> Transform:
    """(scale, rotate_deg, translate) that rotate ``points`` by ``rotation``, scale them to
    ``size`` (longest box side) or ``height`` (extent along z), and put their box centre at
    ``centre`` (x, y) and their lowest point at ``bottom`` (z)."""
    rotate_deg = tuple(float(a) for a in Rotation.from_matrix(rotation).as_euler("xyz", degrees=True))
    # the matrix the scene will build from rotate_deg, so that the bounds below are exact
    rotation = Rotation.from_euler("xyz", rotate_deg, degrees=True).as_matrix()
    rotated = np.asarray(points, dtype=np.float64) @ rotation.T
    lower, upper = rotated.min(axis=0), rotated.max(axis=0)
    extent = upper - lower
    scale = 1.0
    if size is not None or height is not None:
        span = float(extent.max()) if size is not None else float(extent[2])
        if not span > 0:
            raise ValueError("the object has no extent to scale (all particles in one point "
                             "or one plane)")
        scale = (size if size is not None else height) / span  # type: ignore[operator]
    middle = 0.5 * (lower + upper) * scale
    translate = (float(centre[0] - middle[0]), float(centre[1] - middle[1]),
                 float(bottom + CLEARANCE - scale * lower[2]))
    return scale, rotate_deg, translate  # type: ignore[return-value]


def _centre(data: Mapping[str, Any], key: str) -> tuple[float, float]:
    keypath = join(key, "centre")
    if "centre" not in data:
        raise SceneError(keypath, "required key is missing (the x and y of the object's centre)")
    value = data["centre"]
    if not isinstance(value, list) or len(value) != 2:
        raise SceneError(keypath, "expected a list of 2 numbers (x, y)")
    return check_number(value[0], f"{keypath}[0]"), check_number(value[1], f"{keypath}[1]")


def _bottom(data: Mapping[str, Any], key: str, ground: float | None) -> float:
    value = data.get("bottom", "ground")
    if value == "ground":
        if ground is None:
            raise SceneError(join(key, "bottom"), "'ground' needs a ground boundary; give the "
                             "height of the object's lowest point in metres")
        return ground
    return check_number(value, join(key, "bottom"))


def _up(data: Mapping[str, Any], key: str, model: Path) -> np.ndarray:
    value = data.get("up", "model")
    if value == "model":
        info = model / OBJECT_FILE if model.is_dir() else None
        if info is None or not info.is_file():
            raise SceneError(join(key, "up"), f"'model' needs the {OBJECT_FILE} train.py writes "
                             f"beside {PARTICLES_FILE}, and {model} has none; give the up "
                             f"direction in model coordinates, [x, y, z]")
        try:
            return np.asarray(read_object_frame(info).up)
        except ValueError as exc:
            raise SceneError(join(key, "up"), str(exc)) from None
    up = np.asarray(vec3(data, "up", key))
    if not np.linalg.norm(up) > 0:
        raise SceneError(join(key, "up"), "the up direction must not be [0, 0, 0]")
    return up


def _model_points(model: Path, key: str) -> np.ndarray:
    path = model / PARTICLES_FILE if model.is_dir() else model
    try:
        columns = read_particles_ply(path)
    except ParticlesPlyError as exc:
        raise SceneError(key, str(exc)) from None
    if not all(axis in columns for axis in "xyz") or len(columns["x"]) == 0:
        raise SceneError(key, f"'{path}' holds no particle positions")
    points = np.stack([np.asarray(columns[axis], dtype=np.float64) for axis in "xyz"], axis=1)
    if not np.isfinite(points).all():
        raise SceneError(key, f"'{path}' has non-finite particle positions")
    return points


def placement_transform(raw_object: Any, path: str, model: Path | None,
                        ground: float | None) -> Transform | None:
    """The transform of ``objects[i].placement`` (module docstring), or None for an object
    without one. ``raw_object`` is the object's YAML mapping, ``model`` its resolved model path,
    ``ground`` the height of the scene's ground boundary (None without one). Errors are
    SceneErrors naming the key."""
    if not isinstance(raw_object, Mapping) or "placement" not in raw_object:
        return None
    key = join(path, "placement")
    if "transform" in raw_object:
        raise SceneError(path, "give either 'transform' or 'placement', not both")
    if model is None:
        raise SceneError(key, "places a trained model; place a primitive with 'transform'")
    data = mapping(raw_object["placement"], key)
    check_keys(data, key, PLACEMENT_KEYS)
    if "size" in data and "height" in data:
        raise SceneError(key, "give 'size' (the longest side) or 'height', not both")
    size = number(data, "size", key, None, gt=0.0)
    height = number(data, "height", key, None, gt=0.0)
    yaw_deg = number(data, "yaw_deg", key, 0.0)
    centre = _centre(data, key)
    bottom = _bottom(data, key, ground)
    up = _up(data, key, model)
    points = _model_points(model, join(path, "model"))
    rotation = upright_rotation(points, up, yaw_deg)
    try:
        return place(points, rotation, centre, bottom, size=size, height=height)
    except ValueError as exc:
        raise SceneError(key, str(exc)) from None
