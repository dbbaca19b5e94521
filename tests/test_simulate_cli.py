"""simulate.py: exit codes, output folder, diagnostics, blow-up handling and exact --resume.

Two kinds of tests:

* driver mechanics (always run): the solver is replaced by ``BallisticSolver``, a small
  deterministic particle integrator with the documented ``CollisionMPM`` interface, so the
  folder layout, checkpoint order and resume logic are tested independently of the physics;
* end-to-end with the real ``fracture_gs.mpm.solver.CollisionMPM`` (skipped until it exists).
"""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import yaml

from fracture_gs.cli import simulate as cli
from fracture_gs.pipeline import simulate as stage
from fracture_gs.config import load_scene
from fracture_gs.mpm.fragments import count_fragments, fragment_ids, object_link_radii
from fracture_gs.folders.sim_writer import diagnostics_columns
from fracture_gs.folders.sim_reader import load_frame, read_diagnostics_csv
from fracture_gs.mpm.types import SimState, SimulationBlowUp, StepStats

REPO = Path(__file__).resolve().parents[1]


def tiny_scene() -> dict[str, Any]:
    """Two small NACC spheres flying at each other on a 16³ grid (a few hundred particles)."""
    material = {"part": 0, "model": "nacc", "E": 2.0e3, "nu": 0.3, "density": 100.0,
                "Jp0": 0.98, "beta": 0.5, "xi": 1.0, "M": 2.36}
    return {
        "name": "tiny",
        "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
        "frames": 6,
        "frame_dt": 0.01,
        "gravity": [0, 0, -9.8],
        "cfl": 0.4,
        "boundaries": [{"type": "ground", "height": 0.2}, {"type": "box", "condition": "slip"}],
        "objects": [
            {"name": "left", "primitive": {"shape": "sphere", "radius": 0.12},
             "transform": {"translate": [0.36, 0.5, 0.5]}, "velocity": [2, 0, 0],
             "materials": [material]},
            {"name": "right", "primitive": {"shape": "sphere", "radius": 0.12},
             "transform": {"translate": [0.64, 0.5, 0.5]}, "velocity": [-2, 0, 0],
             "materials": [dict(material)]},
        ],
    }


def write_scene(path: Path, scene: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(scene, sort_keys=False))
    return path


# ----------------------------------------------------------------------------- test double


class BallisticSolver:
    """Deterministic stand-in with the CollisionMPM interface: free flight + gravity, clamped
    into the domain, adaptive substeps. It lets the driver be tested without the physics."""

    def __init__(self, particles: Any, materials: Any, domain: Any, *, contact: Any = None,
                 boundaries: Any = (), gravity: Any = (0, 0, -9.8), cfl: float = 0.3,
                 object_names: Any = (), backend: str = "auto",
                 device: torch.device = torch.device("cpu"), seed: int = 0) -> None:
        self.particles = particles.to(device)
        self.domain = domain
        self.gravity = torch.tensor(gravity, dtype=torch.float32, device=device)
        self.cfl = cfl
        self.object_names = list(object_names)
        n = len(particles)
        eye = torch.eye(3, device=device).expand(n, 3, 3).clone()
        self.state = SimState(x=self.particles.x.clone(), v=self.particles.v.clone(),
                              C=torch.zeros(n, 3, 3, device=device), F_E=eye,
                              material_state=torch.zeros(n, 1, device=device),
                              fractured=torch.zeros(n, dtype=torch.bool, device=device))

    def advance(self, frame_dt: float) -> StepStats:
        s = self.state
        x, v = s.x.clone(), s.v.clone()
        t, left, steps, dt_min, clamped = s.time, frame_dt, 0, float("inf"), 0
        lo = torch.tensor(self.domain.lower) + 3 * self.domain.dx
        hi = torch.tensor(self.domain.upper) - 3 * self.domain.dx
        while left > 1e-12 * frame_dt:
            dt = min(self.cfl * self.domain.dx / (float(v.norm(dim=1).max()) + 1.0), left)
            v = v + dt * self.gravity
            x = x + dt * v
            outside = ((x < lo) | (x > hi)).any(dim=1)
            clamped += int(outside.sum())
            x = torch.minimum(torch.maximum(x, lo), hi)
            if not torch.isfinite(x).all():
                raise SimulationBlowUp("non-finite position")
            t, left, steps, dt_min = t + dt, left - dt, steps + 1, min(dt_min, dt)
        self.state = SimState(x=x, v=v, C=s.C, F_E=s.F_E, material_state=s.material_state,
                              fractured=s.fractured | (x[:, 2] < 0.3), time=t,
                              step=s.step + steps)
        return StepStats(steps=steps, dt_min=dt_min, clamped=clamped)

    def diagnostics(self) -> dict[str, Any]:
        m = self.particles.mass.double()
        x, v = self.state.x.double(), self.state.v.double()
        g = self.gravity.double()

        def summary(mask: torch.Tensor) -> dict[str, Any]:
            mm = m[mask]
            return {"momentum": (mm[:, None] * v[mask]).sum(0),
                    "kinetic": 0.5 * (mm * (v[mask] ** 2).sum(1)).sum(),
                    "elastic": torch.zeros((), dtype=torch.float64),
                    "gravitational": -(mm * (x[mask] @ g)).sum()}

        total = summary(torch.ones_like(m, dtype=torch.bool))
        total["per_object"] = [summary(self.particles.obj_id == k)
                               for k in range(len(self.object_names))]
        total["fractured"] = int(self.state.fractured.sum())
        total["fragments"] = count_fragments(self.fragment_ids(), self.particles.obj_id)
        return total

    def fragment_ids(self) -> torch.Tensor:
        return fragment_ids(self.state.x, self.particles.obj_id,
                            object_link_radii(self.particles.rest_volume, self.particles.obj_id,
                                              len(self.object_names)))

    def state_in_input_order(self) -> SimState:
        return self.state  # never reorders its particles

    def frame_fields_in_input_order(self) -> dict[str, torch.Tensor]:
        return {"damage": torch.zeros_like(self.state.alpha)}  # no brittle material

    def state_dict(self) -> dict[str, Any]:
        s = self.state
        return {"x": s.x.clone(), "v": s.v.clone(), "C": s.C.clone(), "F_E": s.F_E.clone(),
                "material_state": s.material_state.clone(), "fractured": s.fractured.clone(), "time": s.time,
                "step": s.step}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        arrays = {k: torch.as_tensor(d[k]) for k in ("x", "v", "C", "F_E", "material_state", "fractured")}
        self.state = SimState(**arrays, time=float(d["time"]), step=int(d["step"]))


@pytest.fixture
def ballistic(monkeypatch: pytest.MonkeyPatch) -> None:
    """Run the driver on the BallisticSolver (materials are not needed either)."""
    monkeypatch.setattr(stage, "create_solver", lambda built, device, backend: BallisticSolver(
        built.particles, built.materials, built.domain, gravity=built.gravity, cfl=built.cfl,
        object_names=built.object_names, device=device))


def run_main(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def frames_of(out: Path) -> list[dict[str, np.ndarray]]:
    files = sorted((out / "frames").glob("frame_*.npz"))
    return [load_frame(f) for f in files]


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def assert_same_frames(a: Path, b: Path) -> None:
    fa, fb = frames_of(a), frames_of(b)
    assert len(fa) == len(fb)
    for frame_a, frame_b in zip(fa, fb):
        assert frame_a.keys() == frame_b.keys()
        for key in frame_a:
            assert frame_a[key].dtype == frame_b[key].dtype
            assert np.array_equal(frame_a[key], frame_b[key]), key


# ----------------------------------------------------------------------------- mechanics


def test_output_folder_layout(tmp_path: Path, ballistic: None,
                              capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    code, stdout, stderr = run_main(["--scene", str(scene), "--out", str(out),
                                     "--frames", "4", "--device", "cpu"], capsys)
    assert code == 0, stderr
    assert "momentum drift" in stdout and "fractured" in stdout and "clamped" in stdout
    assert "momentum balance" in stdout
    assert load_scene(out / "scene.yaml") == replace(load_scene(scene), frames=4)
    with np.load(out / "particles.npz") as particles:
        assert set(particles.files) >= {"mass", "rest_volume", "obj_id", "part_id",
                                        "is_surface", "rest_x", "gaussian_index"}
        n = particles["mass"].shape[0]
        assert particles["rest_x"].shape == (n, 3)
        obj = particles["obj_id"]
    frames = frames_of(out)
    assert len(frames) == 5
    for frame in frames:
        assert frame["x"].shape == (n, 3) and frame["x"].dtype == np.float32
        assert frame["v"].shape == (n, 3) and frame["F_E"].shape == (n, 3, 3)
        assert frame["alpha"].shape == (n,) and frame["fractured"].dtype == np.bool_
        assert frame["damage"].shape == (n,) and frame["damage"].dtype == np.float32
        assert all(np.isfinite(frame[k]).all() for k in ("x", "v", "F_E", "alpha"))
        # the connected piece of every particle; the two objects never share one
        assert frame["fragment_id"].shape == (n,) and frame["fragment_id"].dtype == np.int32
        assert not set(frame["fragment_id"][obj == 0]) & set(frame["fragment_id"][obj == 1])
    with open(out / "diagnostics.csv") as handle:
        header = next(csv.reader(handle))
    assert header == ["frame", "time", "steps", "dt_min", "px", "py", "pz", "kinetic",
                      "elastic", "gravitational", "total_energy", "fractured",
                      "left_px", "left_py", "left_pz", "left_kinetic",
                      "right_px", "right_py", "right_pz", "right_kinetic", "fragments",
                      "impulse_x", "impulse_y", "impulse_z", "dissipated_energy"]
    table = read_diagnostics_csv(out / "diagnostics.csv")
    assert table["frame"].tolist() == [0, 1, 2, 3, 4]
    assert np.allclose(table["time"], 0.01 * np.arange(5))
    assert (table["steps"][1:] > 0).all() and table["steps"][0] == 0
    assert np.allclose(table["total_energy"],
                       table["kinetic"] + table["elastic"] + table["gravitational"])
    assert np.allclose(table["px"], table["left_px"] + table["right_px"])
    # gravity: total z momentum falls by M g dt per frame
    mass = np.load(out / "particles.npz")["mass"].astype(np.float64).sum()
    assert np.allclose(np.diff(table["pz"]), -9.8 * 0.01 * mass, rtol=1e-4)
    assert (out / "diagnostics.png").stat().st_size > 1000
    assert not list(out.rglob(".*.tmp"))   # no temp files left behind


def test_resume_equals_uninterrupted_run(tmp_path: Path, ballistic: None,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    straight, pieces = tmp_path / "straight", tmp_path / "pieces"
    assert run_main(["--scene", str(scene), "--out", str(straight), "--frames", "6"],
                    capsys)[0] == 0
    assert run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "3"],
                    capsys)[0] == 0
    code, stdout, _ = run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "6",
                                "--resume"], capsys)
    assert code == 0
    assert_same_frames(straight, pieces)
    assert (straight / "diagnostics.csv").read_text() == (pieces / "diagnostics.csv").read_text()
    assert load_scene(pieces / "scene.yaml").frames == 6
    # resuming a finished run does nothing and succeeds
    code, stdout, _ = run_main(["--scene", str(scene), "--out", str(pieces), "--resume"],
                               capsys)
    assert code == 0 and "nothing to simulate" in stdout


@pytest.mark.parametrize("last_frame", ["missing", "truncated"])
def test_resume_after_kill_between_checkpoint_and_frame(
        tmp_path: Path, last_frame: str, ballistic: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    run_main(["--scene", str(scene), "--out", str(straight), "--frames", "5"], capsys)
    run_main(["--scene", str(scene), "--out", str(killed), "--frames", "3"], capsys)
    # the checkpoint of frame 3 is written before frame 3's file: a kill in between leaves
    # the checkpoint ahead of the frames. It holds that frame's exact state, so a resume
    # rewrites the frame (also when the file was damaged afterwards).
    frame_3 = killed / "frames" / "frame_00003.npz"
    if last_frame == "missing":
        frame_3.unlink()
    else:
        _truncate(frame_3)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(killed), "--frames", "5",
                                "--resume"], capsys)
    assert code == 0, stderr
    assert_same_frames(straight, killed)


def test_resume_with_other_scene_is_rejected(tmp_path: Path, ballistic: None,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    run_main(["--scene", str(scene), "--out", str(out), "--frames", "2"], capsys)
    changed = tiny_scene()
    changed["objects"][1]["velocity"] = [-3, 0, 0]
    other = write_scene(tmp_path / "other.yaml", changed)
    code, _, stderr = run_main(["--scene", str(other), "--out", str(out), "--resume"], capsys)
    assert code == 2
    assert stderr.strip() == (f"error: --resume: the scene differs from {out / 'scene.yaml'} "
                              "at 'objects[1].velocity[0]'")
    assert len(frames_of(out)) == 3   # untouched
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(tmp_path / "empty"),
                                "--resume"], capsys)
    assert code == 2 and stderr.startswith("error: --resume: ") and "no run to resume" in stderr


def test_blow_up_stops_with_exit_1_and_keeps_frames(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ballistic: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    original = BallisticSolver.advance
    calls = {"n": 0}

    def advance_then_nan(self: BallisticSolver, frame_dt: float) -> StepStats:
        calls["n"] += 1
        if calls["n"] == 3:   # frame 3 produces NaN
            self.state.v = self.state.v.clone()
            self.state.v[0, 0] = float("nan")
        return original(self, frame_dt)

    monkeypatch.setattr(BallisticSolver, "advance", advance_then_nan)
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(out)], capsys)
    assert code == 1
    lines = stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("error: simulation blew up while computing frame 3 (t = 0.02")
    assert "frames 0..2" in lines[0]
    frames = frames_of(out)
    assert len(frames) == 3
    for frame in frames:
        assert all(np.isfinite(frame[k]).all() for k in ("x", "v", "F_E", "alpha"))
    assert read_diagnostics_csv(out / "diagnostics.csv")["frame"].tolist() == [0, 1, 2]
    assert (out / "diagnostics.png").exists()


# ----------------------------------------------------------------------------- invalid input


def wait_for_file(proc: subprocess.Popen[str], path: Path, timeout: float = 120) -> None:
    """Wait until a running simulate.py has written ``path``."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline
        time.sleep(0.05)


def _like_a_terminal() -> None:
    """In the child before exec: SIGINT delivered and handled the default way, as from a shell.

    A blocked or ignored signal is inherited across exec; a library loaded by an earlier test in
    this pytest process could leave SIGINT so, and the child would then never see the Ctrl-C."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _simulate_subprocess(args: list[str], cwd: Path, **kwargs: Any) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen([sys.executable, str(REPO / "simulate.py"), *args], cwd=cwd,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_like_a_terminal, **kwargs)


INVALID_CHANGES = [
    (("objects", 1, "materials", 0, "nu", 0.5),
     "error: objects[1].materials[0].nu: 0.5 is not < 0.5"),
    (("objects", 0, "velocty", [1, 0, 0]),
     "error: objects[0].velocty: unknown key (did you mean 'velocity'?)"),
    (("objects", 0, "transform", "translate", [0.95, 0.5, 0.5]),
     "error: objects[0].transform: object 'left' reaches x = "),
    (("domain", "grid", "big"), "error: domain.grid: expected an integer, got str 'big'"),
    (("objects", 1, "materials", 0, "alpha0", -0.1),
     "error: objects[1].materials[0].Jp0: give only one of 'alpha0' and 'Jp0'"),
]


def _invalid_scene(tmp_path: Path, change: tuple[Any, ...]) -> Path:
    scene = tiny_scene()
    node: Any = scene
    for key in change[:-2]:
        node = node[key]
    node[change[-2]] = change[-1]
    return write_scene(tmp_path / "bad.yaml", scene)


@pytest.mark.parametrize("change,expected", INVALID_CHANGES)
def test_invalid_scene_exits_2_with_one_line(tmp_path: Path, change: tuple[Any, ...],
                                             expected: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    path = _invalid_scene(tmp_path, change)
    code, stdout, stderr = run_main(["--scene", str(path), "--out", str(tmp_path / "out")],
                                    capsys)
    assert code == 2
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(expected), stderr
    assert stdout == ""
    assert not (tmp_path / "out").exists()   # nothing was simulated or written


def test_invalid_scene_through_the_script(tmp_path: Path) -> None:
    """The real entry script: exit status 2, exactly one stderr line, no output folder."""
    path = _invalid_scene(tmp_path, INVALID_CHANGES[0][0])
    proc = _simulate_subprocess(["--scene", str(path), "--out", str(tmp_path / "out")],
                                cwd=tmp_path)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 2, stderr
    assert stderr == INVALID_CHANGES[0][1] + "\n"
    assert not (tmp_path / "out").exists()


def test_cli_missing_model_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tiny_scene()
    del scene["objects"][0]["primitive"]
    scene["objects"][0]["model"] = "output/no_such_model"
    path = write_scene(tmp_path / "bad.yaml", scene)
    code, _, stderr = run_main(["--scene", str(path), "--out", str(tmp_path / "out")], capsys)
    assert code == 2
    assert stderr == "error: objects[0].model: 'output/no_such_model' does not exist\n"
    code, _, stderr = run_main(["--scene", str(tmp_path / "none.yaml")], capsys)
    assert code == 2 and stderr == f"error: {tmp_path / 'none.yaml'}: file not found\n"
    code, _, stderr = run_main(["--scene", str(path), "--frames", "0"], capsys)
    assert code == 2 and stderr == "error: --frames: 0 is not >= 1\n"


# ----------------------------------------------------------------------------- real solver


def test_real_solver_run_resume_and_blow_up(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    straight, pieces = tmp_path / "straight", tmp_path / "pieces"
    code, stdout, stderr = run_main(["--scene", str(scene), "--out", str(straight),
                                     "--frames", "3", "--device", "cpu"], capsys)
    assert code == 0, stderr
    frames = frames_of(straight)
    assert len(frames) == 4
    assert all(np.isfinite(f["x"]).all() and np.isfinite(f["F_E"]).all() for f in frames)
    assert not np.array_equal(frames[0]["x"], frames[-1]["x"])   # something moved
    table = read_diagnostics_csv(straight / "diagnostics.csv")
    assert list(table) == diagnostics_columns(["left", "right"])
    assert (table["steps"][1:] >= 1).all()

    run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "1"], capsys)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "3",
                                "--resume"], capsys)
    assert code == 0, stderr
    assert_same_frames(straight, pieces)

    from fracture_gs.mpm.solver import CollisionMPM
    original = CollisionMPM.advance
    calls = {"n": 0}

    def failing_advance(self: Any, frame_dt: float) -> Any:
        calls["n"] += 1
        if calls["n"] == 2:
            raise SimulationBlowUp("NaN in particle velocities")
        return original(self, frame_dt)

    monkeypatch.setattr(CollisionMPM, "advance", failing_advance)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(tmp_path / "boom"),
                                "--frames", "3"], capsys)
    assert code == 1
    assert "blew up while computing frame 2" in stderr and "NaN in particle velocities" in stderr
    kept = frames_of(tmp_path / "boom")
    assert len(kept) == 2
    for a, b in zip(kept, frames[:2]):
        assert np.array_equal(a["x"], b["x"])


def test_real_solver_frames_keep_the_input_order_across_reorders(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """The solver re-sorts its particles while running; frames and resumed runs do not notice."""
    from fracture_gs.mpm.solver import CollisionMPM
    original_init = CollisionMPM.__init__
    interval = {"steps": 2}

    def init_with_interval(self: Any, *args: Any, **kwargs: Any) -> None:
        original_init(self, *args, **dict(kwargs, reorder_every=interval["steps"]))

    monkeypatch.setattr(CollisionMPM, "__init__", init_with_interval)
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    runs = {}
    for name, steps in (("fixed", 0), ("moving", 2)):
        interval["steps"] = steps
        runs[name] = tmp_path / name
        code, _, stderr = run_main(["--scene", str(scene), "--out", str(runs[name]), "--frames", "3"], capsys)
        assert code == 0, stderr
    fixed, moving = frames_of(runs["fixed"]), frames_of(runs["moving"])
    rest_x = np.load(runs["moving"] / "particles.npz")["rest_x"]
    assert np.array_equal(moving[0]["x"], rest_x)   # frame 0 in the particles.npz order
    for a, b in zip(fixed[1:], moving[1:]):         # 3 steps per frame: reordered every 2
        assert np.abs(a["x"] - b["x"]).max() <= 1e-5 * np.abs(a["x"]).max()
        assert np.array_equal(a["fractured"], b["fractured"])
    # Resume from a checkpoint taken between reorders: the same frames as the uninterrupted run.
    pieces = tmp_path / "pieces"
    run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "1"], capsys)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(pieces), "--frames", "3", "--resume"], capsys)
    assert code == 0, stderr
    assert_same_frames(runs["moving"], pieces)


def test_real_subprocess_kill_and_resume(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """SIGKILL a running simulate.py after a few frames; --resume gives the same frames."""
    scene_dict = tiny_scene()
    scene_dict["frames"] = 40
    scene = write_scene(tmp_path / "tiny.yaml", scene_dict)
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    proc = _simulate_subprocess(["--scene", str(scene), "--out", str(killed), "--device",
                                 "cpu"], cwd=tmp_path)
    wait_for_file(proc, killed / "frames" / "frame_00002.npz")
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    done = len(frames_of(killed))
    target = min(done + 1, 40)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(killed), "--resume",
                                "--frames", str(target)], capsys)
    assert code == 0, stderr
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(straight),
                                "--frames", str(target)], capsys)
    assert code == 0, stderr
    assert_same_frames(straight, killed)
    assert not list(killed.rglob(".*.tmp"))


# ----------------------------------------------------------------------------- a stranger's input
# Issue 15, finding 5: each of these used to end in a traceback (exit 1). Now: exit 2, one line
# on stderr naming the file or key, nothing simulated.


def assert_one_line_error(code: int, stderr: str, start: str, *needles: str) -> str:
    assert code == 2, stderr
    assert "Traceback" not in stderr, stderr
    lines = stderr.splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(start), stderr
    for needle in needles:
        assert needle in lines[0], stderr
    return lines[0]


@pytest.mark.parametrize("content,problem", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "not a YAML text file (byte 0 is not UTF-8)"),
    (b"name: caf\xe9\n", "not a YAML text file (byte 9 is not UTF-8)"),
    (b"", "the file holds no scene (empty YAML document)"),
    (b"# only a comment\n", "the file holds no scene (empty YAML document)"),
], ids=["png", "latin-1", "empty", "comment-only"])
def test_scene_file_of_the_wrong_kind(tmp_path: Path, content: bytes, problem: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "scene.yaml"
    path.write_bytes(content)
    code, stdout, stderr = run_main(["--scene", str(path), "--out", str(tmp_path / "out")],
                                    capsys)
    assert_one_line_error(code, stderr, f"error: {path}: {problem}")
    assert stdout == "" and not (tmp_path / "out").exists()


def test_scene_is_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, stderr = run_main(["--scene", str(tmp_path)], capsys)
    assert_one_line_error(code, stderr, f"error: {tmp_path}: cannot read (Is a directory)")


def test_out_names_an_existing_file(tmp_path: Path, ballistic: None,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    taken = tmp_path / "results.txt"
    taken.write_text("not a folder\n")
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(taken)], capsys)
    assert_one_line_error(code, stderr, f"error: --out: '{taken}' is a file, not a folder")
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(taken / "run")], capsys)
    assert_one_line_error(code, stderr,
                          f"error: --out: '{taken / 'run'}' cannot be created: '{taken}' is a file")
    assert taken.read_text() == "not a folder\n"


@pytest.mark.parametrize("damaged", ["checkpoint.npz", "particles.npz",
                                     "frames/frame_00000.npz", "frames/frame_00001.npz"])
def test_resume_with_a_truncated_file(tmp_path: Path, damaged: str, ballistic: None,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    assert run_main(["--scene", str(scene), "--out", str(out), "--frames", "2"], capsys)[0] == 0
    _truncate(out / damaged)
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(out), "--frames", "4",
                                "--resume"], capsys)
    assert_one_line_error(code, stderr, f"error: --resume: {out / damaged}: cannot be read (",
                          "damaged", "without --resume")


def test_resume_with_a_foreign_checkpoint(tmp_path: Path, ballistic: None,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    run_main(["--scene", str(scene), "--out", str(out), "--frames", "2"], capsys)
    np.savez(out / "checkpoint.npz", weights=np.zeros(3))
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(out), "--resume"], capsys)
    assert_one_line_error(code, stderr, f"error: --resume: {out / 'checkpoint.npz'}: cannot be "
                          "read (no 'columns' array)")


def _huge_grid_scene() -> dict[str, Any]:
    scene = tiny_scene()
    scene["domain"]["grid"] = 4096
    for obj in scene["objects"]:
        obj["primitive"]["radius"] = 0.002   # a few thousand particles: only the grid is huge
    return scene


def test_grid_too_large_is_refused_before_allocating(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """2 objects x 4100³ nodes x 13 float32 fields = 6.5 TiB: named, never allocated."""
    scene = write_scene(tmp_path / "huge.yaml", _huge_grid_scene())
    code, stdout, stderr = run_main(["--scene", str(scene), "--out", str(tmp_path / "out"),
                                     "--device", "cpu"], capsys)
    line = assert_one_line_error(code, stderr, "error: domain.grid: 4096 needs 6.5 TiB of grid "
                                 "memory (2 grids of about 4100³ nodes), more than the ")
    assert line.endswith("of free cpu memory; use a coarser grid")
    assert not (tmp_path / "out").exists()


def test_memory_check_names_the_grid_or_the_primitive() -> None:
    from fracture_gs.config import parse_scene
    from fracture_gs.mpm.memory import check_scene_memory, grid_memory_bytes

    config = parse_scene(tiny_scene())
    grid_bytes, n_grids, nodes = grid_memory_bytes(config)
    # 16 cells + 1 node, padded to blocks of 4: 20³ nodes; mass + momentum + velocity + contact
    # normal (gradient) + volume + position moment = 13 float32 per node and grid (contact
    # fields: 2 objects)
    assert (n_grids, nodes) == (2, 20 ** 3)
    assert grid_bytes == 2 * 20 ** 3 * 13 * 4
    check_scene_memory(config, torch.device("cpu"), available=grid_bytes + 10 ** 6)
    with pytest.raises(Exception, match=r"^domain\.grid: 16 needs 812\.5 KiB of grid memory"):
        check_scene_memory(config, torch.device("cpu"), available=grid_bytes - 1)
    dense = tiny_scene()
    dense["objects"][1]["primitive"]["particles_per_cell"] = 10 ** 6
    config = parse_scene(dense)
    with pytest.raises(Exception, match=r"^objects\[1\]\.primitive: sampling 5\.66e\+07 candidate "
                                        r"particles at grid 16 \(1000000 per cell\)"):
        check_scene_memory(config, torch.device("cpu"), available=10 ** 9)


def test_write_failure_mid_run_exits_1_with_one_line(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ballistic: None,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A full disk while writing frame 3: exit 1, the file and the reason, frames 0..2 kept."""
    import errno

    from fracture_gs.folders import sim_writer as output_module
    original = output_module.save_npz_atomic

    def disk_full_at_frame_3(path: Path, arrays: Any) -> None:
        if path.name == "frame_00003.npz":
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        original(path, arrays)

    monkeypatch.setattr(output_module, "save_npz_atomic", disk_full_at_frame_3)
    scene = write_scene(tmp_path / "tiny.yaml", tiny_scene())
    out = tmp_path / "sim"
    code, _, stderr = run_main(["--scene", str(scene), "--out", str(out)], capsys)
    assert code == 1 and "Traceback" not in stderr
    assert stderr.splitlines() == [f"error: {out / 'frames' / 'frame_00003.npz'}: "
                                   "No space left on device"]
    assert len(frames_of(out)) == 3


def test_ctrl_c_exits_130_with_one_line(tmp_path: Path) -> None:
    """SIGINT while frames are being computed: exit 130, one line, no traceback, resumable."""
    scene_dict = tiny_scene()
    scene_dict["frames"] = 400
    scene = write_scene(tmp_path / "tiny.yaml", scene_dict)
    out = tmp_path / "sim"
    proc = _simulate_subprocess(["--scene", str(scene), "--out", str(out), "--device", "cpu"],
                                cwd=tmp_path)
    wait_for_file(proc, out / "frames" / "frame_00001.npz")
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert stderr.splitlines() == [f"interrupted; the frames written so far in {out} are valid, "
                                   "continue with --resume"]
    assert len(frames_of(out)) >= 2 and not list(out.rglob(".*.tmp"))


def test_overlapping_objects_are_simulated_with_a_warning(tmp_path: Path, ballistic: None,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """Two equal spheres 0.225 radii apart share 83 % of their volume: a legal but suspicious
    start, reported on stderr with both names and the share; spheres apart give no warning."""
    scene = tiny_scene()
    scene["frames"] = 1
    code, _, err = run_main(["--scene", str(write_scene(tmp_path / "apart.yaml", scene)),
                             "--out", str(tmp_path / "apart")], capsys)
    assert code == 0 and "warning" not in err
    scene["objects"][1]["transform"]["translate"] = [0.36 + 0.225 * 0.12, 0.5, 0.5]
    code, _, err = run_main(["--scene", str(write_scene(tmp_path / "overlap.yaml", scene)),
                             "--out", str(tmp_path / "overlap")], capsys)
    assert code == 0
    warning, = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert "'left'" in warning and "'right'" in warning and "overlap" in warning
    share = int(warning.split("overlap: ")[1].split("%")[0])
    assert 78 <= share <= 88, warning
    assert (tmp_path / "overlap" / "frames" / "frame_00001.npz").is_file()


def test_a_duplicate_scene_key_exits_2_with_one_line(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    path = write_scene(tmp_path / "twice.yaml", tiny_scene())
    path.write_text(path.read_text() + "frames: 2\n")
    lines = path.read_text().splitlines()
    first = lines.index("frames: 6") + 1
    code, _, err = run_main(["--scene", str(path), "--out", str(tmp_path / "out")], capsys)
    assert code == 2
    assert err.strip().splitlines() == [
        f"error: {path}: invalid YAML at line {len(lines)}: duplicate key 'frames' (first given "
        f"at line {first})"]
    assert not (tmp_path / "out").exists()
