"""Dataset loaders: the same known cameras written in every format must come back equal."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from data_scenes import (HEIGHT, KNOWN_POINTS, WIDTH, rig, view_pixels, write_blender,
                         write_colmap, write_dtu)
from fracture_gs.data import (DatasetError, detect_format, load_blender, load_colmap,
                              load_dataset, load_dtu)
from fracture_gs.data.images import downscaled_size

PIXEL_TOLERANCE = 1e-3


def assert_same_projection(loaded, truth, points=KNOWN_POINTS, loaded_points=None):
    assert len(loaded) == len(truth)
    for camera, expected in zip(loaded, truth):
        uv, depth = camera.project(points if loaded_points is None else loaded_points)
        uv_expected, depth_expected = expected.project(points)
        assert (depth > 0).all()
        torch.testing.assert_close(uv, uv_expected, atol=PIXEL_TOLERANCE, rtol=0)
        assert (camera.width, camera.height) == (expected.width, expected.height)


@pytest.mark.parametrize("with_extension", [False, True])
def test_blender_cameras_images_and_alpha(tmp_path, with_extension):
    cameras = rig(3)
    write_blender(str(tmp_path), cameras, "train", with_extension)
    write_blender(str(tmp_path), rig(5)[3:], "test")
    assert detect_format(str(tmp_path)) == "blender"
    black = load_dataset(str(tmp_path))
    assert black.format == "blender" and len(black) == 3
    assert_same_projection(black.cameras, cameras)
    rgba = view_pixels(1, 4).astype(np.float32) / 255.0
    alpha = torch.from_numpy(rgba[:, :, 3])
    torch.testing.assert_close(black.masks[1], alpha)
    torch.testing.assert_close(black.images[1], torch.from_numpy(rgba[:, :, :3]) * alpha[..., None])
    white = load_blender(str(tmp_path), white_background=True)
    torch.testing.assert_close(white.images[1], torch.from_numpy(rgba[:, :, :3]) * alpha[..., None]
                               + (1 - alpha[..., None]))
    assert white.background == (1.0, 1.0, 1.0)
    test = load_dataset(str(tmp_path), split="test")
    assert len(test) == 2 and test.image_paths[0].endswith("r_0.png")
    assert len(load_dataset(str(tmp_path), split="all")) == 5


@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_PINHOLE", "OPENCV"])
@pytest.mark.parametrize("binary", [True, False])
def test_colmap_binary_and_text(tmp_path, model, binary):
    cameras = rig(4, cx_offset=1.3, fy_ratio=1.0 if model == "SIMPLE_PINHOLE" else 1.1)
    points, colors = write_colmap(str(tmp_path), cameras, model, binary)
    assert detect_format(str(tmp_path)) == "colmap"
    dataset = load_dataset(str(tmp_path))
    assert dataset.format == "colmap" and dataset.masks is None
    assert [p.rsplit("/", 1)[-1] for p in dataset.image_paths] == [f"view_{i:02d}.png"
                                                                   for i in range(4)]
    assert_same_projection(dataset.cameras, cameras)
    np.testing.assert_allclose(dataset.points, points, rtol=1e-6)
    np.testing.assert_allclose(dataset.point_colors, colors / 255.0, rtol=1e-6)
    torch.testing.assert_close(dataset.images[2], torch.from_numpy(view_pixels(2) / 255.0).float())


def test_colmap_masks_and_holdout(tmp_path):
    cameras = rig(5)
    write_colmap(str(tmp_path), cameras, with_masks=True)
    dataset = load_colmap(str(tmp_path))
    assert dataset.masks.shape == (5, HEIGHT, WIDTH)
    assert dataset.masks[3, 3:13, 3:20].min() == 1.0 and dataset.masks[3].sum() == 10 * 17
    train = load_dataset(str(tmp_path), split="train", holdout_every=2)
    test = load_dataset(str(tmp_path), split="test", holdout_every=2)
    assert_same_projection(train.cameras, [cameras[1], cameras[3]])
    assert_same_projection(test.cameras, [cameras[0], cameras[2], cameras[4]])
    with pytest.raises(DatasetError, match="no test split"):
        load_dataset(str(tmp_path), split="test")


def test_dtu_normalised_cameras(tmp_path):
    cameras = rig(3, cx_offset=0.7, fy_ratio=0.95)
    scale_mat = write_dtu(str(tmp_path), cameras)
    assert detect_format(str(tmp_path)) == "dtu"
    dataset = load_dataset(str(tmp_path))
    assert dataset.format == "dtu" and dataset.masks.shape == (3, HEIGHT, WIDTH)
    np.testing.assert_allclose(dataset.scale_mat, scale_mat)
    # a point of the normalised frame is scale_mat @ point in the world the truth lives in
    world = KNOWN_POINTS.double() * scale_mat[0, 0] + torch.from_numpy(scale_mat[:3, 3])
    assert_same_projection(dataset.cameras, cameras, points=world.float(),
                           loaded_points=KNOWN_POINTS)
    assert dataset.masks[1, 2:20, 1:13].min() == 1.0 and dataset.masks[1].sum() == 18 * 12
    assert len(load_dtu(str(tmp_path), split="test", holdout_every=3)) == 1


@pytest.mark.parametrize("factor,width,height", [(2, 20, 15), (4, 10, 8)])
def test_downscale_scales_intrinsics_and_averages_pixels(tmp_path, factor, width, height):
    cameras = rig(2, cx_offset=1.3, fy_ratio=1.1)
    write_colmap(str(tmp_path), cameras, with_masks=True)
    full = load_dataset(str(tmp_path))
    small = load_dataset(str(tmp_path), downscale=factor)
    assert small.images.shape == (2, height, width, 3) and small.masks.shape == (2, height, width)
    for camera_full, camera_small in zip(full.cameras, small.cameras):
        uv_full, _ = camera_full.project(KNOWN_POINTS)
        uv_small, _ = camera_small.project(KNOWN_POINTS)
        scale = torch.tensor([width / WIDTH, height / HEIGHT])
        torch.testing.assert_close(uv_small, uv_full * scale, atol=1e-4, rtol=0)
    if factor == 2:  # 2x2 block averages
        blocks = full.images[0].reshape(height, 2, width, 2, 3).mean(dim=(1, 3))
        torch.testing.assert_close(small.images[0], blocks, atol=1e-5, rtol=0)


def test_downscaled_size_rules():
    assert downscaled_size(3200, 1800, -1) == (1600, 900)
    assert downscaled_size(1200, 900, -1) == (1200, 900)
    assert downscaled_size(801, 601, 2) == (400, 300)
    assert downscaled_size(800, 600, 8) == (100, 75)
    for bad in (0, -2, 1.5):
        with pytest.raises(ValueError, match="downscale"):
            downscaled_size(800, 600, bad)


def test_scene_bounds_and_subset(tmp_path):
    cameras = rig(4)
    write_colmap(str(tmp_path), cameras)
    dataset = load_dataset(str(tmp_path))
    centers = torch.stack([camera.center for camera in cameras])
    center, radius = dataset.scene_bounds()
    torch.testing.assert_close(center, centers.mean(0), atol=1e-5, rtol=0)
    assert radius == pytest.approx(1.1 * float((centers - centers.mean(0)).norm(dim=1).max()),
                                   rel=1e-5)
    part = dataset.subset([2, 0])
    assert len(part) == 2 and part.image_paths == [dataset.image_paths[2], dataset.image_paths[0]]
    torch.testing.assert_close(part.images[1], dataset.images[0])
    moved = dataset.to(dataset.images.device)
    assert moved.images.device == dataset.images.device and len(moved) == 4
    torch.testing.assert_close(moved.cameras[1].world_to_camera, dataset.cameras[1].world_to_camera)
