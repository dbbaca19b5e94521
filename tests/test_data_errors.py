"""Malformed datasets fail with one DatasetError line naming the offending file."""
from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest

from data_scenes import (HEIGHT, WIDTH, rig, view_pixels, write_blender, write_colmap,
                         write_dtu, write_rgb)
from fracture_gs.data import DatasetError, load_dataset


def assert_fails(source, *needles, **kwargs):
    with pytest.raises(DatasetError) as info:
        load_dataset(str(source), **kwargs)
    message = str(info.value)
    assert "\n" not in message
    for needle in needles:
        assert str(needle) in message, message
    return message


def edit_json(path, edit):
    with open(path) as handle:
        content = json.load(handle)
    edit(content)
    with open(path, "w") as handle:
        json.dump(content, handle)


def test_unknown_folder_format(tmp_path):
    (tmp_path / "photos").mkdir()
    assert_fails(tmp_path, str(tmp_path), "unknown dataset format")
    assert_fails(tmp_path / "missing", "missing", "not found")


def test_blender_missing_image(tmp_path):
    write_blender(str(tmp_path), rig(2))
    os.remove(tmp_path / "train" / "r_1.png")
    assert_fails(tmp_path, os.path.join("train", "r_1"), "not found")


def test_blender_frame_missing_key(tmp_path):
    write_blender(str(tmp_path), rig(2))
    edit_json(tmp_path / "transforms_train.json", lambda c: c["frames"][1].pop("transform_matrix"))
    assert_fails(tmp_path, "transforms_train.json", "frame 1", "transform_matrix")
    edit_json(tmp_path / "transforms_train.json", lambda c: c.pop("camera_angle_x"))
    assert_fails(tmp_path, "transforms_train.json", "camera_angle_x")


def test_blender_nan_matrix_and_bad_json(tmp_path):
    write_blender(str(tmp_path), rig(2))
    def poison(content):
        content["frames"][0]["transform_matrix"][1][2] = float("nan")
    edit_json(tmp_path / "transforms_train.json", poison)
    assert_fails(tmp_path, "transforms_train.json", "NaN")
    (tmp_path / "transforms_train.json").write_text("{not json")
    assert_fails(tmp_path, "transforms_train.json", "invalid JSON")


def test_blender_missing_test_split(tmp_path):
    write_blender(str(tmp_path), rig(2))
    assert_fails(tmp_path, "transforms_test.json", "not found", split="test")


def test_inconsistent_image_sizes(tmp_path):
    write_blender(str(tmp_path), rig(3))
    write_rgb(str(tmp_path / "train" / "r_2.png"), view_pixels(2, 4, width=WIDTH + 2))
    assert_fails(tmp_path, "r_2.png", "inconsistent image size", f"{WIDTH + 2}x{HEIGHT}")


def test_unreadable_image(tmp_path):
    write_colmap(str(tmp_path), rig(2))
    (tmp_path / "images" / "view_01.png").write_bytes(b"this is not a png")
    assert_fails(tmp_path, "view_01.png", "cannot be decoded")


def test_colmap_image_size_differs_from_camera(tmp_path):
    write_colmap(str(tmp_path), rig(1))
    write_rgb(str(tmp_path / "images" / "view_00.png"), view_pixels(0, 3, height=HEIGHT - 4))
    assert_fails(tmp_path, "view_00.png", f"{WIDTH}x{HEIGHT - 4}", "camera")


def test_colmap_unknown_camera_model(tmp_path):
    write_colmap(str(tmp_path), rig(2), binary=False)
    path = tmp_path / "sparse" / "0" / "cameras.txt"
    path.write_text(path.read_text().replace("PINHOLE", "PINHOLE_3000"))
    assert_fails(tmp_path, "cameras.txt", "unknown camera model", "PINHOLE_3000")


def test_colmap_unknown_model_id_in_binary(tmp_path):
    write_colmap(str(tmp_path), rig(1))
    path = tmp_path / "sparse" / "0" / "cameras.bin"
    data = bytearray(path.read_bytes())
    data[12:16] = struct.pack("<i", 42)  # model id of the first camera
    path.write_bytes(bytes(data))
    assert_fails(tmp_path, "cameras.bin", "unknown camera model id 42")


def test_colmap_distorted_camera_is_refused(tmp_path):
    write_colmap(str(tmp_path), rig(2), model="OPENCV")
    path = tmp_path / "sparse" / "0" / "cameras.bin"
    data = bytearray(path.read_bytes())
    data[8 + 24 + 4 * 8:8 + 24 + 5 * 8] = struct.pack("<d", 0.05)  # k1 of the first camera
    path.write_bytes(bytes(data))
    assert_fails(tmp_path, "cameras.bin", "OPENCV", "distortion", "image_undistorter")


def test_colmap_fisheye_is_refused(tmp_path):
    write_colmap(str(tmp_path), rig(1), binary=False)
    path = tmp_path / "sparse" / "0" / "cameras.txt"
    lines = path.read_text().replace("PINHOLE", "OPENCV_FISHEYE").splitlines()
    lines[-1] += " 0.1 0.0 0.0 0.0"  # OPENCV_FISHEYE has 8 parameters
    path.write_text("\n".join(lines) + "\n")
    assert_fails(tmp_path, "cameras.txt", "unsupported model OPENCV_FISHEYE")


def test_colmap_truncated_binary(tmp_path):
    write_colmap(str(tmp_path), rig(2))
    path = tmp_path / "sparse" / "0" / "images.bin"
    path.write_bytes(path.read_bytes()[:-5])
    assert_fails(tmp_path, "images.bin", "truncated")


def test_colmap_missing_images_file_and_camera(tmp_path):
    write_colmap(str(tmp_path), rig(2), binary=False)
    cameras_txt = tmp_path / "sparse" / "0" / "cameras.txt"
    cameras_txt.write_text("\n".join(cameras_txt.read_text().splitlines()[:-1]) + "\n")
    assert_fails(tmp_path, "images.txt", "missing camera 2")
    os.remove(tmp_path / "sparse" / "0" / "images.txt")
    assert_fails(tmp_path, "images.bin", "not found")


def test_colmap_nan_pose(tmp_path):
    write_colmap(str(tmp_path), rig(2), binary=False)
    path = tmp_path / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    fields = lines[2].split()
    fields[5] = "nan"
    lines[2] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    assert_fails(tmp_path, "images.txt", "NaN")


def test_colmap_mask_size_mismatch_and_missing_mask(tmp_path):
    write_colmap(str(tmp_path), rig(2), with_masks=True)
    write_rgb(str(tmp_path / "masks" / "view_01.png.png"), np.zeros((HEIGHT, WIDTH - 1), np.uint8))
    assert_fails(tmp_path, "view_01.png.png", "mask is", f"{WIDTH - 1}x{HEIGHT}")
    os.remove(tmp_path / "masks" / "view_01.png.png")
    assert_fails(tmp_path, os.path.join("masks", "view_01.png"), "mask not found")


def test_dtu_missing_key_and_nan(tmp_path):
    write_dtu(str(tmp_path), rig(2))
    npz = tmp_path / "cameras_sphere.npz"
    arrays = dict(np.load(npz))
    arrays.pop("world_mat_1")
    np.savez(npz, **arrays)
    assert_fails(tmp_path, "cameras_sphere.npz", "world_mat_1")
    arrays["world_mat_1"] = arrays["world_mat_0"].copy()
    arrays["world_mat_1"][0, 0] = np.nan
    np.savez(npz, **arrays)
    assert_fails(tmp_path, "cameras_sphere.npz", "'world_mat_1'", "NaN")
    npz.write_bytes(b"garbage")
    assert_fails(tmp_path, "cameras_sphere.npz", "cannot be read")


def test_dtu_mask_count_mismatch(tmp_path):
    write_dtu(str(tmp_path), rig(3))
    os.remove(tmp_path / "mask" / "002.png")
    assert_fails(tmp_path, "mask", "2 masks for 3 images")


def test_dtu_skewed_camera_is_refused(tmp_path):
    write_dtu(str(tmp_path), rig(2))
    npz = tmp_path / "cameras_sphere.npz"
    arrays = dict(np.load(npz))
    shear = np.eye(4)
    shear[0, 1] = 0.2  # K[0,1] = 0.2 fy: far more than half a pixel over the image
    arrays["world_mat_1"] = shear @ arrays["world_mat_1"]
    np.savez(npz, **arrays)
    assert_fails(tmp_path, "cameras_sphere.npz", "'world_mat_1'", "skew")


# ----------------------------------------------------------------------------- unreadable files
# Issue 15, finding 5: a file without read permission used to escape as a PermissionError
# traceback (JSON, COLMAP, parts.json) or read as "cannot be decoded" (images via cv2.imread).


@pytest.fixture
def make_unreadable(monkeypatch):
    """``make_unreadable(path)`` takes the read permission away from ``path``.

    root reads any file whatever its mode, so when the tests run as root ``open`` is also made
    to refuse that path with the error the kernel gives everybody else.
    """
    import builtins
    import errno

    blocked: set[str] = set()
    real_open = builtins.open

    def guarded_open(file, *args, **kwargs):
        if isinstance(file, (str, os.PathLike)) and os.path.abspath(file) in blocked:
            raise PermissionError(errno.EACCES, "Permission denied", os.fspath(file))
        return real_open(file, *args, **kwargs)

    def block(path):
        os.chmod(path, 0)
        if os.geteuid() == 0:
            blocked.add(os.path.abspath(path))
            monkeypatch.setattr(builtins, "open", guarded_open)

    yield block
    for path in blocked:
        os.chmod(path, 0o644)


UNREADABLE_CASES = {
    "blender transforms": (lambda root: write_blender(root, rig(2)), "transforms_train.json"),
    "blender image": (lambda root: write_blender(root, rig(2)), os.path.join("train", "r_1.png")),
    "colmap cameras.bin": (lambda root: write_colmap(root, rig(2)),
                           os.path.join("sparse", "0", "cameras.bin")),
    "colmap images.txt": (lambda root: write_colmap(root, rig(2), binary=False),
                          os.path.join("sparse", "0", "images.txt")),
    "colmap mask": (lambda root: write_colmap(root, rig(2), with_masks=True),
                    os.path.join("masks", "view_00.png.png")),
    "dtu cameras": (lambda root: write_dtu(root, rig(2)), "cameras_sphere.npz"),
    "dtu image": (lambda root: write_dtu(root, rig(2)), os.path.join("image", "001.png")),
}


@pytest.mark.parametrize("case", sorted(UNREADABLE_CASES))
def test_unreadable_file_is_named(tmp_path, case, make_unreadable):
    write, relative = UNREADABLE_CASES[case]
    write(str(tmp_path))
    path = tmp_path / relative
    make_unreadable(path)
    assert_fails(tmp_path, f"{path}: cannot read (Permission denied)")


def run_data_cli(args, capsys):
    from fracture_gs.data.__main__ import main

    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_data_cli_unreadable_file_exits_2_with_one_line(tmp_path, make_unreadable, capsys):
    write_blender(str(tmp_path), rig(2))
    code, out, _ = run_data_cli([tmp_path], capsys)
    assert code == 0 and "views      2 of 40x30 pixels" in out
    image = tmp_path / "train" / "r_0.png"
    make_unreadable(image)
    code, out, err = run_data_cli([tmp_path], capsys)
    assert code == 2 and out == ""
    assert err == f"error: {image}: cannot read (Permission denied)\n"


def test_data_cli_unreadable_parts_file(tmp_path, make_unreadable, capsys):
    write_blender(str(tmp_path), rig(2))
    parts = tmp_path / "parts.json"
    parts.write_text(json.dumps({"format": "fracture_gs/parts-v1",
                                 "parts": [{"id": 0, "name": "body"}], "rules": []}))
    code, out, _ = run_data_cli([tmp_path], capsys)
    assert code == 0 and "parts      body (parts.json)" in out
    make_unreadable(parts)
    code, _, err = run_data_cli([tmp_path], capsys)
    assert code == 2 and err == f"error: {parts}: cannot read (Permission denied)\n"


@pytest.mark.parametrize("kind", ["file instead of folder", "folder instead of image",
                                  "empty image", "empty transforms"])
def test_data_cli_files_of_the_wrong_kind(tmp_path, kind, capsys):
    write_blender(str(tmp_path), rig(2))
    if kind == "file instead of folder":
        target, expected = tmp_path / "transforms_train.json", "is a file, expected a dataset folder"
    elif kind == "folder instead of image":
        os.remove(tmp_path / "transforms_train.json")
        write_colmap(str(tmp_path), rig(2))
        target = tmp_path / "images" / "view_01.png"
        os.remove(target)
        os.mkdir(target)
        expected = "is a folder, expected a file"
    elif kind == "empty image":
        target = tmp_path / "train" / "r_1.png"
        target.write_bytes(b"")
        expected = "empty file, expected an image"
    else:
        target = tmp_path / "transforms_train.json"
        target.write_bytes(b"")
        expected = "invalid JSON"
    source = target if kind == "file instead of folder" else tmp_path
    code, _, err = run_data_cli([source], capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"error: {target}: {expected}"), err


FIXTURE = os.path.join(os.path.dirname(__file__), "data", "synthetic_fixture")


def test_data_cli_mesh_check_compares_masks_with_the_mesh(capsys):
    code, out, err = run_data_cli([FIXTURE, "--mesh-check"], capsys)
    assert code == 0, err
    line = next(line for line in out.splitlines() if line.startswith("mesh check"))
    low = float(line.split("min ")[1].split(",")[0])
    assert 0.95 < low <= 1.0 and "over 5 views" in line  # the fixture's masks are renders of gt_mesh.ply


def test_data_cli_mesh_check_needs_masks_and_the_mesh(tmp_path, capsys):
    without_masks, without_mesh = tmp_path / "colmap", tmp_path / "blender"
    write_colmap(str(without_masks), rig(2))  # images/ without masks/
    code, out, err = run_data_cli([without_masks, "--mesh-check"], capsys)
    assert code == 2 and out == ""
    assert err.strip().splitlines() == [
        f"error: {without_masks}: --mesh-check needs masks (alpha channels or mask/)"]
    write_blender(str(without_mesh), rig(2))  # RGBA images, no gt_mesh.ply
    code, out, err = run_data_cli([without_mesh, "--mesh-check"], capsys)
    assert code == 2 and out == ""
    assert err.strip().splitlines() == [f"error: {without_mesh / 'gt_mesh.ply'}: file not found"]


def test_data_cli_mesh_check_names_a_broken_mesh(tmp_path, capsys):
    import shutil

    folder = tmp_path / "fixture"
    shutil.copytree(FIXTURE, folder)
    (folder / "gt_mesh.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    code, out, err = run_data_cli([folder, "--mesh-check"], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and out == "" and len(lines) == 1
    assert lines[0].startswith(f"error: {folder / 'gt_mesh.ply'}: cannot be read as a triangle mesh"), lines
