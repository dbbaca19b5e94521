"""What FPGO adds to the per-frame render time of a simulation.

For every frame from the fracture onset on (docs/formulas.md §14), the frame's Gaussians are built and drawn
from ``--views`` orbit cameras at ``--size``² without FPGO and with FPGO, the two runs
interleaved frame by frame (and their order alternated) so that a machine whose load drifts
disturbs both alike. Per frame: the Gaussians (deformation, plus FPGO), the rasterization of
all views, and their sum — what ``render.py`` reports as ms per frame, without PNG / video
writing. Prints one JSON object: per-frame rows and the medians / means over the frames.

Usage: PYTHONPATH=. python benchmarks/fpgo_cost.py --sim output/sims/<name> [--views 4]
           [--size 800] [--repeats 1] [--frames a:b] [--step 1]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import torch

from fracture_gs.cli.render import add_interior_options
from fracture_gs.pipeline.views import resolve_views
from fracture_gs.fracture.fpgo import EXCLUSIVE_RULES, FPGOSettings
from fracture_gs.metrics.onset import fracture_window_from_simulation
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.folders.sim_reader import Simulation


def median_sizes(gaussians) -> dict[str, float]:
    """Median size det(Σ)^(1/6) (m) of the trained / flat Gaussians and of FPGO's interior and
    lens Gaussians of a frame (0 where there are none)."""
    size = torch.linalg.det(gaussians.covariances.double()).clamp_min(0.0) ** (1.0 / 6.0)
    lens = gaussians.exclusive >= 0
    parts = {"base": ~gaussians.is_fpgo, "interior": gaussians.is_fpgo & ~lens, "lens": lens}
    return {name: float(size[mask].median()) if bool(mask.any()) else 0.0
            for name, mask in parts.items()}


def timed_frame(scene: SceneGaussians, frame, cameras, background: torch.Tensor,
                fpgo: bool) -> dict[str, float]:
    """Milliseconds of one frame: Gaussians (incl. FPGO), raster of every camera, FPGO alone."""
    tick = time.perf_counter()
    gaussians = scene.frame(frame, fpgo=fpgo)
    gaussians_ms = (time.perf_counter() - tick) * 1e3
    tick = time.perf_counter()
    for camera in cameras:
        gaussians.rasterize(camera, background)
    raster_ms = (time.perf_counter() - tick) * 1e3
    return {"gaussians_ms": gaussians_ms, "raster_ms": raster_ms,
            "total_ms": gaussians_ms + raster_ms, "count": len(gaussians),
            "fpgo_ms": gaussians.stats.milliseconds if gaussians.stats is not None else 0.0,
            "detail_ms": dict(gaussians.stats.detail_ms) if gaussians.stats is not None else {},
            "lenses": gaussians.stats.lens_gaussians if gaussians.stats is not None else 0,
            "interior": gaussians.stats.interior_gaussians if gaussians.stats is not None else 0,
            "buried": gaussians.stats.buried_particles if gaussians.stats is not None else 0}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", type=Path, required=True)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--repeats", type=int, default=1, help="timed runs per frame and mode")
    parser.add_argument("--frames", default=None,
                        help="a:b (b excluded); default: from the fracture onset on")
    parser.add_argument("--step", type=int, default=1, help="every step-th of those frames")
    parser.add_argument("--exclusive", choices=EXCLUSIVE_RULES, default="group",
                        help="FPGO lens exclusive rule (render.py --exclusive)")
    add_interior_options(parser)
    args = parser.parse_args(argv)
    sim = Simulation.open(args.sim)
    onset = fracture_window_from_simulation(sim.root).onset_frame
    if args.frames is not None:
        frames = sim.select_frames(args.frames)
    elif onset is not None:
        frames = [f for f in sim.frames if f >= onset]
    else:
        frames = list(sim.frames)
    frames = frames[::max(args.step, 1)]
    tick = time.perf_counter()
    scene = SceneGaussians.from_simulation(sim, settings=FPGOSettings(
        exclusive=args.exclusive, interior=args.interior, exposure=args.exposure))
    bind_s = time.perf_counter() - tick
    cameras = [v.camera for v in resolve_views(f"orbit:{args.views}", sim, sim.frames,
                                               (args.size, args.size))]
    background = torch.ones(3)
    timed_frame(scene, sim.load_frame(frames[0]), cameras, background, True)   # warm-up
    rows = []
    for position, index in enumerate(frames):
        frame = sim.load_frame(index)
        runs: dict[bool, list[dict[str, float]]] = {True: [], False: []}
        for repeat in range(args.repeats):
            order = (False, True) if (position + repeat) % 2 == 0 else (True, False)
            for fpgo in order:
                runs[fpgo].append(timed_frame(scene, frame, cameras, background, fpgo))
        best = {fpgo: min(r, key=lambda run: run["total_ms"]) for fpgo, r in runs.items()}
        row = {"frame": index, "fractured": int(frame.fractured.sum()),
               "gaussians_no_fpgo": best[False]["count"], "gaussians_fpgo": best[True]["count"],
               "no_fpgo_ms": round(best[False]["total_ms"], 1),
               "fpgo_ms": round(best[True]["total_ms"], 1),
               "fpgo_pass_ms": round(best[True]["fpgo_ms"], 1),
               "raster_no_fpgo_ms": round(best[False]["raster_ms"], 1),
               "raster_fpgo_ms": round(best[True]["raster_ms"], 1),
               "fpgo_detail_ms": {k: round(v, 1) for k, v in best[True]["detail_ms"].items()},
               "lens_gaussians": best[True]["lenses"], "interior_gaussians": best[True]["interior"],
               "buried_particles": best[True]["buried"]}
        row["added"] = round(row["fpgo_ms"] / row["no_fpgo_ms"] - 1.0, 3)
        rows.append(row)
        print(f"frame {index}: {row['no_fpgo_ms']:.0f} ms without FPGO, {row['fpgo_ms']:.0f} ms "
              f"with ({100 * row['added']:+.0f} %)", file=sys.stderr)

    def summary(key: str) -> dict[str, float]:
        values = [r[key] for r in rows]
        return {"median": round(statistics.median(values), 3), "mean": round(statistics.fmean(values), 3)}

    no_fpgo, fpgo = summary("no_fpgo_ms"), summary("fpgo_ms")
    result = {"sim": str(args.sim), "particles": len(sim.particles), "onset": onset,
              "frames": len(rows), "views": args.views, "size": args.size, "exclusive": args.exclusive,
              "interior": args.interior, "exposure": args.exposure,
              "repeats": args.repeats, "bind_seconds": round(bind_s, 2),
              "omp_threads": os.environ.get("OMP_NUM_THREADS"),
              "torch_threads": torch.get_num_threads(), "cpu_count": os.cpu_count(),
              "load_average": [round(v, 2) for v in os.getloadavg()],
              "no_fpgo_ms_per_frame": no_fpgo, "fpgo_ms_per_frame": fpgo,
              "fpgo_pass_ms": summary("fpgo_pass_ms"),
              "raster_no_fpgo_ms": summary("raster_no_fpgo_ms"),
              "raster_fpgo_ms": summary("raster_fpgo_ms"),
              "fpgo_detail_ms_median": {
                  part: round(statistics.median(r["fpgo_detail_ms"].get(part, 0.0) for r in rows), 1)
                  for part in rows[0]["fpgo_detail_ms"]},
              "added_median_of_frames": summary("added")["median"],
              "added_of_means": round(fpgo["mean"] / no_fpgo["mean"] - 1.0, 3),
              "gaussian_size_m_last_frame": {
                  name: round(value, 6)
                  for name, value in median_sizes(scene.frame(sim.load_frame(frames[-1]))).items()},
              "rows": rows}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
