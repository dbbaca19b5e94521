"""Per-frame cost of rendering a simulation frame, with and without FPGO.

Scene: a solid ball of ``--particles`` particles (default 200k) on a cubic lattice;
the outer layer carries trained-looking Gaussians (isotropic, 0.7 × spacing, SH degree 3). Six
random crack bands flag ``--fractured`` (default half) of the particles as fractured; the pieces
between the cracks move apart by half a spacing and the fractured particles scatter by a further
0.3 spacing (see ``crack_pattern``); F_E is a random small strain. One frame is rendered at ``--size``² from ``--views``
orbit cameras; timings are medians over ``--repeats`` runs after a warm-up:

* ``frame_ms``: the Gaussians of the frame (deformation: F Σ F^T, polar rotation; plus FPGO),
* ``raster_ms``: rasterization, per view,
* ``total_ms`` = frame_ms + raster_ms (one view).

Usage: PYTHONPATH=. python benchmarks/bench_render.py [--particles 200000] [--size 800]
Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from fracture_gs._backend import compiled_module
from fracture_gs.cli.render import add_interior_options
from fracture_gs.config.scene import parse_scene
from fracture_gs.fracture.fpgo import EXCLUSIVE_RULES, FPGOSettings
from fracture_gs.gaussians import GaussianModel
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.folders.model_folder import write_model_folder
from fracture_gs.render.views import orbit_views
from fracture_gs.folders.sim_reader import SimFrame, SimParticles, Simulation


def sphere_particles(count: int) -> tuple[np.ndarray, np.ndarray, float]:
    """About ``count`` lattice points in the unit ball, the outer-layer flag and the spacing."""
    spacing = (4.0 / 3.0 * math.pi / count) ** (1.0 / 3.0)
    axis = np.arange(-1.0, 1.0 + 1e-9, spacing)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    radius = np.linalg.norm(grid, axis=1)
    inside = radius <= 1.0
    return grid[inside], radius[inside] > 1.0 - spacing, spacing


def crack_pattern(points: np.ndarray, spacing: float, share: float, rng: np.random.Generator,
                  planes: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Fractured flags and moved positions: bands around ``planes`` random planes through the
    ball, as wide as needed to flag ``share`` of the particles, open the ball into pieces; each
    piece (sign pattern of the planes) moves by 0.5 spacing along a random direction, and every
    fractured particle by a further random 0.3 spacing."""
    normals = rng.normal(size=(planes, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = rng.uniform(-0.5, 0.5, planes)
    signed = points @ normals.T - offsets                        # (N, planes)
    distance = np.abs(signed).min(axis=1)
    fractured = distance <= np.quantile(distance, share)
    piece = ((signed > 0) * (1 << np.arange(planes))).sum(axis=1)
    shift = rng.normal(size=(1 << planes, 3))
    shift *= 0.5 * spacing / np.linalg.norm(shift, axis=1, keepdims=True)
    moved = points + shift[piece]
    moved[fractured] += 0.3 * spacing * rng.standard_normal((int(fractured.sum()), 3))
    return fractured, moved


def build(count: int, fractured_share: float, folder: Path, seed: int = 0):
    rng = np.random.default_rng(seed)
    points, surface, spacing = sphere_particles(count)
    n, gaussians = points.shape[0], int(surface.sum())
    colours = torch.tensor(0.5 + 0.4 * points[surface], dtype=torch.float32).clamp(0, 1)
    model = GaussianModel.from_points(torch.tensor(points[surface], dtype=torch.float32), colours,
                                      sh_degree=3, isotropic=True, initial_opacity=0.9)
    with torch.no_grad():
        model.log_scales.fill_(math.log(0.7 * spacing))
        model.sh_rest.normal_(0.0, 0.05)
    gaussian_index = np.full(n, -1)
    gaussian_index[surface] = np.arange(gaussians)
    write_model_folder(folder / "model", points, np.full(n, spacing ** 3), surface, gaussian_index,
                       model, spacing=spacing)
    material = {"part": 0, "model": "elastic", "E": 1e5, "nu": 0.3, "density": 1000.0}
    scene = parse_scene({"name": "bench_render", "domain": {"min": [-2, -2, -2], "max": [2, 2, 2],
                                                            "grid": 64},
                         "objects": [{"name": "sphere", "model": str(folder / "model"),
                                      "materials": [material]}]})
    particles = SimParticles(rest_x=points.astype(np.float32), obj_id=np.zeros(n, np.int32),
                             is_surface=surface, gaussian_index=gaussian_index,
                             rest_volume=np.full(n, spacing ** 3, np.float32))
    sim = Simulation(folder, scene, particles, [0])
    fractured, moved = crack_pattern(points, spacing, fractured_share, rng)
    x = moved
    F = np.eye(3) + 0.02 * rng.standard_normal((n, 3, 3))
    frame = SimFrame(1, torch.tensor(x, dtype=torch.float32), torch.tensor(F, dtype=torch.float32),
                     torch.from_numpy(fractured))
    return sim, frame, spacing


def median_ms(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=200_000)
    parser.add_argument("--fractured", type=float, default=0.5)
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--exclusive", choices=EXCLUSIVE_RULES, default="group",
                        help="FPGO lens exclusive rule (render.py --exclusive)")
    add_interior_options(parser)
    args = parser.parse_args(argv)
    device = torch.device(args.device)
    with tempfile.TemporaryDirectory(prefix="bench_render_") as tmp:
        sim, frame, spacing = build(args.particles, args.fractured, Path(tmp))
        scene = SceneGaussians.from_simulation(sim, device, FPGOSettings(
            exclusive=args.exclusive, interior=args.interior, exposure=args.exposure))
    frame = frame.to(device)
    views = orbit_views(args.views, (0.0, 0.0, 0.0), 1.1, args.size, args.size)
    cameras = [view.camera.to(device) for view in views]
    background = torch.ones(3, device=device)

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    result: dict = {"particles": len(sim.particles), "fractured": int(frame.fractured.sum()),
                    "size": args.size, "views": args.views, "repeats": args.repeats,
                    "exclusive": args.exclusive, "interior": args.interior,
                    "exposure": args.exposure,
                    "device": str(device), "compiled": compiled_module() is not None,
                    "omp_threads": int(compiled_module().openmp_max_threads()) if compiled_module() else 0,
                    "torch_threads": torch.get_num_threads(), "cpu_count": os.cpu_count()}
    for label, fpgo in (("no_fpgo", False), ("fpgo", True)):
        gaussians = scene.frame(frame, fpgo=fpgo)

        def make() -> None:
            scene.frame(frame, fpgo=fpgo)
            sync()

        frame_ms = median_ms(make, args.repeats)
        raster = []
        for camera in cameras:
            def draw(camera=camera) -> None:
                gaussians.rasterize(camera, background)
                sync()
            raster.append(median_ms(draw, args.repeats))
        entry = {"gaussians": len(gaussians), "frame_ms": round(frame_ms, 2),
                 "raster_ms_per_view": [round(r, 2) for r in raster],
                 "raster_ms": round(statistics.mean(raster), 2),
                 "total_ms": round(frame_ms + statistics.mean(raster), 2)}
        if gaussians.stats is not None:
            stats = gaussians.stats
            entry.update(lens_gaussians=stats.lens_gaussians,
                         interior_gaussians=stats.interior_gaussians,
                         hidden_particles=stats.hidden_particles,
                         fpgo_detail_ms={k: round(v, 2) for k, v in stats.detail_ms.items()})
        result[label] = entry
    result["fpgo_overhead"] = round(result["fpgo"]["total_ms"] / result["no_fpgo"]["total_ms"] - 1.0, 3)
    json.dump(result, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
