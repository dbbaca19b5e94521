"""Writers of tiny Blender / COLMAP / DTU scenes with known cameras, for the loader tests."""
from __future__ import annotations

import json
import math
import os

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from fracture_gs.data.colmap_io import (ColmapCamera, ColmapImage, write_model_binary,
                                        write_model_text)
from fracture_gs.render.camera import Camera

WIDTH, HEIGHT = 40, 30
KNOWN_POINTS = torch.tensor([[0.1, -0.05, 0.2], [-0.2, 0.15, -0.1], [0.0, 0.0, 0.0]])


def rig(count: int = 4, cx_offset: float = 0.0, fy_ratio: float = 1.0) -> list[Camera]:
    """Cameras on a ring around the origin looking at it (y is up in the world)."""
    cameras = []
    for index in range(count):
        angle = 2.0 * math.pi * index / count + 0.3
        eye = [2.5 * math.cos(angle), 0.7 + 0.2 * index, 2.5 * math.sin(angle)]
        base = Camera.look_at(eye, [0.0, 0.1, 0.0], [0.0, 1.0, 0.0], math.radians(50), WIDTH,
                              HEIGHT)
        cameras.append(Camera(base.world_to_camera.double(), base.fx, base.fx * fy_ratio,
                              base.cx + cx_offset, base.cy - 0.5 * cx_offset, WIDTH, HEIGHT))
    return cameras


def view_pixels(index: int, channels: int = 3, width: int = WIDTH,
                height: int = HEIGHT) -> np.ndarray:
    """Deterministic uint8 RGB(A) content of view ``index`` (in RGB order)."""
    rng = np.random.default_rng(100 + index)
    pixels = rng.integers(0, 256, size=(height, width, channels), dtype=np.uint8)
    if channels == 4:
        pixels[:, :, 3] = 0
        pixels[5:25, 8:30, 3] = 255
        pixels[10:12, 10:20, 3] = 128
    return pixels


def write_rgb(path: str, pixels: np.ndarray) -> None:
    """Write RGB / RGBA uint8 pixels with OpenCV (which expects BGR / BGRA)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        converted = cv2.cvtColor(pixels, cv2.COLOR_RGBA2BGRA)
    elif pixels.ndim == 3:
        converted = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    else:
        converted = pixels
    assert cv2.imwrite(path, converted)


def write_blender(root: str, cameras: list[Camera], split: str = "train",
                  with_extension: bool = False) -> None:
    """transforms_<split>.json (OpenGL camera-to-world) + RGBA PNGs."""
    fov_x = 2.0 * math.atan(0.5 * WIDTH / cameras[0].fx)
    frames = []
    for index, camera in enumerate(cameras):
        camera_to_world = np.linalg.inv(camera.world_to_camera.double().numpy())
        camera_to_world[:3, 1:3] *= -1.0  # OpenCV -> OpenGL camera axes
        name = f"./{split}/r_{index}"
        write_rgb(os.path.join(root, split, f"r_{index}.png"), view_pixels(index, 4))
        frames.append({"file_path": name + (".png" if with_extension else ""),
                       "rotation": 0.0, "transform_matrix": camera_to_world.tolist()})
    with open(os.path.join(root, f"transforms_{split}.json"), "w") as handle:
        json.dump({"camera_angle_x": fov_x, "frames": frames}, handle)


def colmap_entries(cameras: list[Camera], model: str) -> tuple[list, list]:
    colmap_cameras, colmap_images = [], []
    for index, camera in enumerate(cameras):
        if model == "SIMPLE_PINHOLE":
            params = [camera.fx, camera.cx, camera.cy]
        elif model == "PINHOLE":
            params = [camera.fx, camera.fy, camera.cx, camera.cy]
        else:  # OPENCV with zero distortion
            params = [camera.fx, camera.fy, camera.cx, camera.cy, 0.0, 0.0, 0.0, 0.0]
        colmap_cameras.append(ColmapCamera(index + 1, model, WIDTH, HEIGHT, np.array(params)))
        world_to_camera = camera.world_to_camera.double().numpy()
        x, y, z, w = Rotation.from_matrix(world_to_camera[:3, :3]).as_quat()
        colmap_images.append(ColmapImage(10 + index, np.array([w, x, y, z]),
                                         world_to_camera[:3, 3].copy(), index + 1,
                                         f"view_{index:02d}.png"))
    return colmap_cameras, colmap_images


def write_colmap(root: str, cameras: list[Camera], model: str = "PINHOLE", binary: bool = True,
                 with_masks: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """sparse/0 (binary or text) + images/ (+ masks/); returns the written points and colours."""
    colmap_cameras, colmap_images = colmap_entries(cameras, model)
    points = np.array([[0.1, 0.2, 0.3], [-1.0, 0.5, 2.0], [0.0, -0.25, 0.125]])
    colors = np.array([[255, 0, 0], [0, 128, 255], [7, 8, 9]], dtype=np.uint8)
    writer = write_model_binary if binary else write_model_text
    # reverse the order to check that the loader sorts by name
    writer(os.path.join(root, "sparse", "0"), colmap_cameras, colmap_images[::-1], points, colors)
    for index, image in enumerate(colmap_images):
        write_rgb(os.path.join(root, "images", image.name), view_pixels(index))
        if with_masks:
            mask = np.zeros((HEIGHT, WIDTH), np.uint8)
            mask[index:index + 10, 3:20] = 255
            write_rgb(os.path.join(root, "masks", image.name + ".png"), mask)
    return points, colors


def intrinsics_matrix(camera: Camera, integer_pixel_centres: bool) -> np.ndarray:
    shift = 0.5 if integer_pixel_centres else 0.0
    return np.array([[camera.fx, 0.0, camera.cx - shift], [0.0, camera.fy, camera.cy - shift],
                     [0.0, 0.0, 1.0]])


def write_dtu(root: str, cameras: list[Camera], scale: float = 1.7,
              offset: tuple[float, float, float] = (0.3, -0.2, 0.5),
              with_masks: bool = True) -> np.ndarray:
    """cameras_sphere.npz (world_mat = K [R|t] with integer pixel centres, scale_mat mapping the
    unit sphere to the world) + image/ + mask/; returns the scale_mat."""
    scale_mat = np.diag([scale, scale, scale, 1.0])
    scale_mat[:3, 3] = offset
    arrays = {}
    for index, camera in enumerate(cameras):
        world_mat = np.eye(4)
        world_mat[:3, :4] = intrinsics_matrix(camera, True) @ camera.world_to_camera.double().numpy()[:3]
        arrays[f"world_mat_{index}"] = world_mat * 3.7  # projective scale must not matter
        arrays[f"scale_mat_{index}"] = scale_mat
        write_rgb(os.path.join(root, "image", f"{index:03d}.png"), view_pixels(index))
        if with_masks:
            mask = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
            mask[2:20, index:index + 12] = 255
            write_rgb(os.path.join(root, "mask", f"{index:03d}.png"), mask)
    np.savez(os.path.join(root, "cameras_sphere.npz"), **arrays)
    return scale_mat
