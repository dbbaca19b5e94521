"""Rasterizer speed: forward and forward+backward ms per image, C++ vs the torch reference.

Scene: N Gaussians evenly spread over a unit sphere's surface (Fibonacci lattice),
isotropic scale 1.5 × their mean spacing, opacity 0.8, SH degree 3, seen from 3 units away
at 512×512 with a 60° field of view. Runs 100k and 1M Gaussians (``--skip-1m`` to skip the
latter) with the compiled backend, and the dense reference at a size it can handle
(``--reference-num`` Gaussians at ``--reference-size``², with the compiled backend on the same
scene for comparison). Prints one JSON object.

Usage: PYTHONPATH=. python benchmarks/bench_raster.py [--skip-1m] [--repeats 5] [--device cpu|cuda]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time

import torch

from fracture_gs._backend import compiled_module
from fracture_gs.render import Camera, rasterize


def sphere_scene(num: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """Gaussians on a Fibonacci lattice of the unit sphere with random degree-3 SH."""
    index = torch.arange(num, dtype=torch.float64) + 0.5
    polar = torch.acos(1.0 - 2.0 * index / num)
    azimuth = math.pi * (1.0 + 5.0 ** 0.5) * index
    means = torch.stack([torch.cos(azimuth) * torch.sin(polar), torch.sin(azimuth) * torch.sin(polar),
                         torch.cos(polar)], -1).float()
    spacing = math.sqrt(4.0 * math.pi / num)
    gen = torch.Generator().manual_seed(seed)
    sh = 0.1 * torch.randn(num, 16, 3, generator=gen)
    sh[:, 0] = torch.rand(num, 3, generator=gen) * 1.5 - 0.5
    quats = torch.zeros(num, 4)
    quats[:, 0] = 1.0
    return {"means": means, "opacities": torch.full((num,), 0.8),
            "scales": torch.full((num, 3), 1.5 * spacing), "quats": quats, "sh": sh}


def sphere_camera(size: int) -> Camera:
    return Camera.look_at((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), math.radians(60.0),
                          size, size)


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _time_ms(fn, repeats: int, device: torch.device) -> tuple[float, float]:
    """Median wall-clock ms and median process CPU ms (all threads) of fn() (finished on the device)."""
    fn()  # warm-up
    _synchronize(device)
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        _synchronize(device)
        wall.append((time.perf_counter() - start) * 1e3)
        cpu.append((time.process_time() - start_cpu) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def measure(scene: dict[str, torch.Tensor], camera: Camera, backend: str, repeats: int) -> dict:
    """Median forward and forward+backward ms; gradients for means, scales, quats, opacities, sh."""
    def forward() -> None:
        with torch.no_grad():
            rasterize(scene["means"], scene["opacities"], camera, scales=scene["scales"],
                      quats=scene["quats"], sh=scene["sh"], backend=backend)

    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}

    def forward_backward() -> None:
        out = rasterize(leaves["means"], leaves["opacities"], camera, scales=leaves["scales"],
                        quats=leaves["quats"], sh=leaves["sh"], backend=backend)
        (out["rgb"].sum() + out["depth"].sum()).backward()

    with torch.no_grad():
        out = rasterize(scene["means"], scene["opacities"], camera, scales=scene["scales"],
                        quats=scene["quats"], sh=scene["sh"], backend=backend)
    device = scene["means"].device
    forward_ms, forward_cpu_ms = _time_ms(forward, repeats, device)
    both_ms, both_cpu_ms = _time_ms(forward_backward, repeats, device)
    # cpu_ms: CPU time summed over threads; on a shared, loaded machine it is the steadier
    # figure (wall / cpu shows how much of the cores the process actually got).
    return {"forward_ms": round(forward_ms, 2), "forward_backward_ms": round(both_ms, 2),
            "forward_cpu_ms": round(forward_cpu_ms, 2),
            "forward_backward_cpu_ms": round(both_cpu_ms, 2),
            "visible": int((out["radii"] > 0).sum()),
            "coverage": round(float(out["alpha"].mean()), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-1m", action="store_true", help="skip the 1M-Gaussian run")
    parser.add_argument("--reference-num", type=int, default=1000)
    parser.add_argument("--reference-size", type=int, default=64)
    parser.add_argument("--device", default="cpu", help="cpu or cuda: where the scene lives and the kernels run")
    args = parser.parse_args()
    if compiled_module() is None:
        raise SystemExit("bench_raster: fracture_gs._C is not built")
    device = torch.device(args.device)

    def on_device(scene: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return {k: v.to(device) for k, v in scene.items()}

    result = {"device": str(device), "threads": compiled_module().openmp_max_threads(), "cpu_count": os.cpu_count(),
              "load_average_1min": round(os.getloadavg()[0], 2), "image": [args.size, args.size],
              "cpp": {}}
    counts = [100_000] if args.skip_1m else [100_000, 1_000_000]
    for num in counts:
        result["cpp"][str(num)] = measure(on_device(sphere_scene(num)), sphere_camera(args.size), "cpp",
                                          args.repeats)
    small_scene, small_camera = on_device(sphere_scene(args.reference_num)), sphere_camera(args.reference_size)
    result["reference_size"] = {"num": args.reference_num,
                                "image": [args.reference_size, args.reference_size],
                                "reference": measure(small_scene, small_camera, "reference", 2),
                                "cpp": measure(small_scene, small_camera, "cpp", args.repeats)}
    result["load_average_1min_after"] = round(os.getloadavg()[0], 2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
