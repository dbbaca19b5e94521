#!/usr/bin/env python3
"""Quality measures of a train.py model against its synthetic dataset, as JSON.

    python benchmarks/recon_quality.py -m output/teapot -s /work/data/teapot

Reports: Chamfer distance of mesh.ply to the dataset's gt_mesh.ply (definition in
``fracture_gs.recon.quality``) in % of the ground-truth bounding-box diagonal; mesh, visual
hull and ground-truth volumes; particle checks (total rest volume vs mesh volume, coefficient
of variation of the surface particles' nearest-neighbour spacing, part_id agreement with
parts.json at the nearest ground-truth surface point, Gaussian means = particle positions);
the train/test PSNR and SSIM and the per-stage timings that train.py recorded.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import trimesh

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_gs.data.parts import load_part_spec  # noqa: E402
from fracture_gs.gaussians import read_ply  # noqa: E402
from fracture_gs.io.model_layout import latest_iteration, point_cloud_path  # noqa: E402
from fracture_gs.io.particles_ply import read_particles_ply  # noqa: E402
from fracture_gs.recon.quality import (chamfer_distance, part_agreement,  # noqa: E402
                                       spacing_variation)


def measure(model_path: str, source_path: str) -> dict:
    mesh = trimesh.load(os.path.join(model_path, "mesh.ply"), process=False)
    reference = trimesh.load(os.path.join(source_path, "gt_mesh.ply"), process=False)
    particles = read_particles_ply(os.path.join(model_path, "particles.ply"))
    with open(os.path.join(model_path, "timings.json"), encoding="utf-8") as handle:
        summary = json.load(handle)
    position = np.stack([particles[a] for a in "xyz"], axis=1).astype(np.float64)
    surface = particles["is_surface"] > 0
    result = {"model": model_path, "chamfer": chamfer_distance(mesh, reference),
              "volume": {"mesh": float(mesh.volume), "ground_truth": float(reference.volume),
                         "visual_hull": summary.get("hull_volume"),
                         "mesh_vs_gt_percent": 100 * (mesh.volume / reference.volume - 1)},
              "particles": {"surface": int(surface.sum()), "interior": int((~surface).sum()),
                            "rest_volume_vs_mesh_percent":
                                100 * (float(particles["volume"].sum()) / mesh.volume - 1),
                            "surface_spacing_cv": spacing_variation(position[surface])}}
    parts_file = os.path.join(source_path, "parts.json")
    if os.path.isfile(parts_file):
        result["particles"]["part_agreement"] = part_agreement(
            position, particles["part_id"], reference, load_part_spec(parts_file))
    iteration = latest_iteration(model_path)
    if iteration is not None:
        gaussians = read_ply(point_cloud_path(model_path, iteration))
        index = particles["gaussian_index"][surface]
        means = gaussians.means.detach().numpy()[index]
        result["particles"]["max_particle_gaussian_offset"] = float(
            np.abs(means - position[surface]).max())
    for key in ("train", "test", "timings", "n_surface", "n_interior", "surface_spacing"):
        if key in summary:
            result[key] = summary[key]
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-m", "--model_path", required=True)
    parser.add_argument("-s", "--source_path", required=True)
    args = parser.parse_args()
    print(json.dumps(measure(args.model_path, args.source_path), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
