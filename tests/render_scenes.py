"""Tiny simulation folders and model folders for the render / FPGO tests.

``write_model`` writes a train.py-style model folder (``particles.ply`` + ``point_cloud/
iteration_N/point_cloud.ply`` + ``particles.json``); ``write_sim`` writes a simulate.py-style
output folder with prescribed frames, so that what the renderer must draw is known exactly.
"""
from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from fracture_gs.pipeline.simulate import run_simulation
from fracture_gs.config.scene import parse_scene
from fracture_gs.gaussians import GaussianModel
from fracture_gs.folders.model_folder import write_model_folder

SPACING = 0.02


def lattice_block(half: tuple[float, float, float], spacing: float = SPACING
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Particles on a cubic lattice filling the box [-half, half] and the outer-layer flag."""
    axes = [np.arange(-h, h + 1e-9, spacing) for h in half]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    index = np.stack(np.meshgrid(*[np.arange(a.size) for a in axes], indexing="ij"), -1).reshape(-1, 3)
    counts = np.array([a.size for a in axes])
    surface = ((index == 0) | (index == counts - 1)).any(axis=1)
    return points, surface


def write_model(folder: Path, points: np.ndarray, surface: np.ndarray, *,
                spacing: float = SPACING, sh_degree: int = 1, iteration: int = 30,
                opacity: float = 0.9, scale_factor: float = 0.7, seed: int = 0,
                write_spacing: bool = True, part_id: np.ndarray | None = None) -> GaussianModel:
    """A model folder whose surface particles each own one isotropic Gaussian at their position
    (colour varying with position, random higher SH bands). Returns the Gaussians."""
    rng = np.random.default_rng(seed)
    surface_points = points[surface]
    lower, upper = points.min(0), points.max(0)
    colours = 0.15 + 0.7 * (surface_points - lower) / np.maximum(upper - lower, 1e-9)
    model = GaussianModel.from_points(torch.tensor(surface_points, dtype=torch.float32),
                                      torch.tensor(colours, dtype=torch.float32),
                                      sh_degree=sh_degree, isotropic=True, initial_opacity=opacity)
    with torch.no_grad():
        model.log_scales.fill_(float(np.log(scale_factor * spacing)))
        model.sh_rest.copy_(torch.tensor(rng.normal(0, 0.15, model.sh_rest.shape),
                                         dtype=torch.float32))
    gaussian_index = np.full(points.shape[0], -1, dtype=np.int64)
    gaussian_index[np.nonzero(surface)[0]] = np.arange(surface_points.shape[0])
    write_model_folder(folder, points, np.full(points.shape[0], spacing ** 3), surface,
                       gaussian_index, model, spacing=spacing if write_spacing else None,
                       iteration=iteration, part_id=part_id)
    return model


def write_sim(root: Path, scene: dict[str, Any], particles: dict[str, np.ndarray],
              frames: list[dict[str, np.ndarray]]) -> Path:
    """A simulate.py output folder: scene.yaml, particles.npz and frames/frame_XXXXX.npz."""
    (root / "frames").mkdir(parents=True, exist_ok=True)
    (root / "scene.yaml").write_text(yaml.safe_dump(scene, sort_keys=False))
    count = particles["rest_x"].shape[0]
    defaults = {"mass": np.ones(count, np.float32), "part_id": np.zeros(count, np.int32),
                "material_id": np.zeros(count, np.int32)}
    np.savez(root / "particles.npz", **{**defaults, **particles})
    for index, frame in enumerate(frames):
        full = {"v": np.zeros((count, 3), np.float32), "alpha": np.zeros(count, np.float32),
                **frame}
        np.savez(root / "frames" / f"frame_{index:05d}.npz", **full)
    return root


def block_scene(model: Path | None, transform: dict[str, Any] | None = None,
                name: str = "block") -> dict[str, Any]:
    """Scene with one object (a trained model folder, or a primitive box when None)."""
    obj: dict[str, Any] = {"name": name, "velocity": [0, 0, 0],
                           "materials": [{"part": 0, "model": "elastic", "E": 1e4, "nu": 0.3,
                                          "density": 1}]}
    if model is not None:
        obj["model"] = str(model)
    else:
        obj["primitive"] = {"shape": "box", "size": [0.2, 0.2, 0.2], "particles_per_cell": 8}
    if transform is not None:
        obj["transform"] = transform
    return {"name": "render_test", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 32},
            "frames": 2, "frame_dt": 0.01, "gravity": [0, 0, -9.8],
            "boundaries": [{"type": "box", "condition": "slip"}], "objects": [obj]}


def identity_frames(rest_x: np.ndarray, count: int) -> list[dict[str, np.ndarray]]:
    n = rest_x.shape[0]
    return [{"x": rest_x.astype(np.float32), "F_E": np.tile(np.eye(3, dtype=np.float32), (n, 1, 1)),
             "fractured": np.zeros(n, bool)} for _ in range(count)]


def simulate_quietly(out: Path, scene: dict[str, Any]) -> Path:
    """Run the real solver on ``scene`` into ``out`` on the CPU, without progress output."""
    run_simulation(parse_scene(scene), out, device=torch.device("cpu"), progress=False,
                   log=io.StringIO())
    return out
