"""Reading, compositing and resizing image and mask files for the dataset loaders."""
from __future__ import annotations

import os

import cv2
import numpy as np

from fracture_gs.data.dataset import DatasetError
from fracture_gs.data.files import os_reason, read_bytes

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".webp")
MAX_AUTO_WIDTH = 1600


def _to_unit_float(pixels: np.ndarray, path: str) -> np.ndarray:
    """Integer or float pixels as float32 in [0, 1]."""
    if pixels.dtype == np.uint8:
        return pixels.astype(np.float32) / 255.0
    if pixels.dtype == np.uint16:
        return pixels.astype(np.float32) / 65535.0
    if pixels.dtype in (np.float32, np.float64):
        values = pixels.astype(np.float32)
        if not np.isfinite(values).all():
            raise DatasetError(f"{path}: image contains NaN or Inf pixels")
        return np.clip(values, 0.0, 1.0)
    raise DatasetError(f"{path}: unsupported pixel type {pixels.dtype}")


def _read_raw(path: str) -> np.ndarray:
    if not os.path.exists(path):
        raise DatasetError(f"{path}: image file not found")
    data = read_bytes(path)  # read here: cv2.imread hides why a file cannot be read
    if not data:
        raise DatasetError(f"{path}: empty file, expected an image")
    pixels = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.size == 0:
        raise DatasetError(f"{path}: cannot be decoded as an image")
    return pixels


def read_image(path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image file as float32 RGB (H, W, 3) in [0, 1] plus its alpha (H, W) or None."""
    pixels = _to_unit_float(_read_raw(path), path)
    if pixels.ndim == 2:
        return np.repeat(pixels[:, :, None], 3, axis=2), None
    channels = pixels.shape[2]
    if channels == 1:
        return np.repeat(pixels, 3, axis=2), None
    if channels == 3:
        return np.ascontiguousarray(pixels[:, :, ::-1]), None
    if channels == 4:
        return np.ascontiguousarray(pixels[:, :, 2::-1]), np.ascontiguousarray(pixels[:, :, 3])
    raise DatasetError(f"{path}: unsupported number of channels {channels}")


def read_mask(path: str) -> np.ndarray:
    """Read a mask file as float32 (H, W) in [0, 1] (mean of the colour channels)."""
    pixels = _to_unit_float(_read_raw(path), path)
    if pixels.ndim == 2:
        return pixels
    return np.ascontiguousarray(pixels[:, :, :3].mean(axis=2, dtype=np.float32))


def composite(rgb: np.ndarray, alpha: np.ndarray | None,
              background: tuple[float, float, float]) -> np.ndarray:
    """Blend straight-alpha RGB over a constant background colour."""
    if alpha is None:
        return rgb
    bg = np.asarray(background, dtype=np.float32)
    return rgb * alpha[:, :, None] + bg * (1.0 - alpha[:, :, None])


def downscaled_size(width: int, height: int, downscale: int) -> tuple[int, int]:
    """Image size after 3DGS's ``-r`` option.

    ``downscale`` is a positive integer factor (1, 2, 4, 8, ...), or -1 to shrink only images
    wider than 1600 pixels to a width of 1600.
    """
    if isinstance(downscale, bool) or not isinstance(downscale, (int, np.integer)):
        raise ValueError(f"downscale must be a positive integer or -1, got {downscale!r}")
    if downscale == -1:
        if width <= MAX_AUTO_WIDTH:
            return width, height
        return MAX_AUTO_WIDTH, max(1, round(height * MAX_AUTO_WIDTH / width))
    if downscale < 1:
        raise ValueError(f"downscale must be a positive integer or -1, got {downscale}")
    return max(1, round(width / downscale)), max(1, round(height / downscale))


def resize(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize an (H, W[, C]) float32 array with area averaging (no-op at the same size)."""
    if pixels.shape[1] == width and pixels.shape[0] == height:
        return pixels
    return cv2.resize(pixels, (width, height), interpolation=cv2.INTER_AREA)


def find_image_file(stem_path: str) -> str | None:
    """``stem_path`` itself if it is a file, else the first ``stem_path + ext`` that exists."""
    if os.path.isfile(stem_path):
        return stem_path
    for extension in IMAGE_EXTENSIONS + tuple(e.upper() for e in IMAGE_EXTENSIONS):
        if os.path.isfile(stem_path + extension):
            return stem_path + extension
    return None


def list_image_files(folder: str) -> list[str]:
    """Sorted image files directly inside ``folder``."""
    try:
        entries = os.listdir(folder)
    except OSError as exc:
        raise DatasetError(f"{folder}: cannot list the folder ({os_reason(exc)})") from None
    names = [name for name in entries
             if os.path.splitext(name)[1].lower() in IMAGE_EXTENSIONS
             and os.path.isfile(os.path.join(folder, name))]
    return [os.path.join(folder, name) for name in sorted(names)]
