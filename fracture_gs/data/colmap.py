"""COLMAP loader: ``sparse/0/{cameras,images,points3D}.{bin,txt}`` + ``images/`` (docs/file_formats.md §1)."""
from __future__ import annotations

import os

import numpy as np

from fracture_gs.data.cameras import make_camera, quaternion_to_rotation, require_finite
from fracture_gs.data.colmap_io import ColmapCamera, read_model
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.views import assemble_dataset, split_indices

DISTORTION_TOLERANCE = 1e-6
# models that are pinhole once their distortion parameters are zero: name -> number of
# leading (focal, principal point) parameters
UNDISTORTABLE_MODELS = {"SIMPLE_RADIAL": 3, "RADIAL": 3, "OPENCV": 4, "FULL_OPENCV": 4}


def find_sparse_folder(source_path: str) -> str | None:
    """``sparse/0`` if it holds a model, else ``sparse`` if it does, else None."""
    for folder in (os.path.join(source_path, "sparse", "0"), os.path.join(source_path, "sparse")):
        if any(os.path.isfile(os.path.join(folder, "cameras" + ext)) for ext in (".bin", ".txt")):
            return folder
    return None


def pinhole_intrinsics(camera: ColmapCamera, path: str) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a COLMAP camera, which must be distortion-free.

    COLMAP puts the centre of the top-left pixel at (0.5, 0.5), the convention of
    :class:`Camera`, so the principal point is used unchanged.
    """
    params = camera.params
    if camera.model == "SIMPLE_PINHOLE":
        return params[0], params[0], params[1], params[2]
    if camera.model == "PINHOLE":
        return params[0], params[1], params[2], params[3]
    if camera.model in UNDISTORTABLE_MODELS:
        leading = UNDISTORTABLE_MODELS[camera.model]
        distortion = params[leading:]
        if np.abs(distortion).max() > DISTORTION_TOLERANCE:
            raise DatasetError(f"{path}: camera {camera.camera_id} is {camera.model} with "
                               f"non-zero distortion {distortion.tolist()}; run "
                               f"`colmap image_undistorter` first")
        if leading == 3:
            return params[0], params[0], params[1], params[2]
        return params[0], params[1], params[2], params[3]
    raise DatasetError(f"{path}: camera {camera.camera_id} has unsupported model {camera.model} "
                       f"(use PINHOLE, SIMPLE_PINHOLE or undistorted OPENCV; run "
                       f"`colmap image_undistorter`)")


def _mask_path(masks_folder: str, image_name: str) -> str:
    """The mask of ``image_name``: same name, name + '.png', or stem + '.png'."""
    candidates = [image_name, image_name + ".png", os.path.splitext(image_name)[0] + ".png"]
    for candidate in candidates:
        path = os.path.join(masks_folder, candidate)
        if os.path.isfile(path):
            return path
    raise DatasetError(f"{os.path.join(masks_folder, image_name)}: mask not found (also tried "
                       f"{candidates[1]!r} and {candidates[2]!r})")


def load_colmap(source_path: str, split: str = "train", downscale: int = 1,
                white_background: bool = False, holdout_every: int = 0,
                images_folder: str = "images") -> Dataset:
    """Load a COLMAP reconstruction.

    Images are ordered by name (as 3DGS does). Poses are COLMAP's world-to-camera
    (qvec w x y z, tvec). Masks come from ``masks/`` when that folder exists (same file
    names, or with ``.png`` appended / swapped in), else from the images' alpha channel.
    The sparse points are returned as ``points`` / ``point_colors``.
    """
    sparse = find_sparse_folder(source_path)
    if sparse is None:
        raise DatasetError(f"{os.path.join(source_path, 'sparse', '0')}: no cameras.bin or "
                           f"cameras.txt")
    model = read_model(sparse)
    images = sorted(model.images.values(), key=lambda image: image.name)
    if not images:
        raise DatasetError(f"{sparse}: the model has no registered images")
    images = [images[i] for i in split_indices(len(images), split, holdout_every, sparse)]
    cameras, image_paths = [], []
    for image in images:
        pose_file = model.images_path
        if image.camera_id not in model.cameras:
            raise DatasetError(f"{pose_file}: image {image.name!r} refers to missing camera "
                               f"{image.camera_id}")
        camera = model.cameras[image.camera_id]
        fx, fy, cx, cy = pinhole_intrinsics(camera, model.cameras_path)
        require_finite(np.concatenate([image.qvec, image.tvec]), f"pose of {image.name!r}",
                       pose_file)
        if np.linalg.norm(image.qvec) < 1e-12:
            raise DatasetError(f"{pose_file}: image {image.name!r} has a zero quaternion")
        world_to_camera = np.eye(4)
        world_to_camera[:3, :3] = quaternion_to_rotation(image.qvec)
        world_to_camera[:3, 3] = image.tvec
        image_path = os.path.join(source_path, images_folder, image.name)
        cameras.append(make_camera(world_to_camera, fx, fy, cx, cy, camera.width, camera.height,
                                   image_path))
        image_paths.append(image_path)
    masks_folder = os.path.join(source_path, "masks")
    mask_paths = None
    if os.path.isdir(masks_folder):
        mask_paths = [_mask_path(masks_folder, image.name) for image in images]
    points = colors = None
    if model.points_xyz is not None:
        require_finite(model.points_xyz, "point positions", os.path.join(sparse, "points3D"))
        points = model.points_xyz.astype(np.float32)
        colors = model.points_rgb.astype(np.float32) / 255.0
    return assemble_dataset(cameras, image_paths, mask_paths, downscale=downscale,
                            white_background=white_background, format="colmap",
                            points=points, point_colors=colors)
