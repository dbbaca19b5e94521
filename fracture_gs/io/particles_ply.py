"""``particles.ply``: the particles of a trained object, written by train.py and read
by simulate.py.

One ``vertex`` element, binary little-endian: ``x y z volume`` (float32), ``is_surface``
(uint8), ``part_id`` and ``gaussian_index`` (int32; the row of the Gaussian a surface particle
carries in ``point_cloud.ply``, -1 for none). Header comments ``comment <key> <value>`` carry
numbers such as the particle spacing.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping

import numpy as np
import plyfile

from fracture_gs.io.atomic import atomic_write

PARTICLE_PROPERTIES = (("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("volume", "<f4"),
                       ("is_surface", "u1"), ("part_id", "<i4"), ("gaussian_index", "<i4"))


class ParticlesPlyError(ValueError):
    """A file that cannot be read as a particles.ply; the message names it."""


def write_particles_ply(path: str | os.PathLike, position: np.ndarray, volume: np.ndarray,
                        is_surface: np.ndarray, part_id: np.ndarray | int,
                        gaussian_index: np.ndarray,
                        comments: Mapping[str, float] | None = None) -> None:
    """Write a particles.ply atomically; ``comments`` become ``comment key value`` lines."""
    vertices = np.empty(len(position), dtype=list(PARTICLE_PROPERTIES))
    for axis, name in enumerate("xyz"):
        vertices[name] = np.asarray(position)[:, axis]
    vertices["volume"] = volume
    vertices["is_surface"] = np.asarray(is_surface).astype(np.uint8)
    vertices["part_id"] = part_id
    vertices["gaussian_index"] = gaussian_index
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")], byte_order="<",
                          comments=[f"{key} {value!r}" for key, value in (comments or {}).items()])
    atomic_write(path, ply.write)


def read_particles_ply(path: str | os.PathLike) -> dict:
    """The columns of a particles.ply (its ``vertex`` element, else its first), by property
    name, plus its numeric header comments under ``"comments"`` (a dict). ParticlesPlyError
    when the file cannot be read or holds no element."""
    try:
        ply = plyfile.PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for malformed files
        raise ParticlesPlyError(f"cannot read particles from '{path}': {exc}") from None
    if not ply.elements:
        raise ParticlesPlyError(f"'{path}' has no elements")
    element = ply["vertex"] if "vertex" in [e.name for e in ply.elements] else ply.elements[0]
    data = element.data
    columns: dict = {name: np.asarray(data[name]) for name in data.dtype.names}
    comments = {}
    for line in ply.comments:
        key, _, value = line.partition(" ")
        with contextlib.suppress(ValueError):
            comments[key] = float(value)
    columns["comments"] = comments
    return columns
