"""Render a :class:`SyntheticObject` with Mitsuba 3 (``scalar_rgb``): RGBA, alpha = coverage.

Mitsuba's perspective sensor looks along its local +z with +x to the *left* and +y up (see
``ScalarTransform4f.look_at``), while an OpenGL camera looks along -z with +x right, +y up; the
two frames differ by a rotation of 180 degrees about y: ``to_world = c2w_gl @ diag(-1,1,-1,1)``.
The lights are fixed in the world, so all views see one static scene.
"""
from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from fracture_gs.data.synthetic.objects import SyntheticObject

OPENGL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


class MitsubaUnavailable(RuntimeError):
    """Mitsuba 3 is not installed."""


def require_mitsuba() -> ModuleType:
    """Import Mitsuba 3 with the ``scalar_rgb`` variant, or raise a one-line error."""
    try:
        import mitsuba
    except ImportError:
        raise MitsubaUnavailable("rendering needs Mitsuba 3: pip install mitsuba==3.9.1") from None
    mitsuba.set_variant("scalar_rgb")
    return mitsuba


def mitsuba_to_world(camera_to_world_gl: np.ndarray) -> np.ndarray:
    """Sensor ``to_world`` matrix for an OpenGL camera-to-world matrix."""
    return np.asarray(camera_to_world_gl, dtype=np.float64) @ OPENGL_TO_MITSUBA


def _mesh(mi: ModuleType, name: str, vertices: np.ndarray, faces: np.ndarray,
          normals: np.ndarray, colors: np.ndarray, bsdf: Any) -> Any:
    props = mi.Properties()
    props["bsdf"] = bsdf
    mesh = mi.Mesh(name, len(vertices), len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(vertices, dtype=np.float32).ravel()
    params["faces"] = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    params["vertex_normals"] = np.ascontiguousarray(normals, dtype=np.float32).ravel()
    params.update()
    mesh.add_attribute("vertex_color", 3,
                       np.ascontiguousarray(colors, dtype=np.float32).ravel())
    return mesh


def build_scene(obj: SyntheticObject, max_depth: int = 4) -> Any:
    """Mitsuba scene: the object's parts (principled BSDF, vertex colours), a dim uniform sky
    (hidden from the camera) and two directional lights (key from above, fill from the side)."""
    mi = require_mitsuba()
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth, "hide_emitters": True},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.45}},
        "key": {"type": "directional", "direction": [-0.45, 0.35, -1.0],
                "irradiance": {"type": "rgb", "value": 2.6}},
        "fill": {"type": "directional", "direction": [0.7, -0.6, -0.25],
                 "irradiance": {"type": "rgb", "value": 0.7}},
    }
    for piece in obj.pieces():
        bsdf = mi.load_dict({"type": "principled",
                             "base_color": {"type": "mesh_attribute", "name": "vertex_color"},
                             "roughness": piece.look.roughness,
                             "specular": piece.look.specular})
        scene[f"part{piece.part}"] = _mesh(mi, f"{obj.name}_part{piece.part}", piece.vertices,
                                           piece.faces, piece.normals, piece.colors, bsdf)
    return mi.load_dict(scene)


def render_view(scene: Any, camera_to_world_gl: np.ndarray, fov_x: float, width: int,
                height: int, spp: int, seed: int = 0) -> np.ndarray:
    """Render one view: (H, W, 4) float32, linear RGB premultiplied by alpha (coverage)."""
    mi = require_mitsuba()
    sensor = mi.load_dict({
        "type": "perspective",
        "fov": float(np.degrees(fov_x)),
        "fov_axis": "x",
        "near_clip": 0.01,
        "far_clip": 100.0,
        "to_world": mi.ScalarTransform4f(mitsuba_to_world(camera_to_world_gl).tolist()),
        "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgba",
                 "rfilter": {"type": "box"}},
        # Stratified (multi-jittered) samples: far less noise than independent ones at the
        # same count; spp is rounded up to a product of two integers by Mitsuba.
        "sampler": {"type": "multijitter", "sample_count": spp, "seed": seed},
    })
    image = mi.render(scene, sensor=sensor, spp=spp, seed=seed)
    return np.array(image, dtype=np.float32).reshape(height, width, 4)
