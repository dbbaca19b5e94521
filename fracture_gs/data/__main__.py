"""``python -m fracture_gs.data DATASET``: load a dataset as ``train.py`` would and summarise it.

A quick check of a folder before a long training run: every view, image and mask is read
(and ``parts.json`` when the folder has one). ``--mesh-check`` also ray-casts ``gt_mesh.ply``
(synthetic datasets) through every camera and prints the IoU of its silhouette with the masks:
cameras, images and mesh agree when it is close to 1. Exit status 0 when the dataset loads, 2
with one ``error: <file>: <problem>`` line when it does not, 130 when interrupted.
"""
from __future__ import annotations

import argparse
import io
import os
import sys
from collections.abc import Sequence

from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.loading import load_dataset
from fracture_gs.data.parts import PartSpecError, load_part_spec
from fracture_gs.data.up import camera_up, level_residual_deg

PARTS_FILE = "parts.json"
MESH_FILE = "gt_mesh.ply"


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m fracture_gs.data",
        description="Load a Blender / COLMAP / DTU dataset folder and print what it holds.")
    parser.add_argument("dataset", help="dataset folder")
    parser.add_argument("--split", choices=("train", "test", "all"), default="train")
    parser.add_argument("--downscale", type=int, default=1,
                        help="integer factor, or -1 to cap the width at 1600 pixels")
    parser.add_argument("--holdout-every", type=int, default=0,
                        help="COLMAP / DTU: views 0, k, 2k, ... are the test split (train.py's "
                        "--holdout-every)")
    parser.add_argument("--mesh-check", action="store_true",
                        help=f"compare the masks with the silhouettes of {MESH_FILE}")
    return parser.parse_args(argv)


def describe(dataset: Dataset) -> list[str]:
    """Summary lines of a loaded dataset."""
    _, radius = dataset.scene_bounds()
    lines = [f"format     {dataset.format}",
             f"views      {len(dataset)} of {dataset.width}x{dataset.height} pixels",
             f"masks      {'yes' if dataset.masks is not None else 'no'}",
             f"cameras    rig radius {radius:.4g} (3DGS scene extent)"]
    if dataset.points is not None:
        lines.append(f"points     {dataset.points.shape[0]} sparse points")
    up, method = camera_up(dataset.cameras)
    lines.append(f"up         [{up[0]:.3f}, {up[1]:.3f}, {up[2]:.3f}] ({method}, "
                 f"{level_residual_deg(dataset.cameras, up):.1f} deg rms tilt)")
    return lines


def mesh_check(dataset: Dataset, folder: str) -> str:
    """Summary line of the mask / mesh-silhouette agreement (DatasetError when impossible)."""
    import trimesh

    from fracture_gs.data.files import read_bytes
    from fracture_gs.data.synthetic.silhouette import mask_mesh_ious

    path = os.path.join(folder, MESH_FILE)
    if dataset.masks is None:
        raise DatasetError(f"{folder}: --mesh-check needs masks (alpha channels or mask/)")
    data = read_bytes(path)
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
        vertices, faces = mesh.vertices, mesh.faces
    except Exception as exc:  # trimesh raises many types for malformed files
        raise DatasetError(f"{path}: cannot be read as a triangle mesh ({exc})") from None
    try:
        ious = mask_mesh_ious(dataset.cameras, [m.numpy() for m in dataset.masks], vertices,
                              faces)
    except ValueError as exc:
        raise DatasetError(f"{path}: {exc}") from None
    return (f"mesh check mask IoU with {MESH_FILE}: min {min(ious):.4f}, mean "
            f"{sum(ious) / len(ious):.4f} over {len(ious)} views")


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = parse_args(argv)
    try:
        if args.downscale == 0 or args.downscale < -1:
            raise DatasetError(f"--downscale: {args.downscale} is neither a positive factor "
                               "nor -1")
        if args.holdout_every < 0:
            raise DatasetError(f"--holdout-every: {args.holdout_every} is not >= 0")
        dataset = load_dataset(args.dataset, split=args.split, downscale=args.downscale,
                               holdout_every=args.holdout_every)
        lines = [f"dataset    {args.dataset} ({args.split})"] + describe(dataset)
        parts_path = os.path.join(args.dataset, PARTS_FILE)
        if os.path.exists(parts_path):
            spec = load_part_spec(parts_path)
            lines.append(f"parts      {', '.join(spec.part_names)} ({PARTS_FILE})")
        if args.mesh_check:
            lines.append(mesh_check(dataset, args.dataset))
    except (DatasetError, PartSpecError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
