"""docs/own_object.md as a new user follows it: the commands of its tested bash block, in order,
with its scene YAML, on the shipped Blender-format fixture (tiny sizes: seconds)."""
from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

from fracture_gs.cli import render as render_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli import train as train_cli

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
