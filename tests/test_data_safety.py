"""The on-disk homes keep data safe: one consistent iteration per model folder, a locked
simulation folder, re-runs and --force that remove only what the tools wrote, a reader that
refuses gaps and mixed runs, and an interrupted demo that says so."""
from __future__ import annotations

import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import yaml

from fracture_gs.cli import demo as demo_cli
from fracture_gs.cli import render as render_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli.train import main as train_main
from fracture_gs.config.scene import parse_scene
from fracture_gs.folders.model_folder import write_model_folder
from fracture_gs.folders.sim_reader import Simulation, SimulationError
from fracture_gs.gaussians import GaussianModel
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import Manifest
from fracture_gs.io.model_layout import latest_iteration, latest_point_cloud
from fracture_gs.io.sim_layout import LOCK_FILE, SimLayout
from fracture_gs.pipeline.experiments.runner import SimJob, run_jobs
from fracture_gs.pipeline.simulate import run_simulation

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "synthetic_fixture"
# the smallest run that writes every file of a model folder (visual hull only, 6 iterations)
TINY_TRAIN = ["--sdf-res", "16", "--sdf-iters", "0", "--iterations", "6", "--n-surface", "100",
              "--nv", "1", "--particle-res", "6", "--quiet"]


def small_scene(name: str = "small", frames: int = 3) -> dict[str, Any]:
    """One NACC sphere falling onto the ground on a 16³ grid (a few hundred particles)."""
    material = {"part": 0, "model": "nacc", "E": 2.0e3, "nu": 0.3, "density": 100.0,
                "Jp0": 0.98, "beta": 0.5, "xi": 1.0, "M": 2.36}
    return {"name": name, "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
            "frames": frames, "frame_dt": 0.01, "gravity": [0, 0, -9.8], "cfl": 0.4,
            "boundaries": [{"type": "ground", "height": 0.2}, {"type": "box", "condition": "slip"}],
            "objects": [{"name": "ball", "primitive": {"shape": "sphere", "radius": 0.12},
                         "transform": {"translate": [0.5, 0.5, 0.5]}, "velocity": [0, 0, -1],
                         "materials": [material]}]}


def simulate(out: Path, scene: dict[str, Any]) -> Path:
    run_simulation(parse_scene(scene), out, device=torch.device("cpu"), progress=False,
                   log=io.StringIO())
    return out


def write_yaml(path: Path, content: dict[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(content, sort_keys=False))
    return path


def put_user_files(folders: list[Path]) -> list[Path]:
    """A user's file in each folder (made if missing); returns their paths."""
    files = []
    for folder in folders:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "notes_of_the_user.txt"
        path.write_text(f"kept: {folder.name}\n")
        files.append(path)
    return files


def assert_survive(files: list[Path]) -> None:
    for path in files:
        assert path.is_file(), f"{path} was deleted"
        assert path.read_text() == f"kept: {path.parent.name}\n"


# ----------------------------------------------------------------------------- model folder


def test_retraining_leaves_only_the_new_iteration(tmp_path: Path) -> None:
    """An earlier run's higher iteration_N (and the renders made of it) go when a new run
    finishes, so readers pick the new Gaussians; a user's files stay."""
    model = tmp_path / "model"
    count = 4
    gaussians = GaussianModel.from_points(torch.rand(count, 3, dtype=torch.float64))
    write_model_folder(model, np.random.rand(count, 3), np.full(count, 1e-3), np.ones(count, bool),
                       np.arange(count), gaussians, iteration=30000)
    old_renders = model / "test" / "ours_30000"
    (old_renders / "renders").mkdir(parents=True)
    (old_renders / "renders" / "00000.png").write_bytes(b"old render")
    Manifest(old_renders, ["renders/00000.png"]).save()
    user = put_user_files([model, model / "point_cloud" / "iteration_30000", old_renders])
    assert latest_iteration(str(model)) == 30000

    assert train_main(["-s", str(FIXTURE), "-m", str(model), *TINY_TRAIN]) == 0
    assert latest_iteration(str(model)) == 6
    assert latest_point_cloud(model) == model / "point_cloud" / "iteration_6" / "point_cloud.ply"
    assert not (model / "point_cloud" / "iteration_30000" / "point_cloud.ply").exists()
    assert not (old_renders / "renders" / "00000.png").exists()
    assert_survive(user)


# ----------------------------------------------------------------------------- simulation folder


def test_second_simulate_into_a_locked_folder_is_refused(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "sim"
    scene = write_yaml(tmp_path / "small.yaml", small_scene())
    with folder_lock(out, LOCK_FILE, "simulate.py", "simulation folder"):  # the first run
        code = simulate_cli.main(["--scene", str(scene), "--out", str(out), "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "another simulate.py run is writing this simulation folder" in err[0]
    assert not SimLayout(out).frames_dir.exists()


def test_rerun_replaces_what_the_tools_wrote_and_keeps_user_files(tmp_path: Path) -> None:
    """A fresh run over a finished one: old frames, renders and evaluation go, user files in the
    folder and in every sub-folder stay, and the folder holds one run."""
    out = simulate(tmp_path / "sim", small_scene(frames=3))
    layout = SimLayout(out)
    renders, evaluation = layout.renders_dir(True), layout.evaluation_dir
    for folder, name in ((renders / "orbit_00", "00003.png"), (evaluation, "metrics.json")):
        folder.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text("from the earlier run")
        owner = renders if folder.parent == renders else folder
        manifest = Manifest.load(owner)
        manifest.add(folder / name)
        manifest.save()
    user = put_user_files([out, layout.frames_dir, renders, renders / "orbit_00", evaluation])
    kept_run = simulate(out / "kept_run", small_scene(frames=1))   # another run inside this one

    simulate(out, small_scene(frames=1))
    assert SimLayout(kept_run).frames_on_disk() == [0, 1]
    assert Simulation.open(kept_run).frames == [0, 1]
    assert layout.frames_on_disk() == [0, 1]
    assert not (renders / "orbit_00" / "00003.png").exists()
    assert not (evaluation / "metrics.json").exists()
    assert_survive(user)
    assert Simulation.open(out).frames == [0, 1]


def test_reader_refuses_a_missing_frame(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = simulate(tmp_path / "sim", small_scene(frames=3))
    SimLayout(out).frame_path(1).unlink()
    with pytest.raises(SimulationError, match=r"frame_00001\.npz is missing"):
        Simulation.open(out)
    code = render_cli.main(["--sim", str(out), "--views", "orbit:1", "--resolution", "16", "16",
                            "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "frame_00001.npz is missing" in err[0]
    assert not SimLayout(out).renders_dir(True).exists()


def test_reader_refuses_frames_of_another_run(tmp_path: Path,
                                              capsys: pytest.CaptureFixture) -> None:
    first = simulate(tmp_path / "first", small_scene(frames=3))
    second = simulate(tmp_path / "second", small_scene(frames=1))
    for frame in (2, 3):  # the longer run's tail copied over a shorter run
        shutil.copy(SimLayout(first).frame_path(frame), SimLayout(second).frame_path(frame))
    code = render_cli.main(["--sim", str(second), "--views", "orbit:1", "--resolution", "16", "16",
                            "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "frame_00002.npz was not written by the run" in err[0]


# ----------------------------------------------------------------------------- --force, clean-ups


def test_forced_sweep_rerun_keeps_user_files(tmp_path: Path) -> None:
    """evaluate.py --experiment --force re-runs its simulations through run_jobs(force=True):
    only the files the tools wrote are replaced."""
    out = tmp_path / "sims" / "small"
    job = SimJob.of(parse_scene(small_scene(frames=1)), out)
    run_jobs([job])
    user = put_user_files([out, SimLayout(out).frames_dir, SimLayout(out).renders_dir(False)])
    result = run_jobs([job], force=True)[0]
    assert not result.skipped
    assert SimLayout(out).frames_on_disk() == [0, 1]
    assert_survive(user)


def test_demo_simulate_stage_after_an_interrupt_keeps_finished_runs(tmp_path: Path) -> None:
    """demo.py re-run after Ctrl-C in the simulate stage: the finished run is kept, the other is
    simulated again, and user files in both folders stay."""
    from fracture_gs.pipeline.demo import PROFILES, Demo, stage_simulate

    demo = Demo(out=tmp_path / "demo", data=tmp_path / "data", profile=PROFILES["tiny"],
                force=False, device=torch.device("cpu"), weights_dir=None, workers=1,
                redone_from="simulate")
    for mode in ("collision", "mls"):
        write_yaml(demo.scene_path(mode), small_scene(name=f"small_{mode}", frames=1))
    finished = simulate(demo.sim("collision"),
                        yaml.safe_load(demo.scene_path("collision").read_text()))
    stamp = SimLayout(finished).frame_path(1).stat().st_mtime_ns
    half = demo.sim("mls")
    user = put_user_files([finished, SimLayout(finished).frames_dir, half])
    stage_simulate(demo)
    assert SimLayout(finished).frame_path(1).stat().st_mtime_ns == stamp   # kept, not re-run
    assert SimLayout(half).frames_on_disk() == [0, 1]
    assert_survive(user)


def test_synthetic_force_replaces_only_generated_files(tmp_path: Path) -> None:
    pytest.importorskip("mitsuba")
    from fracture_gs.data.synthetic.__main__ import main as synthetic_main

    out = tmp_path / "teapot"
    argv = ["--object", "teapot", "--out", str(out), "--width", "16", "--height", "16",
            "--n-train", "2", "--n-test", "1", "--spp", "1", "--grid", "16", "--quiet"]
    assert synthetic_main(argv) == 0
    (out / "train" / "r_1.png").rename(out / "train" / "r_9.png")   # a generated name, 9 > n_train
    manifest = Manifest.load(out)
    manifest.files = {name.replace("train/r_1.png", "train/r_9.png") for name in manifest.files}
    manifest.save()
    user = put_user_files([out, out / "train", out / "masks_handmade"])
    assert synthetic_main([*argv, "--force"]) == 0
    assert not (out / "train" / "r_9.png").exists()
    assert (out / "train" / "r_1.png").is_file() and (out / "transforms_train.json").is_file()
    assert_survive(user)


# ----------------------------------------------------------------------------- demo interrupt


def test_ctrl_c_in_the_demo_train_stage_says_interrupted(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "demo"
    for name in ("teapot", "table"):  # datasets present: the data stage keeps them
        write_yaml(out / "data" / name / "transforms_train.json", {"frames": []})

    def interrupted(*_args: Any, **_kwargs: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr("fracture_gs.pipeline.train.train_model", interrupted)
    code = demo_cli.main(["--profile", "tiny", "--out", str(out), "--device", "cpu"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 130
    assert len(err) == 1 and err[0].startswith("interrupted")
    assert "fail" not in err[0] and "checkpoint" not in err[0] and "chkpnt" not in err[0]
    assert set(json.loads((out / "stages.json").read_text())["stages"]) == {"data"}
