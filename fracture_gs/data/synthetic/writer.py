"""Writing a generated dataset: RGBA PNGs, transforms JSON files, the ground-truth mesh.

A write that fails (a full disk) raises an ``OSError`` naming its file."""
from __future__ import annotations

import json
import os

import numpy as np
import trimesh
from PIL import Image

from fracture_gs.data.synthetic.textures import linear_to_srgb
from fracture_gs.io.output_folder import naming_file


def rgba8_from_premultiplied(image: np.ndarray) -> np.ndarray:
    """(H,W,4) linear premultiplied float -> (H,W,4) uint8 sRGB with straight alpha (what
    PNG stores). Background pixels (alpha 0) are white, so compositing on white or ignoring
    alpha both give a white background."""
    alpha = np.clip(image[..., 3], 0.0, 1.0)
    straight = image[..., :3] / np.maximum(alpha, 1e-6)[..., None]
    straight = np.where(alpha[..., None] > 0.0, straight, 1.0)
    srgb = linear_to_srgb(straight)
    rgba = np.concatenate([srgb, alpha[..., None]], axis=-1)
    return np.round(rgba * 255.0).astype(np.uint8)


def write_png(path: str, rgba8: np.ndarray) -> None:
    with naming_file(path):
        Image.fromarray(rgba8, mode="RGBA").save(path, optimize=False)


def write_transforms(path: str, camera_angle_x: float, file_paths: list[str],
                     camera_to_worlds: list[np.ndarray]) -> None:
    """NeRF-synthetic ``transforms_*.json`` (camera-to-world, OpenGL axes)."""
    frames = [{"file_path": file_path, "transform_matrix": np.asarray(c2w).tolist()}
              for file_path, c2w in zip(file_paths, camera_to_worlds)]
    with naming_file(path), open(path, "w", encoding="utf-8") as handle:
        json.dump({"camera_angle_x": camera_angle_x, "frames": frames}, handle, indent=2)
        handle.write("\n")


def write_mesh(path: str, mesh: trimesh.Trimesh, colors_srgb8: np.ndarray | None = None) -> None:
    """Binary PLY of the mesh (optionally with per-vertex RGBA uint8 colours)."""
    out = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    if colors_srgb8 is not None:
        out.visual.vertex_colors = colors_srgb8
    with naming_file(path), open(path, "wb") as handle:
        handle.write(trimesh.exchange.ply.export_ply(out, encoding="binary",
                                                     include_attributes=False))


def write_json(path: str, content: dict) -> None:
    with naming_file(path), open(path, "w", encoding="utf-8") as handle:
        json.dump(content, handle, indent=2)
        handle.write("\n")


def ensure_dir(path: str) -> str:
    os.makedirs(path, exist_ok=True)
    return path
