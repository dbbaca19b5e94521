"""DTU / IDR / NeuS loader: ``cameras_sphere.npz`` + ``image/`` + ``mask/`` (docs/file_formats.md §1)."""
from __future__ import annotations

import os

import numpy as np

from fracture_gs.data.cameras import decompose_projection, make_camera, require_finite
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.files import read_npz
from fracture_gs.data.images import list_image_files, read_image
from fracture_gs.data.views import assemble_dataset, split_indices

CAMERAS_FILE = "cameras_sphere.npz"
SKEW_TOLERANCE_PX = 0.5  # largest image shift a dropped skew K[0,1] may cause (in pixels)
SCALE_MAT_TOLERANCE = 1e-6


def _matrix(arrays: dict[str, np.ndarray], key: str, path: str) -> np.ndarray:
    if key not in arrays:
        raise DatasetError(f"{path}: missing key '{key}'")
    matrix = require_finite(arrays[key], f"'{key}'", path)
    if matrix.shape not in ((4, 4), (3, 4)):
        raise DatasetError(f"{path}: '{key}' has shape {matrix.shape}, expected (4, 4)")
    if matrix.shape == (3, 4):
        matrix = np.vstack([matrix, [0.0, 0.0, 0.0, 1.0]])
    return matrix


def load_dtu(source_path: str, split: str = "train", downscale: int = 1,
             white_background: bool = False, holdout_every: int = 0) -> Dataset:
    """Load a scene in the IDR / NeuS layout.

    View i is the i-th file of ``image/`` in name order, with projection
    P = world_mat_i @ scale_mat_i mapping the normalised (unit-sphere) frame to pixels.
    P[:3, :4] is split into K [R | t] with OpenCV's RQ decomposition. IDR and NeuS put pixel
    centres at integer coordinates, :class:`Camera` at i + 0.5, so cx and cy get + 0.5.
    ``mask/`` (optional) is paired with ``image/`` by name order. The returned
    ``scale_mat`` maps the normalised frame back to the original world.
    """
    cameras_path = os.path.join(source_path, CAMERAS_FILE)
    arrays = read_npz(cameras_path)
    image_folder = os.path.join(source_path, "image")
    if not os.path.isdir(image_folder):
        raise DatasetError(f"{image_folder}: folder not found")
    all_images = list_image_files(image_folder)
    if not all_images:
        raise DatasetError(f"{image_folder}: no image files")
    mask_folder = os.path.join(source_path, "mask")
    all_masks = None
    if os.path.isdir(mask_folder):
        all_masks = list_image_files(mask_folder)
        if len(all_masks) != len(all_images):
            raise DatasetError(f"{mask_folder}: {len(all_masks)} masks for {len(all_images)} "
                               f"images in {image_folder}")
    scale_mat_0 = _matrix(arrays, "scale_mat_0", cameras_path)
    first_rgb, _ = read_image(all_images[0])
    height, width = first_rgb.shape[:2]
    selected = split_indices(len(all_images), split, holdout_every, cameras_path)
    cameras = []
    for view in selected:
        scale_mat = _matrix(arrays, f"scale_mat_{view}", cameras_path)
        if np.abs(scale_mat - scale_mat_0).max() > SCALE_MAT_TOLERANCE * np.abs(scale_mat_0).max():
            raise DatasetError(f"{cameras_path}: 'scale_mat_{view}' differs from 'scale_mat_0' "
                               f"(views must share one normalisation)")
        projection = _matrix(arrays, f"world_mat_{view}", cameras_path) @ scale_mat
        if abs(np.linalg.det(projection[:3, :3])) < 1e-12:
            raise DatasetError(f"{cameras_path}: 'world_mat_{view}' is singular")
        intrinsics, world_to_camera = decompose_projection(projection)
        if np.linalg.det(world_to_camera[:3, :3]) < 0 or intrinsics[0, 0] <= 0:
            raise DatasetError(f"{cameras_path}: 'world_mat_{view}' does not decompose into a "
                               f"right-handed camera with positive focal lengths")
        # Camera has no skew term: dropping K[0,1] moves a pixel by skew * y / z, at most
        # skew * max(cy, H - cy) / fy inside the image
        skew_shift = abs(intrinsics[0, 1]) * max(intrinsics[1, 2], height - intrinsics[1, 2]) \
            / intrinsics[1, 1]
        if skew_shift > SKEW_TOLERANCE_PX:
            raise DatasetError(f"{cameras_path}: 'world_mat_{view}' has skew "
                               f"{intrinsics[0, 1]:.4g}, which would shift pixels by up to "
                               f"{skew_shift:.2f} px (skewed pixels are not supported)")
        cameras.append(make_camera(world_to_camera, intrinsics[0, 0], intrinsics[1, 1],
                                   intrinsics[0, 2] + 0.5, intrinsics[1, 2] + 0.5, width,
                                   height, all_images[view]))
    image_paths = [all_images[i] for i in selected]
    mask_paths = None if all_masks is None else [all_masks[i] for i in selected]
    return assemble_dataset(cameras, image_paths, mask_paths, downscale=downscale,
                            white_background=white_background, format="dtu",
                            scale_mat=scale_mat_0)


def resized_projection(projection: np.ndarray, factor: float) -> np.ndarray:
    """The ``world_mat`` of the same camera for its image shrunk ``factor`` times on both axes.

    With IDR's integer pixel centres a pixel coordinate u becomes (u + 0.5) / factor - 0.5."""
    shift = 0.5 / factor - 0.5
    resize = np.array([[1.0 / factor, 0.0, shift, 0.0], [0.0, 1.0 / factor, shift, 0.0],
                       [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return resize @ projection


def write_dtu_subset(source_path: str, out_path: str, views: list[int], factor: int) -> None:
    """Write views ``views`` of a DTU / NeuS folder to ``out_path`` in the same layout, their
    images and masks shrunk ``factor`` times (area averaging; masks as 8-bit grey) and their
    ``world_mat`` adjusted to match; view ``views[k]`` becomes view k."""
    import cv2

    from fracture_gs.data.images import read_mask, resize

    cameras_path = os.path.join(source_path, CAMERAS_FILE)
    arrays = read_npz(cameras_path)
    images = list_image_files(os.path.join(source_path, "image"))
    masks = list_image_files(os.path.join(source_path, "mask"))
    if len(masks) != len(images):
        raise DatasetError(f"{source_path}: expected one mask per image")
    for folder in ("image", "mask"):
        os.makedirs(os.path.join(out_path, folder), exist_ok=True)
    subset = {}
    for index, view in enumerate(views):
        if not 0 <= view < len(images):
            raise DatasetError(f"{source_path}: no view {view} (it has {len(images)})")
        rgb, _ = read_image(images[view])
        height, width = rgb.shape[:2]
        size = (max(1, round(width / factor)), max(1, round(height / factor)))
        pixels = np.clip(resize(rgb, *size) * 255.0 + 0.5, 0, 255).astype(np.uint8)
        mask = np.clip(resize(read_mask(masks[view]), *size) * 255.0 + 0.5, 0, 255).astype(np.uint8)
        cv2.imwrite(os.path.join(out_path, "image", f"{index:03d}.png"), pixels[:, :, ::-1],
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        cv2.imwrite(os.path.join(out_path, "mask", f"{index:03d}.png"), mask,
                    [cv2.IMWRITE_PNG_COMPRESSION, 9])
        subset[f"world_mat_{index}"] = resized_projection(
            _matrix(arrays, f"world_mat_{view}", cameras_path), width / size[0])
        subset[f"scale_mat_{index}"] = _matrix(arrays, f"scale_mat_{view}", cameras_path)
    np.savez_compressed(os.path.join(out_path, CAMERAS_FILE), **subset)
