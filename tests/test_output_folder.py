"""Output folders that cannot be made are bad input: one ``error:`` line naming the option, exit
status 2, before any work, and nothing left behind (fracture_gs/io/output_folder.py)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fracture_gs.io.output_folder import OutputFolderError, os_error_line, prepare_output_folder

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def a_file(tmp_path: Path) -> Path:
    """A plain file: a folder below it can never be made (even by root, unlike permissions)."""
    path = tmp_path / "file.txt"
    path.write_text("keep me")
    return path


def test_makes_nested_folders(tmp_path: Path) -> None:
    out = prepare_output_folder(tmp_path / "a" / "b", "--out")
    assert out.is_dir() and list(out.iterdir()) == []  # the write test leaves no file


def test_check_only_leaves_nothing_behind(tmp_path: Path) -> None:
    prepare_output_folder(tmp_path / "a" / "b", "--out", keep=False)
    assert list(tmp_path.iterdir()) == []
    existing = tmp_path / "here"
    existing.mkdir()
    (existing / "result.txt").write_text("x")
    prepare_output_folder(existing, "--out", keep=False)
    assert (existing / "result.txt").read_text() == "x"


def test_a_file_in_the_way_is_refused(a_file: Path) -> None:
    with pytest.raises(OutputFolderError, match=r"^--out: '.*file\.txt/sub' cannot be created: '.*file\.txt' is a file$"):
        prepare_output_folder(a_file / "sub", "--out")
    with pytest.raises(OutputFolderError, match=r"^-m: '.*file\.txt' is a file, not a folder"):
        prepare_output_folder(a_file, "-m")
    assert a_file.read_text() == "keep me"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_a_folder_the_system_refuses_is_reported_with_its_reason() -> None:
    # /proc takes no new folders, not even from root (whom permission bits never stop).
    with pytest.raises(OutputFolderError, match=r"^--out: '/proc/fgs_out' cannot be created \(.+\)$"):
        prepare_output_folder("/proc/fgs_out", "--out")


def test_os_error_line_names_the_file() -> None:
    line = os_error_line(FileNotFoundError(2, "No such file or directory", "/x/y.png"))
    assert line == "/x/y.png: No such file or directory"


def _one_error_line(capsys: pytest.CaptureFixture, needle: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0], err


def test_simulate_refuses_the_folder_before_simulating(a_file: Path, capsys) -> None:
    from fracture_gs.cli import simulate

    assert simulate.main(["--scene", str(ROOT / "configs" / "two_spheres.yaml"),
                          "--out", str(a_file / "sim")]) == 2
    _one_error_line(capsys, "--out")


def test_train_refuses_the_folder_and_leaves_nothing_on_bad_input(a_file: Path, tmp_path: Path,
                                                                  capsys) -> None:
    from fracture_gs.cli import train

    dataset = tmp_path / "dataset"
    dataset.mkdir()
    (dataset / "transforms_train.json").write_text(json.dumps({"frames": []}))
    assert train.main(["-s", str(dataset), "-m", str(a_file / "model"), "--quiet"]) == 2
    _one_error_line(capsys, "-m/--model_path")
    # A dataset that fails to load after the folder check passed: the check's folders are gone.
    assert train.main(["-s", str(dataset), "-m", str(tmp_path / "new" / "model"), "--quiet"]) == 2
    _one_error_line(capsys, "transforms_train.json")
    assert not (tmp_path / "new").exists()


def test_demo_refuses_the_folder(a_file: Path, capsys) -> None:
    from fracture_gs.cli import demo

    assert demo.main(["--out", str(a_file / "demo")]) == 2
    _one_error_line(capsys, "--out")


def test_evaluate_refuses_the_folder_before_loading_networks(a_file: Path, tmp_path: Path,
                                                             capsys) -> None:
    from fracture_gs.cli import evaluate

    model = tmp_path / "model"
    (model / "point_cloud" / "iteration_10").mkdir(parents=True)
    (model / "point_cloud" / "iteration_10" / "point_cloud.ply").write_bytes(b"")
    assert evaluate.main(["-m", str(model), "--out", str(a_file / "eval")]) == 2
    _one_error_line(capsys, "--out")
    assert evaluate.main(["--experiment", "momentum", "--out", str(a_file / "exp")]) == 2
    _one_error_line(capsys, "--out")


def test_render_model_reports_a_failed_write_in_one_line(tmp_path: Path, capsys) -> None:
    from fracture_gs.cli import render_model
    from fracture_gs.cli.train import main as train_main

    model = tmp_path / "model"
    assert train_main(["-s", str(ROOT / "tests" / "data" / "synthetic_fixture"), "-m", str(model),
                       "--sdf-res", "24", "--sdf-iters", "8", "--iterations", "4",
                       "--n-surface", "200", "--nv", "2", "--particle-res", "8", "--sdf-rays",
                       "256", "--quiet"]) == 0
    capsys.readouterr()
    (model / "test").write_text("in the way")  # render.py -m writes <model>/test/ours_<N>/
    assert render_model.main(["-m", str(model), "--skip_train", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(model / "test") in err[0], err
