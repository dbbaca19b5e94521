"""A stand-in for a ``train.py`` model folder, built from a dataset's ground-truth mesh.

For FPGO measurements without a trained model: surface particles spread
evenly over ``gt_mesh.ply`` (dense random samples thinned to the one nearest the centre of each
cubic cell of edge ``spacing``), each owning an isotropic
Gaussian (scale ``--scale-factor`` × spacing, opacity 0.95) coloured by the nearest mesh vertex
colour (SH degree 0); interior particles one per voxel of the filled voxelisation (pitch =
spacing), jittered inside the voxel. It has no reconstruction error and no view-dependent
colour, so it is a stand-in for the geometry and the binding, not for a trained model's looks.

Usage: python tools/standin_model.py --mesh /work/data/teapot/gt_mesh.ply \
           --out output/standin_teapot [--spacing 0.025]
Prints one JSON line (counts).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

import numpy as np
import torch

from fracture_gs.gaussians import GaussianModel
from fracture_gs.folders.model_folder import write_model_folder


def even_surface_samples(mesh, spacing: float, seed: int) -> np.ndarray:
    """Random surface samples, one per occupied cell (the sample nearest the cell centre)."""
    import trimesh

    dense, _ = trimesh.sample.sample_surface(mesh, int(12.0 * mesh.area / spacing ** 2), seed=seed)
    cells = np.floor(dense / spacing).astype(np.int64)
    offset = np.linalg.norm(dense - (cells + 0.5) * spacing, axis=1)
    order = np.lexsort((offset, cells[:, 2], cells[:, 1], cells[:, 0]))
    first = np.ones(order.size, dtype=bool)
    first[1:] = (np.diff(cells[order], axis=0) != 0).any(axis=1)
    return dense[order[first]]


def build_standin(mesh_path: Path, out: Path, spacing: float, scale_factor: float,
                  seed: int = 0) -> dict[str, int]:
    import trimesh
    from scipy.spatial import cKDTree

    mesh = trimesh.load(str(mesh_path), force="mesh")
    rng = np.random.default_rng(seed)
    surface = even_surface_samples(mesh, spacing, seed)
    voxels = mesh.voxelized(pitch=spacing).fill()
    interior = voxels.points + rng.uniform(-0.5, 0.5, voxels.points.shape) * spacing
    # keep interior particles off the skin (the surface particles are there)
    near_skin = cKDTree(surface).query(interior, k=1)[0] < 0.5 * spacing
    interior = interior[~near_skin]
    colours = np.asarray(mesh.visual.vertex_colors[:, :3], dtype=np.float64) / 255.0
    nearest = cKDTree(mesh.vertices).query(surface, k=1)[1]
    gaussians = GaussianModel.from_points(torch.tensor(surface, dtype=torch.float32),
                                          torch.tensor(colours[nearest], dtype=torch.float32),
                                          sh_degree=0, isotropic=True, initial_opacity=0.95)
    with torch.no_grad():
        gaussians.log_scales.fill_(float(np.log(scale_factor * spacing)))
    x = np.concatenate([surface, interior])
    count_surface = surface.shape[0]
    is_surface = np.arange(x.shape[0]) < count_surface
    gaussian_index = np.where(is_surface, np.arange(x.shape[0]), -1)
    write_model_folder(out, x, np.full(x.shape[0], spacing ** 3), is_surface, gaussian_index,
                       gaussians, spacing=spacing)
    return {"surface_particles": int(count_surface), "interior_particles": int(interior.shape[0]),
            "gaussians": gaussians.num_gaussians}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--spacing", type=float, default=0.025)
    parser.add_argument("--scale-factor", type=float, default=0.6)
    args = parser.parse_args(argv)
    counts = build_standin(args.mesh, args.out, args.spacing, args.scale_factor)
    print(json.dumps({"out": str(args.out), "spacing": args.spacing, **counts}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
