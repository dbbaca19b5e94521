"""A real capture end to end: twelve photos of the DTU scan65 skull (tests/data/dtu_skull_mini,
100x75 pixels, with masks; its README.md says where they come from) go through train.py with a
held-out test split, render.py -m and evaluate.py -m, keep the table out of the splats, and land
in a scene the right way up by their recorded up direction alone."""
from __future__ import annotations

import ast
import contextlib
import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from fracture_gs.cli import evaluate as evaluate_cli
from fracture_gs.cli import render as render_cli
from fracture_gs.cli import render_model as render_model_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli.train import main as train_main
from fracture_gs.config.scene import parse_scene
from fracture_gs.data import load_dataset
from fracture_gs.io.object_frame import read_object_frame
from fracture_gs.io.particles_ply import read_particles_ply
from fracture_gs.metrics.halo import DEFAULT_DILATE_PX, halo, outside_mask
from fracture_gs.mpm.scene import build_scene, rotation_matrix_xyz

ROOT = Path(__file__).resolve().parents[1]
SKULL = ROOT / "tests" / "data" / "dtu_skull_mini"
TINY = ["--sdf-res", "32", "--sdf-iters", "8", "--iterations", "60", "--n-surface", "800",
        "--nv", "2", "--particle-res", "12", "--sdf-rays", "256", "--quiet"]
HOLDOUT = 4
# The normal of the table the skull stands on, in the dataset's normalised frame: a plane fitted
# (RANSAC, 1010 of 1024 points within 0.01) to SIFT features of the table, outside the masks,
# triangulated between neighbouring full-size (1600x1200) views of the whole scan. It is measured
# without the cameras' orientation, so it checks the up direction train.py estimates from them.
TABLE_NORMAL = np.array([0.1097, -0.3784, -0.9191])
TABLE_HEIGHT = -0.5446   # the table plane: x . TABLE_NORMAL = TABLE_HEIGHT


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


@pytest.fixture(scope="module")
def skull(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The mini skull trained with every 4th view held out; the model and train.py's output."""
    model = tmp_path_factory.mktemp("capture") / "skull"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert train_main(["-s", str(SKULL), "-m", str(model), "--holdout-every", str(HOLDOUT),
                           *TINY]) == 0
    return model, printed.getvalue()


def test_the_capture_is_small_and_says_where_it_comes_from() -> None:
    total = sum(f.stat().st_size for f in SKULL.rglob("*") if f.is_file())
    assert total < 400_000
    readme = (SKULL / "README.md").read_text()
    assert "jingz666/NeuF" in readme and "DTU" in readme and "licen" in readme.lower()
    train = load_dataset(str(SKULL), "train", holdout_every=HOLDOUT)
    test = load_dataset(str(SKULL), "test", holdout_every=HOLDOUT)
    assert (len(train), len(test)) == (9, 3) and (test.width, test.height) == (100, 75)


def test_the_data_check_prints_the_split_and_the_up_direction(capsys: pytest.CaptureFixture) -> None:
    from fracture_gs.data.__main__ import main as data_main

    assert data_main([str(SKULL), "--split", "test", "--holdout-every", str(HOLDOUT)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "views      3 of 100x75 pixels" in lines and "masks      yes" in lines
    up = next(line for line in lines if line.startswith("up "))
    vector = np.array([float(v) for v in up[up.index("[") + 1:up.index("]")].split(",")])
    assert angle_deg(vector, TABLE_NORMAL) < 10 and "level cameras" in up


def test_masks_composite_the_photos_on_the_training_background() -> None:
    """The table around the skull is gone from what the photometric fit sees: every pixel
    outside the mask is the background colour, black or white."""
    for white, colour in ((False, 0.0), (True, 1.0)):
        data = load_dataset(str(SKULL), "all", white_background=white)
        outside = data.masks == 0
        assert outside.sum() > 0.3 * outside.numel()
        assert (data.images[outside] == colour).all()
        inside = data.masks == 1   # the photo itself where the mask is solid
        assert data.images[inside].std() > 0.05


def test_holdout_split_feeds_training_rendering_and_evaluation(
        skull: tuple[Path, str], capsys: pytest.CaptureFixture) -> None:
    model, printed = skull
    call = ast.parse((model / "cfg_args").read_text(), mode="eval").body
    options = {k.arg: ast.literal_eval(k.value) for k in call.keywords}
    assert options["holdout_every"] == HOLDOUT and options["eval"] is True
    summary = json.loads((model / "timings.json").read_text())
    assert summary["test"]["views"] == 3 and summary["train"]["views"] == 9
    assert "test PSNR" in printed
    assert not (model / ".train.lock").exists()
    assert render_model_cli.main(["-m", str(model), "--quiet"]) == 0
    iteration = summary["iteration"]
    renders = sorted((model / "test" / f"ours_{iteration}" / "renders").glob("*.png"))
    assert len(renders) == 3 and len(list((model / "train" / f"ours_{iteration}" / "gt").glob("*.png"))) == 9
    capsys.readouterr()
    assert evaluate_cli.main(["-m", str(model), "--no-lpips", "--device", "cpu"]) == 0
    out = capsys.readouterr().out
    assert "test (3 views" in out and "PSNR" in out
    results = json.loads((model / "results.json").read_text())
    assert results[f"ours_{iteration}"]["PSNR"] > 12   # a tiny fit, far above an empty image


def test_no_table_in_the_splats(skull: tuple[Path, str]) -> None:
    """Around the skull the photos show the table; the test renders show the background there
    (what a few pixels of blur of this tiny fit leave aside)."""
    model, _ = skull
    assert render_model_cli.main(["-m", str(model), "--skip_train", "--quiet"]) == 0
    test = load_dataset(str(SKULL), "test", holdout_every=HOLDOUT)
    iteration = json.loads((model / "timings.json").read_text())["iteration"]
    for index, path in enumerate(test.image_paths):
        mask = test.masks[index].numpy()
        outside = outside_mask(mask, DEFAULT_DILATE_PX)
        photo = cv2.imread(path)[:, :, ::-1] / 255.0
        render = cv2.imread(str(model / "test" / f"ours_{iteration}" / "renders"
                                / f"{index:05d}.png"))[:, :, ::-1] / 255.0
        assert photo[outside].mean() > 0.15 and halo(photo, mask, test.background).share > 0.5
        assert render[outside].mean() < 0.05
        assert halo(render, mask, test.background).share < 0.15


def test_the_recorded_up_is_the_table_normal_and_the_underside_is_cut(
        skull: tuple[Path, str]) -> None:
    model, printed = skull
    frame = read_object_frame(model / "object.json")
    assert "object in model coordinates" in printed and "up [" in printed
    assert frame.up_source.startswith("level cameras")
    assert angle_deg(np.asarray(frame.up), TABLE_NORMAL) < 10
    # the silhouettes leave a keel under the skull, which train.py cuts off near the table
    summary = json.loads((model / "timings.json").read_text())
    cut = summary["underside_cut"]
    assert cut["depth"] > 0.1
    columns = read_particles_ply(model / "particles.ply")
    x = np.stack([columns[a] for a in "xyz"], axis=1).astype(np.float64)
    lowest = float((x @ TABLE_NORMAL).min())
    assert TABLE_HEIGHT - 0.15 < lowest < TABLE_HEIGHT + 0.1


def placed_scene(model: Path, **placement) -> dict:
    return {"name": "skull_on_the_floor",
            "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 24},
            "frames": 3, "frame_dt": 0.01,
            "boundaries": [{"type": "ground", "height": 0.2, "friction": 0.5},
                           {"type": "box", "condition": "slip"}],
            "objects": [{"name": "skull", "model": str(model),
                         "placement": {"size": 0.4, "centre": [0.5, 0.5], **placement},
                         "materials": [{"part": 0, "model": "elastic", "E": 2.0e4, "nu": 0.3,
                                        "density": 100}]}]}


def test_placement_stands_the_skull_on_the_ground_by_its_size_alone(
        skull: tuple[Path, str], tmp_path: Path) -> None:
    model, _ = skull
    config = parse_scene(placed_scene(model, yaw_deg=40))
    x = build_scene(config).particles.x.double().numpy()
    assert x[:, 2].min() == pytest.approx(0.2, abs=1e-5)      # resting on the ground
    assert (x.max(axis=0) - x.min(axis=0)).max() == pytest.approx(0.4, rel=1e-5)
    centre = 0.5 * (x.min(axis=0) + x.max(axis=0))
    assert centre[:2] == pytest.approx([0.5, 0.5], abs=1e-5)
    rotation = rotation_matrix_xyz(config.objects[0].transform.rotate_deg)
    up = np.asarray(read_object_frame(model / "object.json").up)
    assert angle_deg(rotation @ up, np.array([0.0, 0.0, 1.0])) < 1e-4
    assert angle_deg(rotation @ TABLE_NORMAL, np.array([0.0, 0.0, 1.0])) < 10
    # the scene stated only the size and placement; the resolved scene holds the transform
    again = parse_scene(config.to_dict())
    assert again.objects[0].transform == config.objects[0].transform


def test_the_placed_skull_rests_on_its_base(skull: tuple[Path, str], tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Three frames on the floor: it neither sinks nor tips over."""
    model, _ = skull
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / "skull.yaml"
    scene.write_text(yaml.safe_dump(placed_scene(model)))
    assert simulate_cli.main(["--scene", str(scene)]) == 0
    frames = sorted((tmp_path / "output" / "sims" / "skull_on_the_floor" / "frames").glob("frame_*.npz"))
    start, end = (np.load(frames[i])["x"].astype(np.float64) for i in (0, -1))
    assert end[:, 2].min() > 0.2 - 2 * (1 / 24)
    # the best rotation from start to end (Kabsch) turns it by a few degrees at most
    a, b = start - start.mean(axis=0), end - end.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    turn = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    assert np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1))) < 3
    # drawn from the held-out views, moved with the skull, on the black it was trained on
    sim = tmp_path / "output" / "sims" / "skull_on_the_floor"
    assert render_cli.main(["--sim", str(sim), "--views", "test", "--frames", "3",
                            "--resolution", "50", "38"]) == 0
    pictures = sorted((sim / "renders").glob("test_*/00003.png"))
    assert len(pictures) == 3
    image = cv2.imread(str(pictures[0]))
    assert image[0, 0].max() == 0 and image.max() > 100
