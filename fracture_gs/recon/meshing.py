"""Marching cubes (PyMCubes) of the SDF's zero level set, small components removed."""
from __future__ import annotations

import mcubes
import numpy as np
import torch
import trimesh

from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.grid import VoxelGrid

LEVEL = 0.0


def extract_mesh(sdf: torch.Tensor | np.ndarray, grid: VoxelGrid,
                 min_component: float = 0.005, source: str = "sdf") -> trimesh.Trimesh:
    """Triangle mesh of ``sdf`` = 0 in world coordinates, outward normals.

    Connected components with fewer than ``min_component`` x (faces of the largest
    component) faces are dropped. Raises :class:`ReconstructionError` naming ``source`` if
    no surface is found.
    """
    values = sdf.detach().cpu().numpy() if isinstance(sdf, torch.Tensor) else np.asarray(sdf)
    values = np.where(np.isfinite(values), values, values[np.isfinite(values)].max(initial=1.0))
    low, high = float(values.min()), float(values.max())
    if not (low < LEVEL < high):
        raise ReconstructionError(
            f"{source}: marching cubes at level {LEVEL:g} found no surface (SDF range "
            f"{low:.3g} .. {high:.3g}); check that the masks show the object, or try "
            f"--sdf-iters 0 (visual hull only) or a larger --sdf-res")
    # PyMCubes marks the side with values above the level as inside: negate the SDF.
    vertices, faces = mcubes.marching_cubes(-values.astype(np.float64), -LEVEL)
    if len(faces) == 0:
        raise ReconstructionError(f"{source}: marching cubes at level {LEVEL:g} produced no "
                                  f"triangles; try a larger --sdf-res")
    vertices = vertices * grid.voxel + np.asarray(grid.origin)
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh = keep_large_components(mesh, min_component)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def keep_large_components(mesh: trimesh.Trimesh, min_component: float) -> trimesh.Trimesh:
    """Drop connected components smaller than ``min_component`` x the largest (in faces)."""
    components = mesh.split(only_watertight=False)
    if len(components) <= 1:
        return mesh
    sizes = np.array([len(part.faces) for part in components])
    keep = [part for part, size in zip(components, sizes) if size >= min_component * sizes.max()]
    return trimesh.util.concatenate(keep)
