#!/usr/bin/env python3
"""Speed of train.py's two iterative stages, printed as JSON.

* Gaussian stage: iterations per second of one fitting step (render at 400x400, L1 + SSIM
  loss, backward, Adam, offset projection) with the default 40,000 isotropic Gaussians.
* SDF refinement: seconds per NeuS-style refinement iteration (1024 rays in 8x8 patches,
  pre-pass + 40 differentiable samples, patch-NCC photo-consistency, mask, eikonal and
  Laplacian terms, Adam) at the coarse and the fine level of train.py's default grid
  (``--sdf-res``, 160 cells along the longest side).

By default the scene is synthetic (a textured sphere rendered with the project's rasterizer
into 24 views, so no dataset is needed); ``--source data/teapot`` times a real dataset.
Wall and process CPU seconds are both reported (the CPU time is what the process itself
used, which matters on a shared machine).

    python benchmarks/bench_train.py [--source DIR] [--gaussians 40000] [--steps 20]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_gs.data import Dataset, load_dataset  # noqa: E402
from fracture_gs.recon.gaussian_fit import FitSettings, fit_gaussians, new_fit_state  # noqa: E402
from fracture_gs.recon.hull import visual_hull  # noqa: E402
from fracture_gs.recon.pipeline import TrainConfig  # noqa: E402
from fracture_gs.recon.sdf_refine import RefineSettings, refine_sdf  # noqa: E402
from fracture_gs.render import Camera, rasterize  # noqa: E402


def fibonacci_sphere(count: int, radius: float = 1.0) -> np.ndarray:
    index = np.arange(count) + 0.5
    z = 1 - 2 * index / count
    azimuth = math.pi * (3 - math.sqrt(5)) * index
    ring = np.sqrt(1 - z * z)
    return radius * np.stack([ring * np.cos(azimuth), ring * np.sin(azimuth), z], axis=1)


def synthetic_dataset(views: int, size: int, seed: int = 0) -> Dataset:
    """A sphere with a random colour pattern seen from ``views`` cameras on a sphere."""
    points = torch.from_numpy(fibonacci_sphere(60_000, 0.8)).float()
    generator = torch.Generator().manual_seed(seed)
    colors = (0.5 + 0.4 * torch.sin(7 * points @ torch.randn(3, 3, generator=generator))).clamp(0, 1)
    scales = torch.full((len(points), 3), 0.008)
    quats = torch.tensor([[1.0, 0, 0, 0]]).repeat(len(points), 1)
    cameras, images, masks = [], [], []
    for direction in fibonacci_sphere(views, 4.0):
        camera = Camera.look_at(direction, (0, 0, 0), (0, 0, 1), 0.69, size, size)
        with torch.no_grad():
            out = rasterize(points, torch.full((len(points),), 0.95), camera, scales=scales,
                            quats=quats, colors=colors)
        cameras.append(camera)
        images.append(out["rgb"].clamp(0, 1))
        masks.append(out["alpha"].clamp(0, 1))
    return Dataset(cameras, torch.stack(images), torch.stack(masks),
                   [f"view{i}.png" for i in range(views)], "blender")


def timed(function) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def bench_gaussians(dataset: Dataset, count: int, steps: int) -> dict:
    surface = fibonacci_sphere(count, 0.8)
    settings = FitSettings(iterations=2)
    state = new_fit_state(surface, None, settings, 4.4, torch.device("cpu"))
    spacing = math.sqrt(4 * math.pi * 0.64 / count)
    rng = np.random.default_rng(0)
    fit_gaussians(state, dataset, settings, spacing, rng)            # warm-up
    settings = FitSettings(iterations=2 + steps)
    wall, cpu = timed(lambda: fit_gaussians(state, dataset, settings, spacing, rng))
    return {"gaussians": count, "image": f"{dataset.width}x{dataset.height}", "steps": steps,
            "iterations_per_s": steps / wall, "ms_per_iteration_wall": 1000 * wall / steps,
            "ms_per_iteration_cpu": 1000 * cpu / steps}


def bench_refinement(dataset: Dataset, steps: int, sdf_res: int) -> dict:
    hull = visual_hull(dataset, sdf_res, torch.device("cpu"))
    result = {}
    for level, fraction in (("coarse", 1.0), ("fine", 0.0)):
        marks: list[tuple[float, float]] = []
        settings = RefineSettings(iterations=steps + 3, coarse_fraction=fraction)
        refine_sdf(dataset, hull.grid, hull.sdf, settings, torch.device("cpu"),
                   lambda row: marks.append((time.perf_counter(), time.process_time())))
        wall = [b[0] - a[0] for a, b in zip(marks[2:], marks[3:])]
        cpu = [b[1] - a[1] for a, b in zip(marks[2:], marks[3:])]
        result[level] = {"s_per_iteration_wall": float(np.median(wall)),
                         "s_per_iteration_cpu": float(np.median(cpu)), "steps": len(wall)}
    result["grid"] = list(hull.grid.shape)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", default=None, help="dataset folder (default: synthetic)")
    parser.add_argument("--gaussians", type=int, default=40_000)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--sdf-res", type=int, default=TrainConfig.sdf_res,
                        help="SDF grid cells along the longest side (default: train.py's)")
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.sdf_res < 8:
        parser.error(f"--sdf-res must be >= 8 (as for train.py), got {args.sdf_res}")
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.source:
        dataset = load_dataset(args.source, "train")
    else:
        dataset = synthetic_dataset(24, 400)
    report = {"threads": torch.get_num_threads(),
              "scene": args.source or "synthetic sphere, 24 views",
              "gaussian_stage": bench_gaussians(dataset, args.gaussians, args.steps),
              "sdf_refinement": bench_refinement(dataset, args.steps, args.sdf_res)}
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
