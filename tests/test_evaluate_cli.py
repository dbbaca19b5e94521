"""evaluate.py on a tiny fracturing collision (795 particles, 8 frames) and a tiny trained model:
the protocol of docs/formulas.md §14 end to end, report files, missing weights, bad input."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from fracture_gs.cli.evaluate import main as evaluate_main
from fracture_gs.pipeline.render import RenderOptions, render_simulation
from fracture_gs.pipeline.simulate import run_simulation
from fracture_gs.config.scene import load_scene
from fracture_gs.pipeline.experiments.sim_eval import EvalOptions, EvaluationError, RunSpec
from fracture_gs.metrics.protocol import MetricNetworks
from fracture_gs.pipeline.experiments.sim_report import evaluate_and_report

ROOT = Path(__file__).resolve().parents[1]
TINY_SCENE = ROOT / "tests" / "data" / "tiny_collision.yaml"
FIXTURE = ROOT / "tests" / "data" / "synthetic_fixture"
SMALL = ["--views", "orbit:2", "--resolution", "48", "48", "--quiet"]


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sims") / "tiny_collision"
    run_simulation(load_scene(TINY_SCENE), out, device=torch.device("cpu"), progress=False,
                   log=open("/dev/null", "w"))
    return out


@pytest.fixture(scope="module")
def evaluated(sim: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("eval")
    assert evaluate_main(["--sim", str(sim), "--out", str(out), *SMALL]) == 0
    return out


def _png(path: Path) -> np.ndarray:
    return cv2.imread(str(path), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float64) / 255.0


def test_sim_evaluation_follows_the_protocol(sim: Path, evaluated: Path) -> None:
    metrics = json.loads((evaluated / "metrics.json").read_text())
    run, = metrics["runs"]
    window = run["window"]
    counts = np.loadtxt(sim / "diagnostics.csv", delimiter=",", skiprows=1, usecols=11)
    onset = int(np.flatnonzero(counts > max(10, 0.001 * 795))[0])
    assert window["onset_frame"] == onset and window["reference_frame"] == onset - 1
    assert window["window_frames"] == list(range(onset + 1, min(onset + 5, 8) + 1))
    values = run["metrics"]
    frames = len(window["window_frames"])
    assert np.asarray(values["psnr"]["per_view"]).shape == (2, frames)
    assert np.asarray(values["lpips"]["per_view"]).shape == (2, frames)
    assert values["n_reference"] == 2 and values["n_window"] == 2 * frames
    assert isinstance(values["fid"], float) and values["fid"] > 0
    assert 0 < values["lpips"]["mean"] < 1 and 5 < values["psnr"]["mean"] < 60
    report = (evaluated / "report.md").read_text()
    assert "N (ref / window)" in report and "biased" in report
    for name in ("momentum.png", "energy.png", "strip.png"):
        assert (evaluated / name).stat().st_size > 1000, name
    conservation = metrics["conservation"][str(sim)]
    assert conservation["momentum_drift"] < 1e-5   # no gravity, no wall reached
    # pieces per object at the last frame add up to the fragments column of diagnostics.csv
    header = (sim / "diagnostics.csv").read_text().splitlines()[0].split(",")
    fragments = np.loadtxt(sim / "diagnostics.csv", delimiter=",", skiprows=1,
                           usecols=header.index("fragments"))
    pieces = metrics["pieces"]
    assert [row["object"] for row in pieces] == ["left", "right"]
    assert sum(row["pieces"] for row in pieces) == int(fragments[-1])
    assert sum(row["pieces_first_frame"] for row in pieces) == int(fragments[0])
    assert all(0 < row["largest_share"] <= 1 for row in pieces)
    assert "## Pieces" in report and "pieces (first → last frame)" in report
    assert conservation["energy_rise"] <= 0.01


def test_psnr_of_render_folder_equals_hand_computation(sim: Path, tmp_path: Path) -> None:
    """--renders reads render.py's PNGs; PSNR recomputed here from the same files."""
    renders = tmp_path / "renders"
    render_simulation(RenderOptions(sim=sim, views="orbit:2", resolution=(40, 40), out=renders),
                      log=open("/dev/null", "w"), progress=False)
    out = tmp_path / "eval"
    assert evaluate_main(["--sim", str(sim), "--renders", str(renders), "--out", str(out),
                          "--no-fid", "--quiet"]) == 0
    run, = json.loads((out / "metrics.json").read_text())["runs"]
    ref, frames = run["window"]["reference_frame"], run["window"]["window_frames"]
    for v, view in enumerate(sorted(p.name for p in renders.iterdir() if p.is_dir())):
        reference = _png(renders / view / f"{ref:05d}.png")
        for t, frame in enumerate(frames):
            mse = np.mean((_png(renders / view / f"{frame:05d}.png") - reference) ** 2)
            assert run["metrics"]["psnr"]["per_view"][v][t] == pytest.approx(
                -10 * math.log10(mse), abs=1e-6)   # images are float32 in [0, 1]
    assert run["metrics"]["fid"] == "unavailable: not requested"


def test_missing_weights_are_reported_not_replaced(sim: Path, tmp_path: Path) -> None:
    empty = tmp_path / "weights"
    empty.mkdir()
    out = tmp_path / "eval"
    assert evaluate_main(["--sim", str(sim), "--out", str(out), "--weights-dir", str(empty),
                          *SMALL]) == 0
    values = json.loads((out / "metrics.json").read_text())["runs"][0]["metrics"]
    assert values["lpips"].startswith("unavailable") and "alexnet.ckpt" in values["lpips"]
    assert values["fid"].startswith("unavailable") and "default_1.pt" in values["fid"]
    assert "alexnet.ckpt" in (out / "report.md").read_text()


@pytest.mark.parametrize("argv, needle", [
    (["--sim", "/nonexistent/sim"], "/nonexistent/sim"),
    (["--sim", "SIM", "--window", "0"], "--window"),
    (["--sim", "SIM", "--resolution", "100000", "100000"], "--resolution: image size 100000x100000"),
    (["--sim", "SIM", "--renders", "/nonexistent/r"], "/nonexistent/r"),
    (["--sim", "SIM", "--mls", "SIM"], "--mls"),
    (["-m", "/nonexistent/model"], "/nonexistent/model"),
    (["--experiment", "momentum", "--configs", "/nonexistent/configs"], "momentum.yaml"),
])
def test_bad_input_is_one_line_and_exit_2(sim: Path, argv: list[str], needle: str,
                                          tmp_path: Path) -> None:
    argv = [str(sim) if a == "SIM" else a for a in argv]
    result = subprocess.run([sys.executable, str(ROOT / "evaluate.py"), *argv, "--out",
                             str(tmp_path / "o")], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0]


def test_report_folder_is_made_only_after_every_run_is_evaluated(sim: Path, tmp_path: Path) -> None:
    """A library caller whose second run cannot be evaluated gets the error and no empty folder."""
    cpu = torch.device("cpu")
    networks = MetricNetworks.load(cpu, lpips=False, fid=False)
    options = EvalOptions(views="orbit:2", resolution=(32, 32), device=cpu)
    out = tmp_path / "report"
    with pytest.raises(EvaluationError, match="no such simulation folder"):
        evaluate_and_report([RunSpec("ours", sim), RunSpec("missing", tmp_path / "nope")], options, networks,
                            out, "t")
    assert not out.exists()
    evaluate_and_report([RunSpec("ours", sim)], options, networks, out, "t")
    assert (out / "metrics.json").is_file() and (out / "report.md").is_file()


def declared_mls_copy(sim: Path, copy: Path) -> Path:
    """The run's folder again with its scene.yaml saying contact mode mls: the same frames, so
    that the 'mls' row of a comparison must equal the 'no FPGO' row."""
    shutil.copytree(sim, copy)
    scene = copy / "scene.yaml"
    text = scene.read_text()
    assert "mode: collision" in text
    scene.write_text(text.replace("mode: collision", "mode: mls"))
    return copy


def test_compare_gives_the_ablation_rows(sim: Path, tmp_path: Path) -> None:
    out = tmp_path / "eval"
    mls = declared_mls_copy(sim, tmp_path / "mls")
    assert evaluate_main(["--sim", str(sim), "--compare", "--mls", str(mls), "--out", str(out),
                          "--no-fid", "--no-lpips", "--views", "orbit:2", "--resolution", "32",
                          "32", "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert [r["fpgo"] for r in metrics["runs"]] == [True, False, False]
    report = (out / "report.md").read_text()
    assert "paper: ours" in report and "90.75" in report
    # paired: ours against each baseline (here the "mls" run is the same simulation, no FPGO)
    means = [r["metrics"]["psnr"]["mean"] for r in metrics["runs"]]
    to_nofpgo, to_mls = metrics["paired"]
    assert to_nofpgo["second"] == metrics["runs"][1]["label"]
    assert to_nofpgo["psnr"]["advantage"] == pytest.approx(means[0] - means[1])
    assert to_mls["psnr"] == to_nofpgo["psnr"]
    low, high = to_nofpgo["psnr"]["interval"]
    assert low <= to_nofpgo["psnr"]["advantage"] <= high and to_nofpgo["psnr"]["views"] == 2
    assert "lpips" not in to_nofpgo and "fid" not in to_nofpgo     # --no-lpips --no-fid
    assert "## Paired comparison" in report


def _evaluate_failing(argv: list[str], capsys: pytest.CaptureFixture) -> str:
    assert evaluate_main([*argv, "--no-fid", "--no-lpips", "--quiet"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


def test_renders_are_labelled_from_their_render_json(sim: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    """A render.py folder made without FPGO is scored as 'no FPGO' whatever its name; asking
    for the other kind, or scoring it against another simulation, is one line and exit 2."""
    renders = tmp_path / "renders_nofpgo"
    render_simulation(RenderOptions(sim=sim, views="orbit:2", resolution=(32, 32), fpgo=False,
                                    out=renders), log=open("/dev/null", "w"), progress=False)
    info = json.loads((renders / "render.json").read_text())
    assert info["fpgo"] is False and info["contact_mode"] == "collision"
    assert info["sim"] == str(sim.resolve()) and info["scene"] == "tiny_collision"
    out = tmp_path / "eval"
    assert evaluate_main(["--sim", str(sim), "--renders", str(renders), "--out", str(out),
                          "--no-fid", "--no-lpips", "--quiet"]) == 0
    run, = json.loads((out / "metrics.json").read_text())["runs"]
    assert run["label"] == "no FPGO" and run["fpgo"] is False
    capsys.readouterr()
    fpgo = tmp_path / "renders_fpgo"
    render_simulation(RenderOptions(sim=sim, views="orbit:1", resolution=(32, 32), out=fpgo),
                      log=open("/dev/null", "w"), progress=False)
    err = _evaluate_failing(["--sim", str(sim), "--renders", str(fpgo), "--no-fpgo", "--out",
                             str(tmp_path / "e2")], capsys)
    assert str(fpgo) in err and "rendered with FPGO" in err and "'no FPGO'" in err
    other = declared_mls_copy(sim, tmp_path / "other")
    err = _evaluate_failing(["--sim", str(other), "--renders", str(renders), "--out",
                             str(tmp_path / "e3")], capsys)
    assert err == (f"error: {renders}: renders of the simulation {sim.resolve()} (scene "
                   f"'tiny_collision'), not of {other}")
    stale = tmp_path / "stale"
    render_simulation(RenderOptions(sim=other, views="orbit:1", resolution=(32, 32), out=stale),
                      log=open("/dev/null", "w"), progress=False)
    (other / "scene.yaml").write_text((other / "scene.yaml").read_text() + "# edited\n")
    err = _evaluate_failing(["--sim", str(other), "--renders", str(stale), "--out",
                             str(tmp_path / "e5")], capsys)
    assert err == (f"error: {stale}: renders of an earlier state of {other} (its scene.yaml or "
                   "particles.npz changed since); render the simulation again")
    (renders / "render.json").unlink()
    err = _evaluate_failing(["--sim", str(sim), "--renders", str(renders), "--out",
                             str(tmp_path / "e4")], capsys)
    assert str(renders / "render.json") in err and "file not found" in err
    assert not any((tmp_path / name).exists() for name in ("e2", "e3", "e4", "e5"))


def test_compare_refuses_runs_of_another_contact_mode(sim: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "eval"
    err = _evaluate_failing(["--sim", str(sim), "--compare", "--mls", str(sim), "--out", str(out)],
                            capsys)
    assert err == (f"error: {sim}: simulated with contact mode 'collision' (its scene.yaml), but "
                   "the run 'mls, no FPGO (PhysGaussian / GIC)' needs contact mode 'mls'")
    mls = declared_mls_copy(sim, tmp_path / "mls")
    err = _evaluate_failing(["--sim", str(mls), "--compare", "--mls", str(mls), "--out", str(out)],
                            capsys)
    assert f"{mls}: simulated with contact mode 'mls'" in err and "'collision'" in err
    assert not out.exists()


def test_static_model_metrics_match_the_pngs(tmp_path: Path) -> None:
    from fracture_gs.cli.train import main as train_main

    model = tmp_path / "teapot"
    assert train_main(["-s", str(FIXTURE), "-m", str(model), "--sdf-res", "24", "--sdf-iters",
                       "8", "--iterations", "16", "--n-surface", "300", "--nv", "2",
                       "--particle-res", "10", "--sdf-rays", "256", "--quiet"]) == 0
    assert evaluate_main(["-m", str(model), "--quiet"]) == 0
    results = json.loads((model / "results.json").read_text())
    (method, values), = results.items()
    folder = model / "test" / method
    names = sorted(p.name for p in (folder / "renders").glob("*.png"))
    psnrs = [-10 * math.log10(np.mean((_png(folder / "renders" / n) - _png(folder / "gt" / n)) ** 2))
             for n in names]
    assert values["PSNR"] == pytest.approx(np.mean(psnrs), abs=1e-4)
    assert 0 < values["SSIM"] <= 1 and 0 < values["LPIPS"] < 1
    per_view = json.loads((model / "per_view.json").read_text())[method]
    assert set(per_view["PSNR"]) == set(names)
    assert (model / "evaluation" / "report.md").is_file()
