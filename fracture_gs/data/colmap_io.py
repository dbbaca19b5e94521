"""Readers (and writers, for tests and exports) of COLMAP's sparse model files.

Formats as documented by COLMAP ("Output format"): ``cameras``, ``images`` and ``points3D``
in binary (little-endian) or text form. Image poses are world-to-camera: a quaternion
(w, x, y, z) and a translation.
"""
from __future__ import annotations

import os
import struct
from dataclasses import dataclass

import numpy as np

from fracture_gs.data.dataset import DatasetError
from fracture_gs.data.files import read_bytes, read_text

# model name -> (model id, number of parameters)
CAMERA_MODELS: dict[str, tuple[int, int]] = {
    "SIMPLE_PINHOLE": (0, 3), "PINHOLE": (1, 4), "SIMPLE_RADIAL": (2, 4), "RADIAL": (3, 5),
    "OPENCV": (4, 8), "OPENCV_FISHEYE": (5, 8), "FULL_OPENCV": (6, 12), "FOV": (7, 5),
    "SIMPLE_RADIAL_FISHEYE": (8, 4), "RADIAL_FISHEYE": (9, 5), "THIN_PRISM_FISHEYE": (10, 12),
    "RAD_TAN_THIN_PRISM_FISHEYE": (11, 16),
}
MODEL_NAMES_BY_ID = {model_id: name for name, (model_id, _) in CAMERA_MODELS.items()}


@dataclass
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    image_id: int
    qvec: np.ndarray  # (4,) w x y z, world-to-camera rotation
    tvec: np.ndarray  # (3,) world-to-camera translation
    camera_id: int
    name: str


@dataclass
class ColmapModel:
    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points_xyz: np.ndarray | None   # (P, 3) float64
    points_rgb: np.ndarray | None   # (P, 3) uint8
    cameras_path: str = ""
    images_path: str = ""


class _BinaryReader:
    """Sequential little-endian reader that reports truncation with the file name."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.data = read_bytes(path)
        self.offset = 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.offset + size > len(self.data):
            raise DatasetError(f"{self.path}: file is truncated at byte {self.offset}")
        values = struct.unpack_from("<" + fmt, self.data, self.offset)
        self.offset += size
        return values

    def skip(self, size: int) -> None:
        if self.offset + size > len(self.data):
            raise DatasetError(f"{self.path}: file is truncated at byte {self.offset}")
        self.offset += size

    def read_string(self) -> str:
        end = self.data.find(b"\x00", self.offset)
        if end < 0:
            raise DatasetError(f"{self.path}: unterminated image name at byte {self.offset}")
        text = self.data[self.offset:end].decode("utf-8", errors="replace")
        self.offset = end + 1
        return text

    def finish(self) -> None:
        if self.offset != len(self.data):
            raise DatasetError(f"{self.path}: {len(self.data) - self.offset} unexpected trailing "
                               f"bytes")


def read_cameras_binary(path: str) -> dict[int, ColmapCamera]:
    reader = _BinaryReader(path)
    cameras = {}
    for _ in range(reader.read("Q")[0]):
        camera_id, model_id, width, height = reader.read("iiQQ")
        if model_id not in MODEL_NAMES_BY_ID:
            raise DatasetError(f"{path}: unknown camera model id {model_id} (camera {camera_id})")
        model = MODEL_NAMES_BY_ID[model_id]
        params = np.array(reader.read("d" * CAMERA_MODELS[model][1]))
        cameras[camera_id] = ColmapCamera(camera_id, model, width, height, params)
    reader.finish()
    return cameras


def read_images_binary(path: str) -> dict[int, ColmapImage]:
    reader = _BinaryReader(path)
    images = {}
    for _ in range(reader.read("Q")[0]):
        image_id, qw, qx, qy, qz, tx, ty, tz, camera_id = reader.read("idddddddi")
        name = reader.read_string()
        num_points2d = reader.read("Q")[0]
        reader.skip(24 * num_points2d)  # (x, y, point3D_id) per observation
        images[image_id] = ColmapImage(image_id, np.array([qw, qx, qy, qz]),
                                       np.array([tx, ty, tz]), camera_id, name)
    reader.finish()
    return images


def read_points3d_binary(path: str) -> tuple[np.ndarray, np.ndarray]:
    reader = _BinaryReader(path)
    count = reader.read("Q")[0]
    xyz = np.empty((min(count, len(reader.data) // 43), 3))
    rgb = np.empty((xyz.shape[0], 3), dtype=np.uint8)
    for index in range(count):
        values = reader.read("QdddBBBd")
        if index >= xyz.shape[0]:
            raise DatasetError(f"{path}: file is truncated at byte {reader.offset}")
        xyz[index] = values[1:4]
        rgb[index] = values[4:7]
        reader.skip(8 * reader.read("Q")[0])  # track: (image_id, point2D_idx) int32 pairs
    reader.finish()
    return xyz[:count], rgb[:count]


def _text_lines(path: str) -> list[tuple[int, str]]:
    """(line number, content) of the non-comment lines, empty lines kept."""
    text = read_text(path, errors="replace")
    return [(number, line.strip()) for number, line in enumerate(text.splitlines(), 1)
            if not line.lstrip().startswith("#")]


def read_cameras_text(path: str) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in _text_lines(path):
        if not line:
            continue
        fields = line.split()
        if len(fields) < 4:
            raise DatasetError(f"{path}:{number}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS")
        model = fields[1]
        if model not in CAMERA_MODELS:
            raise DatasetError(f"{path}:{number}: unknown camera model {model!r}")
        expected = CAMERA_MODELS[model][1]
        if len(fields) - 4 != expected:
            raise DatasetError(f"{path}:{number}: {model} needs {expected} parameters, "
                               f"got {len(fields) - 4}")
        try:
            camera = ColmapCamera(int(fields[0]), model, int(fields[2]), int(fields[3]),
                                  np.array([float(v) for v in fields[4:]]))
        except ValueError:
            raise DatasetError(f"{path}:{number}: non-numeric camera field") from None
        cameras[camera.camera_id] = camera
    return cameras


def read_images_text(path: str) -> dict[int, ColmapImage]:
    images = {}
    lines = _text_lines(path)
    index = 0
    while index < len(lines):
        number, line = lines[index]
        index += 1
        if not line:
            continue
        fields = line.split(maxsplit=9)
        if len(fields) < 10:
            raise DatasetError(f"{path}:{number}: expected IMAGE_ID QW QX QY QZ TX TY TZ "
                               f"CAMERA_ID NAME")
        try:
            image = ColmapImage(int(fields[0]), np.array([float(v) for v in fields[1:5]]),
                                np.array([float(v) for v in fields[5:8]]), int(fields[8]),
                                fields[9])
        except ValueError:
            raise DatasetError(f"{path}:{number}: non-numeric image field") from None
        images[image.image_id] = image
        index += 1  # the POINTS2D line that follows every image line (possibly empty)
    return images


def read_points3d_text(path: str) -> tuple[np.ndarray, np.ndarray]:
    xyz, rgb = [], []
    for number, line in _text_lines(path):
        if not line:
            continue
        fields = line.split()
        if len(fields) < 8:
            raise DatasetError(f"{path}:{number}: expected POINT3D_ID X Y Z R G B ERROR TRACK")
        try:
            xyz.append([float(v) for v in fields[1:4]])
            rgb.append([int(v) for v in fields[4:7]])
        except ValueError:
            raise DatasetError(f"{path}:{number}: non-numeric point field") from None
    return (np.array(xyz, dtype=np.float64).reshape(-1, 3),
            np.clip(np.array(rgb, dtype=np.int64).reshape(-1, 3), 0, 255).astype(np.uint8))


def _pick(folder: str, stem: str, required: bool) -> str | None:
    for extension in (".bin", ".txt"):
        path = os.path.join(folder, stem + extension)
        if os.path.isfile(path):
            return path
    if required:
        raise DatasetError(f"{os.path.join(folder, stem)}.bin: file not found (nor {stem}.txt)")
    return None


def read_model(folder: str) -> ColmapModel:
    """Read ``cameras``, ``images`` and (optional) ``points3D`` from ``folder``, preferring
    the binary files when both forms exist."""
    cameras_path = _pick(folder, "cameras", True)
    images_path = _pick(folder, "images", True)
    points_path = _pick(folder, "points3D", False)
    cameras = (read_cameras_binary if cameras_path.endswith(".bin")
               else read_cameras_text)(cameras_path)
    images = (read_images_binary if images_path.endswith(".bin")
              else read_images_text)(images_path)
    xyz = rgb = None
    if points_path is not None:
        xyz, rgb = (read_points3d_binary if points_path.endswith(".bin")
                    else read_points3d_text)(points_path)
    return ColmapModel(cameras, images, xyz, rgb, cameras_path, images_path)


def write_model_binary(folder: str, cameras: list[ColmapCamera], images: list[ColmapImage],
                       points_xyz: np.ndarray, points_rgb: np.ndarray) -> None:
    """Write a sparse model in COLMAP's binary format (images without 2D observations,
    points with empty tracks)."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "cameras.bin"), "wb") as handle:
        handle.write(struct.pack("<Q", len(cameras)))
        for camera in cameras:
            handle.write(struct.pack("<iiQQ", camera.camera_id, CAMERA_MODELS[camera.model][0],
                                     camera.width, camera.height))
            handle.write(struct.pack("<" + "d" * len(camera.params), *camera.params))
    with open(os.path.join(folder, "images.bin"), "wb") as handle:
        handle.write(struct.pack("<Q", len(images)))
        for image in images:
            handle.write(struct.pack("<idddddddi", image.image_id, *image.qvec, *image.tvec,
                                     image.camera_id))
            handle.write(image.name.encode("utf-8") + b"\x00")
            handle.write(struct.pack("<Q", 0))
    with open(os.path.join(folder, "points3D.bin"), "wb") as handle:
        handle.write(struct.pack("<Q", len(points_xyz)))
        for index, (position, color) in enumerate(zip(points_xyz, points_rgb)):
            handle.write(struct.pack("<QdddBBBdQ", index + 1, *position, *color, 0.0, 0))


def write_model_text(folder: str, cameras: list[ColmapCamera], images: list[ColmapImage],
                     points_xyz: np.ndarray, points_rgb: np.ndarray) -> None:
    """Write a sparse model in COLMAP's text format."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "cameras.txt"), "w", encoding="utf-8") as handle:
        handle.write("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n")
        for camera in cameras:
            params = " ".join(repr(float(v)) for v in camera.params)
            handle.write(f"{camera.camera_id} {camera.model} {camera.width} {camera.height} "
                         f"{params}\n")
    with open(os.path.join(folder, "images.txt"), "w", encoding="utf-8") as handle:
        handle.write("# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                     "# POINTS2D[] as (X, Y, POINT3D_ID)\n")
        for image in images:
            pose = " ".join(repr(float(v)) for v in (*image.qvec, *image.tvec))
            handle.write(f"{image.image_id} {pose} {image.camera_id} {image.name}\n\n")
    with open(os.path.join(folder, "points3D.txt"), "w", encoding="utf-8") as handle:
        handle.write("# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]\n")
        for index, (position, color) in enumerate(zip(points_xyz, points_rgb)):
            coordinates = " ".join(repr(float(v)) for v in position)
            handle.write(f"{index + 1} {coordinates} {int(color[0])} {int(color[1])} "
                         f"{int(color[2])} 0.0\n")
