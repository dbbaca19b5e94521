#!/usr/bin/env python3
"""Vertical cross-sections of train.py geometries against the dataset's ground-truth mesh.

    python tools/figures/sdf_section.py -s data/bowl -m output/bowl_before output/bowl \
        --labels "before" "after" --out docs/train_bowl_section.png

One panel for the visual hull of the first model and one per model: the zero level set of its
``sdf.npz`` (blue) and the ground-truth mesh (red) in the plane y = (the grid's centre), x
horizontal and z vertical, in model coordinates. Prints each model's Chamfer distance and mesh
volume (``mesh.ply``) against the ground truth as JSON, the numbers the panel titles show.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
import trimesh

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))  # the repository root

from fracture_gs.recon.errors import ReconstructionError  # noqa: E402
from fracture_gs.recon.pipeline import load_sdf  # noqa: E402
from fracture_gs.recon.quality import chamfer_distance  # noqa: E402


def _fail(message: str) -> None:
    print(f"sdf_section.py: {message}", file=sys.stderr)
    sys.exit(2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-s", "--source_path", required=True, help="dataset folder with gt_mesh.ply")
    parser.add_argument("-m", "--models", nargs="+", required=True, help="train.py model folders")
    parser.add_argument("--labels", nargs="+", help="one label per model (default: folder names)")
    parser.add_argument("--out", required=True, help="PNG to write")
    args = parser.parse_args()
    labels = args.labels or [os.path.basename(os.path.normpath(m)) for m in args.models]
    if len(labels) != len(args.models):
        _fail(f"--labels: {len(labels)} labels for {len(args.models)} models")
    gt_path = os.path.join(args.source_path, "gt_mesh.ply")
    if not os.path.isfile(gt_path):
        _fail(f"{gt_path}: file not found (a synthetic dataset has one)")
    ground_truth = trimesh.load(gt_path, force="mesh")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels, numbers = [], {}
    for index, (model, label) in enumerate(zip(args.models, labels)):
        try:
            grid, sdf, hull = load_sdf(os.path.join(model, "sdf.npz"))
        except ReconstructionError as error:
            _fail(str(error))
        mesh_path = os.path.join(model, "mesh.ply")
        if not os.path.isfile(mesh_path):
            _fail(f"{mesh_path}: file not found")
        mesh = trimesh.load(mesh_path, force="mesh")
        chamfer = chamfer_distance(mesh, ground_truth)["chamfer_percent"]
        volume = float(mesh.volume) / float(ground_truth.volume) - 1.0
        numbers[label] = {"chamfer_percent": round(chamfer, 3), "volume_vs_gt_percent": round(100 * volume, 1)}
        if index == 0:
            panels.append(("visual hull", grid, hull.numpy()))
        panels.append((f"{label}: Chamfer {chamfer:.2f} %, volume {100 * volume:+.0f} %", grid, sdf.numpy()))

    figure, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 2.6), squeeze=False)
    for axis, (title, grid, values) in zip(axes[0], panels):
        middle = values.shape[1] // 2
        xs = grid.origin[0] + np.arange(values.shape[0]) * grid.voxel
        zs = grid.origin[2] + np.arange(values.shape[2]) * grid.voxel
        section = ground_truth.section(plane_origin=[0.0, grid.origin[1] + middle * grid.voxel, 0.0],
                                       plane_normal=[0.0, 1.0, 0.0])
        if section is not None:
            for curve in section.discrete:
                axis.plot(curve[:, 0], curve[:, 2], color="tab:red", linewidth=0.9)
        axis.contour(xs, zs, values[:, middle, :].T, levels=[0.0], colors="tab:blue", linewidths=1.1)
        axis.set_aspect("equal")
        axis.set_title(title, fontsize=9)
        axis.tick_params(labelsize=7)
    axes[0][0].plot([], [], color="tab:red", label="ground truth")
    axes[0][0].plot([], [], color="tab:blue", label="zero level set")
    axes[0][0].legend(fontsize=7, loc="lower left")
    figure.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    figure.savefig(args.out, dpi=110)
    print(json.dumps(numbers, indent=2))


if __name__ == "__main__":
    main()
