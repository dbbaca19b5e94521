"""No command overwrites or deletes what it did not write, no two runs write one folder, and every
reader knows which run and which models its files came from.

* a folder the tools did not write is refused where a file is in the way, and the scene file
  itself is never written over;
* a manifest vouches only for the folder it was written in: a copy (``cp -a``) of a render
  folder or of a whole run keeps its files through every re-run;
* render and evaluate refuse files they did not write, take a lock, and a smaller render leaves
  no stale image of an earlier one;
* frames, checkpoints and renders carry their run (``run.json``, the checkpoint's ``run``,
  ``render.json``): a frame or checkpoint of another run, a missing last frame and a model
  retrained after the simulation are refused by every reader;
* user files, a copied manifest and a backup copy of a render folder survive simulate, render,
  evaluate, view, train, render -m, evaluate -m, the generator and the demo, fresh and re-run;
* a second run of each writing command into a folder that a first one is writing is refused
  with one line, and the first completes.

The simulations run on the ballistic stand-in of the solver (tests/test_simulate_cli.py): what is
tested is the folders, not the physics.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import yaml

from fracture_gs.cli import render as render_cli
from fracture_gs.cli import simulate as simulate_cli
from fracture_gs.cli.evaluate import main as evaluate_main
from fracture_gs.cli.train import main as train_main
from fracture_gs.folders.sim_reader import Simulation, SimulationError
from fracture_gs.io.manifest import MANIFEST_FILE, Manifest
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.pipeline import simulate as simulate_stage
from fracture_gs.pipeline.experiments.sim_eval import EvaluationError, read_rendered_frames
from render_scenes import block_scene, lattice_block, write_model
from test_data_safety import FIXTURE, TINY_TRAIN, small_scene, write_yaml
from test_simulate_cli import BallisticSolver

CPU = ["--device", "cpu"]
RENDER = ["--views", "orbit:1", "--resolution", "16", "16", *CPU]
EVALUATE = ["--views", "orbit:1", "--resolution", "16", "16", "--no-lpips", "--no-fid", "--quiet",
            *CPU]


def _ballistic(built: Any, device: torch.device, backend: str) -> BallisticSolver:
    return BallisticSolver(built.particles, built.materials, built.domain, gravity=built.gravity,
                           cfl=built.cfl, object_names=built.object_names, device=device)


@pytest.fixture(scope="module", autouse=True)
def ballistic() -> Iterator[None]:
    """Every simulation of this module on the ballistic stand-in of the solver."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(simulate_stage, "create_solver", _ballistic)
        yield


def simulate(out: Path, frames: int = 2, **changes: Any) -> Path:
    """simulate.py of the small scene (with ``changes`` to its ball) into ``out``."""
    scene = small_scene(frames=frames)
    scene["objects"][0].update(changes)
    path = write_yaml(out.parent / f"{out.name}.yaml", scene)
    assert simulate_cli.main(["--scene", str(path), "--out", str(out), *CPU]) == 0
    return out


def one_line(code: int, capsys: pytest.CaptureFixture, *needles: str) -> str:
    """The one ``error:`` line of a run that exited with status 2 (a concurrent first run's
    warnings aside)."""
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if not line.startswith("warning: ")]
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    for needle in needles:
        assert needle in err[0], err[0]
    return err[0]


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file below ``root`` (relative path -> content)."""
    return {path.relative_to(root).as_posix(): path.read_bytes()
            for path in sorted(root.rglob("*")) if path.is_file()}


# ----------------------------------------------------------------------------- keepsakes


@pytest.fixture(scope="module")
def originals(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A simulation folder and its render folder, to copy as a user would."""
    sim = simulate(tmp_path_factory.mktemp("originals") / "sim")
    assert render_cli.main(["--sim", str(sim), *RENDER]) == 0
    return sim, sim / "renders"


def plant(folder: Path, originals: tuple[Path, Path]) -> dict[Path, bytes]:
    """A user's file, a copied manifest (part of a run copied with its ``.written.json``) and a
    backup copy of a render folder (``cp -a``) in ``folder``; returns every file planted."""
    sim, renders = originals
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "notes_of_the_user.txt").write_text(f"kept: {folder}\n")
    subprocess.run(["cp", "-a", str(renders), str(folder / "renders_backup_v1")], check=True)
    copied = folder / "copied_run"
    copied.mkdir()
    for name in (MANIFEST_FILE, "scene.yaml", "diagnostics.csv", "frames"):
        subprocess.run(["cp", "-a", str(sim / name), str(copied / name)], check=True)
    return {path: path.read_bytes()
            for path in [folder / "notes_of_the_user.txt",
                         *(folder / "renders_backup_v1").rglob("*"), *copied.rglob("*")]
            if path.is_file()}


def assert_kept(planted: dict[Path, bytes]) -> None:
    for path, content in planted.items():
        assert path.is_file(), f"{path} was deleted"
        assert path.read_bytes() == content, f"{path} was overwritten"


# ----------------------------------------------------------------------------- no file in the way


def test_simulate_refuses_a_folder_of_the_users_own_files(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture) -> None:
    """A user's folder holding diagnostics.csv, checkpoint.npz, a frame and the scene file: no
    file is replaced or removed, and the scene file is never written over."""
    project = tmp_path / "proj"
    scene = project / "scene.yaml"
    scene.parent.mkdir()
    scene.write_text("# my comments\n" + yaml.safe_dump(small_scene(frames=1), sort_keys=False))
    (project / "diagnostics.csv").write_text("my,own,table\n")
    (project / "checkpoint.npz").write_bytes(b"my checkpoint")
    (project / "frames").mkdir()
    (project / "frames" / "frame_00042.npz").write_bytes(b"my frame")
    before = snapshot(project)
    code = simulate_cli.main(["--scene", str(scene), "--out", str(project), *CPU])
    one_line(code, capsys, "--out", f"holds the scene file {scene} itself")
    copy = write_yaml(tmp_path / "scene.yaml", small_scene(frames=1))
    code = simulate_cli.main(["--scene", str(copy), "--out", str(project), *CPU])
    one_line(code, capsys, "--out", "is in the way", "the tools did not write it")
    assert snapshot(project) == before
    # the scene file of a simulation folder is its input too
    sim = simulate(tmp_path / "sim", frames=1)
    scene_text = (sim / "scene.yaml").read_bytes()
    code = simulate_cli.main(["--scene", str(sim / "scene.yaml"), "--out", str(sim), *CPU])
    one_line(code, capsys, "holds the scene file")
    assert (sim / "scene.yaml").read_bytes() == scene_text
    # a folder holding nothing in the way is written, its files kept
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine\n")
    assert simulate_cli.main(["--scene", str(copy), "--out", str(mine), *CPU]) == 0
    assert (mine / "notes.txt").read_text() == "mine\n"


def test_a_copied_run_vouches_for_nothing(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A backup of the renders (cp -a) survives a re-run of the simulation, and a copy of a
    whole run is not taken for the tools' own folder."""
    sim = simulate(tmp_path / "sims" / "bk")
    assert render_cli.main(["--sim", str(sim), *RENDER]) == 0
    backup = sim / "renders_backup_v1"
    subprocess.run(["cp", "-a", str(sim / "renders"), str(backup)], check=True)
    kept = snapshot(backup)
    simulate(sim)
    assert snapshot(backup) == kept
    assert not (sim / "renders" / "orbit_00" / "00000.png").exists()   # the tools' own: replaced
    copy = tmp_path / "sims" / "bk_copy"
    subprocess.run(["cp", "-a", str(sim), str(copy)], check=True)
    kept = snapshot(copy)
    code = simulate_cli.main(["--scene", str(tmp_path / "sims" / "bk.yaml"), "--out", str(copy),
                              *CPU])
    one_line(code, capsys, "is in the way", "vouches for nothing")
    assert snapshot(copy) == kept
    assert Simulation.open(copy).frames == [0, 1, 2]   # a copy is still a readable run


def test_render_and_evaluate_refuse_files_they_did_not_write(
        originals: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    sim, _ = originals
    user = tmp_path / "userdir"
    (user / "orbit_00").mkdir(parents=True)
    (user / "render.json").write_text("{}\n")
    (user / "timing.csv").write_text("my timings\n")
    (user / "orbit_00" / "00000.png").write_bytes(b"my picture")
    before = snapshot(user)
    code = render_cli.main(["--sim", str(sim), "--out", str(user), *RENDER])
    one_line(code, capsys, "--out", "is in the way")
    assert snapshot(user) == before
    code = render_cli.main(["--sim", str(sim), "--out", str(sim), *RENDER])
    one_line(code, capsys, "--out", "holds the output of simulate.py")
    evaluation = tmp_path / "evaluation"
    evaluation.mkdir()
    (evaluation / "report.md").write_text("my report\n")
    (evaluation / "metrics.json").write_text("{}\n")
    before = snapshot(evaluation)
    code = evaluate_main(["--sim", str(sim), "--out", str(evaluation), *EVALUATE])
    one_line(code, capsys, "--out", "is in the way")
    assert snapshot(evaluation) == before


def test_a_smaller_render_leaves_no_stale_images(originals: tuple[Path, Path],
                                                 tmp_path: Path) -> None:
    sim, _ = originals
    out = tmp_path / "renders"
    assert render_cli.main(["--sim", str(sim), "--out", str(out), "--views", "orbit:2",
                            "--resolution", "16", "16", *CPU]) == 0
    assert render_cli.main(["--sim", str(sim), "--out", str(out), "--frames", "1", *RENDER]) == 0
    pngs = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png"))
    assert pngs == ["orbit_00/00001.png"]
    assert not (out / "video_orbit_01.mp4").exists()
    info = json.loads((out / "render.json").read_text())
    assert info["frames"] == [1] and info["views"] == ["orbit_00"] and info["complete"]
    with pytest.raises(EvaluationError, match="frame 0 was not rendered"):
        read_rendered_frames(out, ["orbit_00"], [0, 1])


def test_compare_refuses_an_mls_baseline_of_another_scene(
        originals: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from fracture_gs.pipeline.experiments.sim_eval import check_same_scene

    sim, _ = originals
    scene = small_scene(frames=2)
    scene["contact"] = {"mode": "mls"}
    scene["objects"][0]["velocity"] = [0, 0, -2]
    other = tmp_path / "other_mls"
    assert simulate_cli.main(["--scene", str(write_yaml(tmp_path / "o.yaml", scene)),
                              "--out", str(other), *CPU]) == 0
    code = evaluate_main(["--sim", str(sim), "--compare", "--mls", str(other), *EVALUATE])
    one_line(code, capsys, f"--mls {other}: not the scene of {sim}",
             "'objects[0].velocity[2]'")
    scene["objects"][0]["velocity"] = small_scene()["objects"][0]["velocity"]
    same = tmp_path / "same_mls"
    assert simulate_cli.main(["--scene", str(write_yaml(tmp_path / "s.yaml", scene)),
                              "--out", str(same), *CPU]) == 0
    check_same_scene(Simulation.open(same), Simulation.open(sim))   # the same scene passes


# ----------------------------------------------------------------------------- outputs know their inputs


def test_render_refuses_a_model_retrained_after_the_simulation(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    points, surface = lattice_block((0.06, 0.06, 0.06))
    model = tmp_path / "model"
    write_model(model, points, surface)
    scene = block_scene(model, {"translate": [0.5, 0.5, 0.5]})
    scene["frames"] = 1
    sim = tmp_path / "sim"
    assert simulate_cli.main(["--scene", str(write_yaml(tmp_path / "b.yaml", scene)),
                              "--out", str(sim), *CPU]) == 0
    assert render_cli.main(["--sim", str(sim), *RENDER]) == 0
    write_model(model, points, surface, seed=1)   # retrained: other Gaussians, same particles
    code = render_cli.main(["--sim", str(sim), "--out", str(tmp_path / "r"), *RENDER])
    one_line(code, capsys, "objects[0].model", "retrained")
    assert not (tmp_path / "r").exists()
    code = simulate_cli.main(["--scene", str(tmp_path / "b.yaml"), "--out", str(sim), "--frames",
                              "2", "--resume", *CPU])
    one_line(code, capsys, "--resume", "retrained")


def test_a_missing_last_frame_is_refused_by_every_reader(
        originals: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    sim = tmp_path / "sim"
    shutil.copytree(originals[0], sim)
    SimLayout(sim).frame_path(2).unlink()
    message = f"{SimLayout(sim).frame_path(2)} is missing (the run wrote frames 0..2)"
    one_line(render_cli.main(["--sim", str(sim), *RENDER]), capsys, message)
    one_line(evaluate_main(["--sim", str(sim), *EVALUATE]), capsys, message)
    pytest.importorskip("viser")
    from fracture_gs.cli import view as view_cli

    one_line(view_cli.main([str(sim), "--port", "0", *CPU]), capsys, message)


def test_a_frame_or_checkpoint_of_another_run_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    first = simulate(tmp_path / "first")
    second = simulate(tmp_path / "second", velocity=[0, 0, -2])   # same particles, other run
    shutil.copy(SimLayout(first).frame_path(1), SimLayout(second).frame_path(1))
    with pytest.raises(SimulationError, match=r"frame_00001\.npz was not written by the run"):
        Simulation.open(second)
    one_line(render_cli.main(["--sim", str(second), *RENDER]), capsys, "was not written by the run")
    third = simulate(tmp_path / "third", velocity=[0, 0, -2])
    shutil.copy(SimLayout(first).checkpoint_path, SimLayout(third).checkpoint_path)
    code = simulate_cli.main(["--scene", str(tmp_path / "third.yaml"), "--out", str(third),
                              "--frames", "3", "--resume", *CPU])
    one_line(code, capsys, "--resume", "checkpoint.npz: belongs to another run")


def test_resume_leaves_no_folder_and_keeps_the_scene(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    scene = write_yaml(tmp_path / "small.yaml", small_scene(frames=3))
    missing = tmp_path / "no_such_run"
    code = simulate_cli.main(["--scene", str(scene), "--out", str(missing), "--resume", *CPU])
    one_line(code, capsys, "--resume", "holds no run to resume")
    assert not missing.exists()
    sim = tmp_path / "sim"
    assert simulate_cli.main(["--scene", str(scene), "--out", str(sim), *CPU]) == 0
    stored = (sim / "scene.yaml").read_bytes()
    assert simulate_cli.main(["--scene", str(scene), "--out", str(sim), "--resume", "--frames",
                              "1", *CPU]) == 0
    assert "nothing to simulate" in capsys.readouterr().out
    assert (sim / "scene.yaml").read_bytes() == stored


def test_a_damaged_frame_stops_the_render_before_it_writes(
        originals: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture) -> None:
    sim = tmp_path / "sim"
    shutil.copytree(originals[0], sim, ignore=shutil.ignore_patterns("renders"))
    frame = SimLayout(sim).frame_path(1)
    intact = frame.read_bytes()
    frame.write_bytes(intact[:len(intact) // 2])
    one_line(render_cli.main(["--sim", str(sim), *RENDER]), capsys, str(frame), "damaged")
    assert not (sim / "renders").exists()
    # damage that only reading the arrays finds: the render's files are removed again
    frame.write_bytes(intact)
    original = Simulation.load_frame

    def damaged_at_frame_1(self: Simulation, index: int, device: Any = None) -> Any:
        if index == 1:
            raise SimulationError(f"{frame}: not a readable .npz file (BadZipFile)")
        return original(self, index, device)

    monkeypatch.setattr(Simulation, "load_frame", damaged_at_frame_1)
    one_line(render_cli.main(["--sim", str(sim), *RENDER]), capsys, str(frame))
    assert not [p for p in (sim / "renders").rglob("*") if p.is_file()]


# ----------------------------------------------------------------------------- one writer per folder


def concurrently(first: Callable[[], int], second: Callable[[], int], monkeypatch: pytest.MonkeyPatch,
                 owner: Any, name: str) -> tuple[int, int]:
    """Run ``first`` in a thread until it calls ``owner.name`` (or ``owner[name]`` of a dict;
    inside its lock), then ``second`` here; returns both exit statuses once ``first`` has
    finished."""
    original = owner[name] if isinstance(owner, dict) else getattr(owner, name)
    inside, release = threading.Event(), threading.Event()
    main = threading.main_thread()

    def paused(*args: Any, **kwargs: Any) -> Any:
        if threading.current_thread() is not main and not inside.is_set():
            inside.set()
            assert release.wait(300)
        return original(*args, **kwargs)

    if isinstance(owner, dict):
        monkeypatch.setitem(owner, name, paused)
    else:
        monkeypatch.setattr(owner, name, paused)
    status: dict[str, int] = {}

    def run_first() -> None:
        try:
            status["first"] = first()
        finally:
            inside.set()

    thread = threading.Thread(target=run_first)
    thread.start()
    try:
        assert inside.wait(300) and "first" not in status, f"the first run ended early: {status}"
        second_status = second()
    finally:
        release.set()
        thread.join(300)
    return status["first"], second_status


def test_two_simulations_or_renders_or_evaluations_into_one_folder(
        originals: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture) -> None:
    from fracture_gs.folders import sim_writer
    from fracture_gs.pipeline import render as render_stage
    from fracture_gs.pipeline.experiments import sim_report

    sim = tmp_path / "sim"
    scene = write_yaml(tmp_path / "small.yaml", small_scene(frames=2))
    argv = ["--scene", str(scene), "--out", str(sim), *CPU]
    codes = concurrently(lambda: simulate_cli.main(argv), lambda: simulate_cli.main(argv),
                         monkeypatch, sim_writer.SimulationOutput, "write_frame")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another simulate.py run is writing this simulation folder")
    assert Simulation.open(sim).frames == [0, 1, 2]

    argv = ["--sim", str(sim), *RENDER]
    codes = concurrently(lambda: render_cli.main(argv),
                         lambda: render_cli.main([*argv, "--no-fpgo", "--out", str(sim / "renders")]),
                         monkeypatch, render_stage, "write_render_info")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another render.py run is writing this render folder")
    assert json.loads((sim / "renders" / "render.json").read_text())["fpgo"] is True

    argv = ["--sim", str(sim), *EVALUATE]
    codes = concurrently(lambda: evaluate_main(argv), lambda: evaluate_main(argv), monkeypatch,
                         sim_report, "evaluate_run")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another evaluate.py run is writing this evaluation folder")
    assert (sim / "evaluation" / "report.md").is_file()
    assert not list(sim.rglob(".*.lock"))   # the locks go with their runs


# ----------------------------------------------------------------------------- every command


def test_simulate_render_evaluate_and_view_keep_what_they_did_not_write(
        originals: tuple[Path, Path], tmp_path: Path) -> None:
    sim = tmp_path / "sim"
    planted = plant(sim, originals)                 # a fresh run into a folder holding them
    simulate(sim)
    layout = SimLayout(sim)
    planted |= plant(layout.frames_dir, originals)
    for folder in (layout.renders_dir(True), layout.evaluation_dir):
        planted |= plant(folder, originals)
        if folder == layout.evaluation_dir:
            assert evaluate_main(["--sim", str(sim), *EVALUATE]) == 0
        else:
            assert render_cli.main(["--sim", str(sim), *RENDER]) == 0
        planted |= plant(folder / "orbit_00" if folder.name == "renders" else folder / "sub",
                         originals)
    assert render_cli.main(["--sim", str(sim), *RENDER]) == 0      # re-runs of each
    assert evaluate_main(["--sim", str(sim), *EVALUATE]) == 0
    simulate(sim)
    assert_kept(planted)
    pytest.importorskip("viser")
    from fracture_gs.viewer.app import Viewer, ViewerOptions
    from fracture_gs.viewer.sources import SimulationSource
    from fracture_gs.testing.headless_browser import WebsocketProbe

    before = snapshot(sim)
    viewer = Viewer(SimulationSource(sim, torch.device("cpu")),
                    ViewerOptions(port=0, grace_seconds=0.2))
    viewer.start()
    try:
        assert viewer.wait_until_shown(0, timeout=30)
        probe = WebsocketProbe(int(viewer.url.rsplit(":", 1)[1]))
        probe.close()
    finally:
        viewer.stop()
    assert snapshot(sim) == before                  # the viewer writes nothing


@pytest.mark.mitsuba
def test_the_generator_keeps_what_it_did_not_write(
        originals: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture) -> None:
    from fracture_gs.data.synthetic import generator
    from fracture_gs.data.synthetic.__main__ import main as synthetic_main

    out = tmp_path / "teapot"
    argv = ["--object", "teapot", "--out", str(out), "--width", "16", "--height", "16",
            "--n-train", "2", "--n-test", "1", "--spp", "1", "--grid", "16", "--quiet"]
    codes = concurrently(lambda: synthetic_main(argv), lambda: synthetic_main(argv), monkeypatch,
                         generator, "_generate")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another generator run is writing this dataset folder")
    planted = plant(out, originals) | plant(out / "train", originals)
    assert synthetic_main([*argv, "--force"]) == 0
    assert_kept(planted)
    copy = tmp_path / "teapot_copy"
    subprocess.run(["cp", "-a", str(out), str(copy)], check=True)
    before = snapshot(copy)
    code = synthetic_main([*argv[:3], str(copy), *argv[4:], "--force"])
    one_line(code, capsys, "a copied or moved dataset")
    assert snapshot(copy) == before


def test_train_render_m_and_evaluate_m_keep_what_they_did_not_write(
        originals: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture) -> None:
    from fracture_gs.folders import model_folder
    from fracture_gs.folders.model_folder import write_model_folder
    from fracture_gs.gaussians import GaussianModel

    model = tmp_path / "model"      # an earlier model, with renders of it
    count = 4
    write_model_folder(model, np.random.rand(count, 3), np.full(count, 1e-3), np.ones(count, bool),
                       np.arange(count), GaussianModel.from_points(torch.rand(count, 3)),
                       iteration=30)
    earlier = model / "test" / "ours_30"
    (earlier / "renders").mkdir(parents=True)
    (earlier / "renders" / "00000.png").write_bytes(b"old render")
    Manifest(earlier, ["renders/00000.png"], kind="model-render").save()
    planted = plant(model, originals) | plant(earlier, originals) | plant(model / "evaluation",
                                                                          originals)
    argv = ["-s", str(FIXTURE), "-m", str(model), *TINY_TRAIN]
    codes = concurrently(lambda: train_main(argv), lambda: train_main(argv), monkeypatch,
                         model_folder, "write_cfg_args")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another train.py run is writing this model folder")
    assert not (earlier / "renders" / "00000.png").exists()
    assert_kept(planted)
    from fracture_gs.pipeline import render_model
    from fracture_gs.pipeline.experiments import static_eval

    render = ["-m", str(model), "--quiet"]
    codes = concurrently(lambda: render_cli.main(render), lambda: render_cli.main(render),
                         monkeypatch, render_model, "_render_views")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another render.py -m run is writing this render folder")
    evaluate = ["-m", str(model), "--no-lpips", "--no-fid", *CPU]
    codes = concurrently(lambda: evaluate_main(evaluate), lambda: evaluate_main(evaluate),
                         monkeypatch, static_eval, "evaluate_model")
    assert codes[0] == 0
    one_line(codes[1], capsys, "another evaluate.py run is writing this evaluation folder")
    for split in ("train", "test"):
        planted |= plant(model / split / "ours_6" / "renders", originals)
    planted |= plant(model / "evaluation" / "sub", originals)
    assert render_cli.main(render) == 0
    assert evaluate_main(evaluate) == 0
    assert_kept(planted)


def test_the_demo_keeps_what_it_did_not_write(
        originals: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture) -> None:
    """The demo's own stages (scene, simulate, render, evaluate) at a few frames, its data and
    train stages standing in with model folders written in code (a real training is
    test_train_render_m_and_evaluate_m_keep_what_they_did_not_write's)."""
    from fracture_gs.cli import demo as demo_cli
    from fracture_gs.metrics.protocol import MetricNetworks
    from fracture_gs.pipeline import demo as demo_stage

    out = tmp_path / "demo"

    def data(demo: Any) -> None:
        for name in demo_stage.OBJECTS:
            write_yaml(demo.data / name / "transforms_train.json", {"frames": []})

    def train(demo: Any) -> None:
        for number, name in enumerate(demo_stage.OBJECTS):
            points, surface = lattice_block((0.05, 0.05, 0.03 + 0.02 * number), 0.025)
            parts = (points[:, 2] < 0).astype(np.int32) if name == "table" else None  # top, legs
            write_model(demo.model(name), points, surface, spacing=0.025, part_id=parts)

    tiny = demo_stage.PROFILES["tiny"]
    monkeypatch.setitem(demo_stage.PROFILES, "tiny", demo_stage.Profile(
        "tiny", tiny.image_size, tiny.n_train, tiny.n_test, tiny.spp, tiny.mesh_grid, tiny.train,
        tiny.teapot_train, grid=32, frames=2, views=1, render_size=16, window=1))
    monkeypatch.setitem(demo_stage.STAGE_FUNCTIONS, "data", data)
    monkeypatch.setitem(demo_stage.STAGE_FUNCTIONS, "train", train)
    load = MetricNetworks.load   # PSNR only: LPIPS and FID are not what is tested here
    monkeypatch.setattr(MetricNetworks, "load", lambda device, weights_dir=None, lpips=True,
                        fid=True: load(device, weights_dir, lpips=False, fid=False))
    planted = plant(out, originals) | plant(out / "evaluation", originals)
    argv = ["--profile", "tiny", "--out", str(out), *CPU]
    codes = concurrently(lambda: demo_cli.main(argv), lambda: demo_cli.main(argv), monkeypatch,
                         demo_stage.STAGE_FUNCTIONS, "scene")
    assert codes[0] == 0, capsys.readouterr().err
    one_line(codes[1], capsys, "another demo.py run is writing this demo folder")
    planted |= plant(out / "scenes", originals) | plant(out / "sims" / "teapot_table", originals)
    planted |= plant(out / "sims" / "teapot_table" / "renders", originals)
    assert demo_cli.main([*argv, "--force"]) == 0, capsys.readouterr().err
    assert_kept(planted)
    assert json.loads((out / "evaluation" / "metrics.json").read_text())["runs"]

