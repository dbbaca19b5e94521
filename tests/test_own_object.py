"""docs/own_object.md as a new user follows it: the commands of its tested bash block, in order,
with its scene YAML, on the shipped Blender-format fixture (tiny sizes: seconds); and its train.py
line on the same photos laid out as a COLMAP folder."""
from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fracture_gs.cli import render as render_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli import train as train_cli
from fracture_gs.data import load_dataset
from fracture_gs.data.colmap_io import ColmapCamera, ColmapImage, write_model_text

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "own_object.md"
ENTRY_POINTS = {"train.py": train_cli.main, "simulate.py": simulate_cli.main, "render.py": render_cli.main}


def doc_block(language: str) -> str:
    """The fenced block of ``language`` that follows a 'tested by tests/test_own_object.py' note."""
    pattern = re.compile(r"<!-- tested by tests/test_own_object\.py[^>]*-->\n```" + language + r"\n(.*?)```",
                         re.DOTALL)
    blocks = pattern.findall(DOC.read_text())
    assert len(blocks) == 1, f"expected one tested {language} block in {DOC}"
    return blocks[0]


def run_line(line: str) -> None:
    words = shlex.split(line, comments=True)
    if not words:
        return
    if words[0] == "cp":   # cp -r <fixture in the repository> <folder>
        assert words[1] == "-r" and len(words) == 4, line
        shutil.copytree(ROOT / words[2], words[3])
        return
    assert words[0] == "python" and words[1] in ENTRY_POINTS, f"not a documented command: {line}"
    assert ENTRY_POINTS[words[1]](words[2:]) == 0, line


def test_the_documented_steps_train_simulate_and_render(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_scene.yaml").write_text(doc_block("yaml"))
    for line in doc_block("bash").splitlines():
        run_line(line)
    model = tmp_path / "output" / "my_object"
    assert (model / "particles.ply").is_file() and (model / "mesh.ply").is_file()
    sim = tmp_path / "output" / "sims" / "my_scene"
    frames = sorted((sim / "frames").glob("frame_*.npz"))
    assert len(frames) == 7   # frame 0 and the scene's 6 frames
    start, end = (np.load(frames[i])["x"] for i in (0, -1))
    assert end[:, 2].mean() < start[:, 2].mean()   # it fell
    renders = sim / "renders"
    assert len(list(renders.glob("*/00006.png"))) == 2 and list(renders.glob("video_*.mp4"))


def blender_to_colmap(blender: Path, colmap: Path) -> None:
    """The Blender-format fixture as a COLMAP folder: sparse/0 (text), images/ and masks/."""
    cameras, images = [], []
    (colmap / "images").mkdir(parents=True)
    (colmap / "masks").mkdir()
    for split in ("train", "test"):
        data = load_dataset(str(blender), split=split)
        for camera, image, mask in zip(data.cameras, data.images, data.masks):
            index = len(cameras) + 1
            name = f"{split}_{index:03d}.png"
            cameras.append(ColmapCamera(index, "PINHOLE", camera.width, camera.height,
                                        np.array([camera.fx, camera.fy, camera.cx, camera.cy], dtype=float)))
            world_to_camera = camera.world_to_camera.double().numpy()
            x, y, z, w = Rotation.from_matrix(world_to_camera[:3, :3]).as_quat()
            images.append(ColmapImage(index, np.array([w, x, y, z]), world_to_camera[:3, 3].copy(), index, name))
            rgb = (image.clamp(0, 1).numpy() * 255).round().astype(np.uint8)
            cv2.imwrite(str(colmap / "images" / name), rgb[:, :, ::-1])
            cv2.imwrite(str(colmap / "masks" / name), ((mask.numpy() > 0.5) * 255).astype(np.uint8))
    write_model_text(str(colmap / "sparse" / "0"), cameras, images, np.zeros((1, 3)), np.zeros((1, 3), np.uint8))


def test_the_documented_train_command_on_a_colmap_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The train.py line of docs/own_object.md on the same photos laid out as a COLMAP folder."""
    monkeypatch.chdir(tmp_path)
    blender_to_colmap(ROOT / "tests" / "data" / "synthetic_fixture", tmp_path / "my_photos")
    train_line = next(line for line in doc_block("bash").splitlines() if line.startswith("python train.py"))
    run_line(train_line)
    assert (tmp_path / "output" / "my_object" / "particles.ply").is_file()


def test_the_own_object_steps_name_every_dataset_layout_the_loader_reads() -> None:
    """The README's own-object steps and this page name the Blender, COLMAP and DTU layouts (the
    DTU one by its files), the hold-out for a test split and the placement of the object."""
    readme = (ROOT / "README.md").read_text()
    steps = readme[readme.index("## Your own object"):readme.index("## Materials")]
    page = DOC.read_text()
    for text in (steps, page):
        for needle in ("Blender", "COLMAP", "DTU", "cameras_sphere.npz", "--holdout-every",
                       "placement"):
            assert needle in text, needle
