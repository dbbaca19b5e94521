"""demo.py end to end at the 'tiny' profile (48x48 images, 6 + 2 views, 300 Gaussians for the
table and 1200 for the hollow teapot, 8 frames on a 32^3 grid): datasets, training, scene, both
simulations, three renders, evaluation; then a second call that skips every finished stage."""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.metrics.shape import rigid_fit_residual

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.mitsuba
def test_tiny_demo_runs_end_to_end_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    command = [sys.executable, str(ROOT / "demo.py"), "--profile", "tiny", "--out", str(out)]
    started = time.perf_counter()
    first = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path)
    seconds = time.perf_counter() - started
    assert first.returncode == 0, first.stderr[-2000:]
    print(f"[demo] tiny profile end to end: {seconds:.0f} s")
    for path in ("sims/teapot_table/renders/video_orbit_00.mp4",
                 "sims/teapot_table/renders_nofpgo/video_orbit_00.mp4",
                 "sims/teapot_table_mls/renders_nofpgo/video_orbit_00.mp4",
                 "evaluation/metrics.json", "evaluation/report.md", "evaluation/strip.png",
                 "models/teapot/particles.ply", "models/table/particles.ply"):
        assert (out / path).is_file() and (out / path).stat().st_size > 0, path
    metrics = json.loads((out / "evaluation" / "metrics.json").read_text())
    assert [run["fpgo"] for run in metrics["runs"]] == [True, False, False]
    assert "teapot_table_mls" in metrics["runs"][2]["sim"]
    scene = (out / "scenes" / "teapot_table_mls.yaml").read_text()
    assert "mode: mls" in scene
    # the table is rigid: it keeps its shape in every frame and stands on the ground
    layout = SimLayout(out / "sims" / "teapot_table")
    table = np.load(layout.particles_path)["obj_id"] == 1
    rest = np.load(layout.frame_path(0))["x"][table]
    residuals = [rigid_fit_residual(rest, np.load(layout.frame_path(frame))["x"][table])
                 for frame in layout.frames_on_disk()]
    assert len(residuals) == 9 and max(residuals) <= 0.01, residuals
    assert "ours (collision + FPGO)" in first.stdout and "paper: ours" in first.stdout
    assert str(out / "evaluation" / "report.md") in first.stdout
    log = json.loads((out / "stages.json").read_text())
    assert set(log["stages"]) == {"data", "train", "scene", "simulate", "render", "evaluate"}

    again = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout.count("skipped") == 6
    assert json.loads((out / "stages.json").read_text()) == log


def test_demo_bad_options_are_one_line(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    for argv, needle in ((["--quick", "--profile", "tiny"], "--quick"),
                         (["--out", str(tmp_path / "file")], "--out"),
                         (["--workers", "0"], "--workers")):
        result = subprocess.run([sys.executable, str(ROOT / "demo.py"), *argv],
                                capture_output=True, text=True, cwd=tmp_path)
        assert result.returncode == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0], result.stderr


def test_demo_names_a_kept_dataset_made_at_other_sizes(tmp_path: Path) -> None:
    """A dataset left in the data folder is kept, but one made at other image sizes or view
    counts than the profile's is named as such (it trains a different model than the one docs/results.md reports)."""
    from fracture_gs.pipeline.demo import PROFILES, _dataset_mismatch

    profile = PROFILES["default"]
    settings = {"width": profile.image_size, "height": profile.image_size, "n_train": profile.n_train,
                "n_test": profile.n_test, "spp": profile.spp, "seed": 0, "resolution": profile.mesh_grid}
    (tmp_path / "generator.json").write_text(json.dumps({"settings": settings}))
    assert _dataset_mismatch(tmp_path, profile) == ""
    (tmp_path / "generator.json").write_text(json.dumps({"settings": dict(settings, width=400, height=400,
                                                                         n_train=100)}))
    note = _dataset_mismatch(tmp_path, profile)
    assert "400x400 with 100 + 8 views" in note and f"{profile.image_size}x{profile.image_size}" in note
    (tmp_path / "generator.json").unlink()
    assert "no generator.json" in _dataset_mismatch(tmp_path, profile)


def test_a_stage_made_with_other_settings_is_redone() -> None:
    """The stage log keeps what the demo's code decided (training sizes, the scene's materials and
    throw): a folder made by a version with other settings is redone, not reused."""
    from fracture_gs.pipeline.demo import PROFILES, Demo, stage_is_current, stage_settings

    demo = Demo(out=Path("unused"), data=Path("unused"), profile=PROFILES["tiny"], force=False,
                device=torch.device("cpu"), weights_dir=None, workers=1)
    scene = stage_settings(demo, "scene")
    logged = {"seconds": 1.0, "settings": json.loads(json.dumps(scene))}   # as stages.json holds it
    assert stage_is_current(logged, scene, outputs_exist=True)
    assert not stage_is_current(logged, {**scene, "speed": 4.0}, outputs_exist=True)
    assert not stage_is_current({"seconds": 1.0}, scene, outputs_exist=True)   # a log without settings
    assert not stage_is_current(logged, scene, outputs_exist=False)
    assert not stage_is_current(None, scene, outputs_exist=True)
    assert stage_settings(demo, "train")["teapot"]["shell"] > 0     # the porcelain teapot is hollow
    assert "shell" not in stage_settings(demo, "train")["table"]
    assert stage_is_current({"seconds": 1.0, "settings": None}, stage_settings(demo, "data"), outputs_exist=True)
