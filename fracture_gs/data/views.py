"""Turning per-view cameras and file paths into a :class:`Dataset` (shared by all loaders)."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from fracture_gs.data.cameras import resized_camera
from fracture_gs.data.dataset import Dataset, DatasetError
from fracture_gs.data.images import composite, downscaled_size, read_image, read_mask, resize
from fracture_gs.render.camera import Camera


def background_color(white_background: bool) -> tuple[float, float, float]:
    return (1.0, 1.0, 1.0) if white_background else (0.0, 0.0, 0.0)


def assemble_dataset(cameras: Sequence[Camera], image_paths: Sequence[str],
                     mask_paths: Sequence[str] | None, *, downscale: int,
                     white_background: bool, format: str, alpha_as_mask: bool = True,
                     **extras) -> Dataset:
    """Read every image (and mask), check it against its camera, downscale both.

    Each camera must describe its image at the file's native resolution; all images must
    share one size. RGBA images are composited on the background; their alpha becomes the
    mask when ``mask_paths`` is None and ``alpha_as_mask`` is set (all images must then have
    alpha, or none). Images with a mask file are composited on the background with the mask
    as their alpha, so that the photometric fit sees the object alone and no background ends
    up in its Gaussians.
    """
    if len(cameras) == 0:
        raise DatasetError(f"{format} dataset: no views to load")
    if mask_paths is not None and len(mask_paths) != len(image_paths):
        raise DatasetError(f"{mask_paths[0] if mask_paths else format}: {len(mask_paths)} masks "
                           f"for {len(image_paths)} images")
    background = background_color(white_background)
    native_size = (cameras[0].width, cameras[0].height)
    width, height = downscaled_size(*native_size, downscale)
    images = torch.empty(len(cameras), height, width, 3, dtype=torch.float32)
    masks = None
    if mask_paths is not None:
        masks = torch.empty(len(cameras), height, width, dtype=torch.float32)
    first_has_alpha = None
    scaled_cameras = []
    for index, (camera, path) in enumerate(zip(cameras, image_paths)):
        rgb, alpha = read_image(path)
        file_size = (rgb.shape[1], rgb.shape[0])
        if index > 0 and file_size != native_size:
            raise DatasetError(f"{path}: inconsistent image size {file_size[0]}x{file_size[1]}, "
                               f"the first image is {native_size[0]}x{native_size[1]}")
        if file_size != (camera.width, camera.height):
            raise DatasetError(f"{path}: image is {file_size[0]}x{file_size[1]} but its camera "
                               f"is {camera.width}x{camera.height}")
        has_alpha = alpha is not None
        if mask_paths is None and alpha_as_mask:
            if first_has_alpha is None:
                first_has_alpha = has_alpha
                if has_alpha:
                    masks = torch.empty(len(cameras), height, width, dtype=torch.float32)
            elif has_alpha != first_has_alpha:
                raise DatasetError(f"{path}: image {'has' if has_alpha else 'lacks'} an alpha "
                                   f"channel unlike {image_paths[0]}")
        pixels = composite(rgb, alpha, background)
        if mask_paths is not None:
            mask = read_mask(mask_paths[index])
            if (mask.shape[1], mask.shape[0]) != file_size:
                raise DatasetError(f"{mask_paths[index]}: mask is {mask.shape[1]}x{mask.shape[0]} "
                                   f"but its image {path} is {file_size[0]}x{file_size[1]}")
            pixels = composite(pixels, mask, background)
            masks[index] = torch.from_numpy(np.ascontiguousarray(resize(mask, width, height)))
        elif masks is not None:
            masks[index] = torch.from_numpy(np.ascontiguousarray(resize(alpha, width, height)))
        images[index] = torch.from_numpy(resize(pixels, width, height))
        scaled_cameras.append(resized_camera(camera, width, height))
    return Dataset(cameras=scaled_cameras, images=images.clamp_(0.0, 1.0),
                   masks=None if masks is None else masks.clamp_(0.0, 1.0),
                   image_paths=list(image_paths), format=format, background=background,
                   **extras)


def split_indices(count: int, split: str, holdout_every: int, source: str) -> list[int]:
    """Views of ``split`` for formats without split files.

    ``holdout_every`` = 0 puts every view in "train" (3DGS without ``--eval``); k > 0 holds out
    views 0, k, 2k, ... as "test" (3DGS's LLFF hold-out uses k = 8). "all" is every view.
    """
    if split == "all":
        return list(range(count))
    if split not in ("train", "test"):
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
    if holdout_every < 0:
        raise ValueError(f"holdout_every must be >= 0, got {holdout_every}")
    if holdout_every == 0:
        if split == "test":
            raise DatasetError(f"{source}: this format has no test split; train with "
                               f"--holdout-every k to hold out every k-th view")
        return list(range(count))
    test = [i for i in range(count) if i % holdout_every == 0]
    if split == "test":
        return test
    return [i for i in range(count) if i % holdout_every != 0]
