"""Shared check for synthetic datasets: rendered masks vs. ray-cast silhouettes of gt_mesh."""
from __future__ import annotations

import numpy as np
import trimesh

from fracture_gs.data import load_dataset
from fracture_gs.data.synthetic.silhouette import mask_iou, rasterize_silhouette


def silhouette_ious(dataset_dir: str, split: str = "all") -> list[float]:
    """IoU of (alpha > 0.5) with the silhouette of gt_mesh.ply through each loaded camera."""
    dataset = load_dataset(dataset_dir, split=split, white_background=True)
    mesh = trimesh.load(f"{dataset_dir}/gt_mesh.ply", process=False)
    vertices = np.asarray(mesh.vertices)
    ious = []
    for camera, mask in zip(dataset.cameras, dataset.masks):
        import torch
        uv, depth = camera.project(torch.as_tensor(vertices, dtype=torch.float64))
        assert float(depth.min()) > 0, "mesh must be in front of every camera"
        silhouette = rasterize_silhouette(uv.numpy(), np.asarray(mesh.faces), camera.width,
                                          camera.height)
        ious.append(mask_iou(mask.numpy() > 0.5, silhouette))
    return ious
