"""Shared check for synthetic datasets: rendered masks vs. ray-cast silhouettes of gt_mesh."""
from __future__ import annotations

import trimesh

from fracture_gs.data import load_dataset
from fracture_gs.data.synthetic.silhouette import mask_mesh_ious


def silhouette_ious(dataset_dir: str, split: str = "all") -> list[float]:
    """IoU of (alpha > 0.5) with the silhouette of gt_mesh.ply through each loaded camera."""
    dataset = load_dataset(dataset_dir, split=split, white_background=True)
    mesh = trimesh.load(f"{dataset_dir}/gt_mesh.ply", process=False)
    return mask_mesh_ious(dataset.cameras, [m.numpy() for m in dataset.masks], mesh.vertices,
                          mesh.faces)
