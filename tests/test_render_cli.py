"""render.py end to end: a real tiny simulation rendered to PNGs, MP4, GIF and timing.csv;
--export-ply read back and rasterized; bad input ends with one line and exit status 2."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

from fracture_gs.cli import render as cli
from fracture_gs.pipeline.render import TIMING_COLUMNS
from fracture_gs.render import rasterize
from fracture_gs.render.frame_gaussians import read_frame_ply
from render_scenes import (SPACING, block_scene, identity_frames, lattice_block, simulate_quietly,
                           write_model, write_sim)

SIZE = (65, 49)  # odd on purpose: the MP4 writer pads to even sizes


def tiny_collision() -> dict:
    material = {"part": 0, "model": "nacc", "E": 2.0e3, "nu": 0.3, "density": 100.0,
                "Jp0": 0.98, "beta": 0.5, "xi": 1.0, "M": 2.36}
    sphere = {"shape": "sphere", "radius": 0.12, "particles_per_cell": 4}
    return {"name": "tiny_render", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
            "frames": 1, "frame_dt": 0.004, "gravity": [0, 0, 0],
            "objects": [{"name": "a", "primitive": sphere, "transform": {"translate": [0.35, 0.5, 0.5]},
                         "velocity": [2, 0, 0], "materials": [material]},
                        {"name": "b", "primitive": sphere, "transform": {"translate": [0.65, 0.5, 0.5]},
                         "velocity": [-2, 0, 0], "materials": [material]}]}


@pytest.fixture(scope="module")
def tiny_sim(tmp_path_factory) -> Path:
    return simulate_quietly(tmp_path_factory.mktemp("render") / "sim", tiny_collision())


def test_renders_a_tiny_simulation_end_to_end(tiny_sim: Path, capsys):
    status = cli.main(["--sim", str(tiny_sim), "--views", "orbit:2", "--resolution", *map(str, SIZE)])
    assert status == 0
    out = tiny_sim / "renders"
    summary = capsys.readouterr().out.strip().splitlines()[-1]
    assert summary.startswith("rendered 2 frames x 2 views") and "ms per frame" in summary
    for view in ("orbit_00", "orbit_01"):
        for frame in (0, 1):
            image = cv2.imread(str(out / view / f"{frame:05d}.png"))
            assert image.shape == (SIZE[1], SIZE[0], 3)
            assert (image < 200).any()                     # the spheres are in the picture
        capture = cv2.VideoCapture(str(out / f"video_{view}.mp4"))
        assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 2
        frames = 0
        while capture.read()[0]:
            frames += 1
        assert frames == 2
        assert capture.get(cv2.CAP_PROP_FRAME_WIDTH) >= SIZE[0]
    with Image.open(out / "preview.gif") as gif:
        assert gif.n_frames == 2
    with open(out / "timing.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["frame"]) for r in rows] == [0, 1]
    assert set(TIMING_COLUMNS) == set(rows[0])
    assert all(int(r["gaussians"]) > 0 and float(r["raster_ms"]) > 0 for r in rows)
    assert not list(out.rglob(".*.tmp*"))                 # nothing half-written left


def test_no_fpgo_writes_its_own_folder(tiny_sim: Path):
    assert cli.main(["--sim", str(tiny_sim), "--views", "orbit:1", "--resolution", "32", "32",
                     "--no-fpgo", "--frames", "1"]) == 0
    assert (tiny_sim / "renders_nofpgo" / "orbit_00" / "00001.png").is_file()
    assert not (tiny_sim / "renders_nofpgo" / "orbit_00" / "00000.png").exists()


@pytest.fixture()
def cracked_block(tmp_path: Path) -> Path:
    """A trained-looking block (SH degree 3, rotated by its transform) broken in two at frame 1."""
    from fracture_gs.mpm.scene import rotation_matrix_xyz

    points, surface = lattice_block((0.06, 0.04, 0.04))
    write_model(tmp_path / "model", points, surface, sh_degree=3)
    transform = {"scale": 1.5, "rotate_deg": [0.0, 30.0, 40.0], "translate": [0.5, 0.5, 0.5]}
    rotation = rotation_matrix_xyz((0.0, 30.0, 40.0))
    rest = (0.5 + 1.5 * points @ rotation.T).astype(np.float32)
    count = points.shape[0]
    frames = identity_frames(rest, 2)
    frames[1]["x"] = (rest + 0.6 * SPACING * (points[:, :1] > 1e-6) * rotation[:, 0]).astype(np.float32)
    frames[1]["fractured"] = np.abs(points[:, 0]) < 1.5 * SPACING
    gaussian_index = np.full(count, -1)
    gaussian_index[np.nonzero(surface)[0]] = np.arange(int(surface.sum()))
    arrays = {"rest_x": rest, "obj_id": np.zeros(count, np.int32), "is_surface": surface,
              "gaussian_index": gaussian_index, "rest_volume": np.full(count, 2.7e-5, np.float32)}
    return write_sim(tmp_path / "sim", block_scene(tmp_path / "model", transform), arrays, frames)


def test_export_ply_renders_like_the_png(cracked_block: Path):
    assert cli.main(["--sim", str(cracked_block), "--views", "orbit:3", "--resolution", "64", "64",
                     "--background", "black", "--export-ply"]) == 0
    out = cracked_block / "renders"
    from fracture_gs.pipeline.views import resolve_views
    from fracture_gs.folders.sim_reader import Simulation

    sim = Simulation.open(cracked_block)
    views = resolve_views("orbit:3", sim, sim.frames, (64, 64))
    model, exclusive = read_frame_ply(out / "ply" / "frame_00001.ply")
    assert exclusive.dtype == torch.int64 and (exclusive >= 0).any()  # lens groups survive it
    for view in views:
        with torch.no_grad():
            rgb = rasterize(model.means, model.opacities, view.camera, scales=model.scales,
                            quats=model.rotations, sh=model.sh, exclusive=exclusive)["rgb"]
        png = cv2.imread(str(out / view.name / "00001.png"))[..., ::-1].astype(np.float64) / 255.0
        image = rgb.clamp(0.0, 1.0).numpy()                   # what a PNG can hold
        assert np.abs(image - png).max() <= 1.0 / 255.0 + 1e-6
        assert png.max() > 0.2


def run_failing(argv: list[str], capsys) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ")
    return err


def test_bad_inputs_stop_with_one_line(cracked_block: Path, tmp_path: Path, capsys):
    sim = str(cracked_block)
    assert "no such simulation folder" in run_failing(["--sim", str(tmp_path / "nothing")], capsys)
    assert "outside the run" in run_failing(["--sim", sim, "--frames", "3:7"], capsys)
    assert "unknown view spec" in run_failing(["--sim", sim, "--views", "spiral"], capsys)
    assert "orbit:N" in run_failing(["--sim", sim, "--views", "orbit:x"], capsys)
    assert "file not found" in run_failing(["--sim", sim, "--views", str(tmp_path / "c.json")], capsys)
    assert "--min-fragment" in run_failing(["--sim", sim, "--min-fragment", "0"], capsys)
    assert "--exposure" in run_failing(["--sim", sim, "--exposure", "1.5"], capsys)
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    assert "--out" in run_failing(["--sim", sim, "--out", str(blocker / "renders")], capsys)
    empty = tmp_path / "empty"
    shutil.copytree(cracked_block, empty)
    for frame in (empty / "frames").iterdir():
        frame.unlink()
    assert "no frame_*.npz" in run_failing(["--sim", str(empty)], capsys)
    shutil.rmtree(cracked_block.parent / "model")
    err = run_failing(["--sim", sim], capsys)
    assert "scene.yaml" in err and "model" in err and "does not exist" in err
    assert not (cracked_block / "renders").exists()


def test_model_option_goes_to_the_static_model_renderer(tmp_path, capsys):
    missing = tmp_path / "no_model"
    assert run_failing(["-m", str(missing)], capsys) == f"error: {missing}: model folder not found"


def _cameras_json(path: Path, **intrinsics: float) -> Path:
    """A one-camera 3DGS cameras.json looking at the domain centre from -y (OpenCV axes)."""
    import json

    camera = {"id": 0, "img_name": "front", "width": 32, "height": 24, "position": [0.5, -1.5, 0.5],
              "rotation": [[1, 0, 0], [0, 0, 1], [0, -1, 0]], "fx": 200.0, "fy": 200.0, **intrinsics}
    path.write_text(json.dumps([camera]))
    return path


@pytest.mark.parametrize("intrinsics", [{"fx": float("nan")}, {"fy": float("nan")},
                                        {"fx": float("inf")}, {"fx": 0.0}, {"fy": -30.0}])
def test_a_camera_with_a_bad_focal_length_is_refused(cracked_block: Path, tmp_path: Path, capsys,
                                                     intrinsics: dict[str, float]):
    cameras = _cameras_json(tmp_path / "cameras.json", **intrinsics)
    err = run_failing(["--sim", str(cracked_block), "--views", str(cameras)], capsys)
    assert str(cameras) in err and "camera 0" in err and "focal" in err
    assert not (cracked_block / "renders").exists()


def test_the_same_camera_with_a_valid_focal_length_renders(cracked_block: Path, tmp_path: Path):
    cameras = _cameras_json(tmp_path / "cameras.json")
    assert cli.main(["--sim", str(cracked_block), "--views", str(cameras), "--frames", "0"]) == 0
    image = cv2.imread(str(cracked_block / "renders" / "front" / "00000.png"))
    assert image.shape == (24, 32, 3) and (image < 200).any()   # the block is in the picture


@pytest.mark.parametrize("size", [("100000", "100000"), ("64", "9000"), ("0", "64")])
def test_an_unrenderable_resolution_is_one_line(cracked_block: Path, tmp_path: Path, capsys,
                                                size: tuple[str, str]):
    err = run_failing(["--sim", str(cracked_block), "--resolution", *size], capsys)
    assert err.startswith(f"error: --resolution: image size {size[0]}x{size[1]}")
    cameras = _cameras_json(tmp_path / "cameras.json", width=int(size[0]), height=int(size[1]))
    err = run_failing(["--sim", str(cracked_block), "--views", str(cameras)], capsys)
    assert str(cameras) in err and f"{size[0]}x{size[1]}" in err
    assert not (cracked_block / "renders").exists()


def test_help_lists_both_targets_and_model_path_renders_a_model(capsys, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "--sim SIM" in text and "-m MODEL, --model_path MODEL" in text
    missing = tmp_path / "missing"
    for flag in ("-m", "--model_path"):   # both go to render.py -m, not to the --sim parser
        assert cli.main([flag, str(missing)]) == 2
        assert capsys.readouterr().err.strip() == f"error: {missing}: model folder not found"
