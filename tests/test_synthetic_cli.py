"""``python -m fracture_gs.data.synthetic``: which output folders it may write or replace.

Issue 15, finding 6: ``--out data/ --force`` used to delete all of ``data/``. ``--force`` may
only replace a folder the generator wrote (it holds ``generator.json``); everything else is
refused with one line, before any work, and without needing Mitsuba.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from fracture_gs.data.synthetic import __main__ as synthetic_cli
from fracture_gs.data.synthetic import generator


@pytest.fixture
def no_rendering(monkeypatch: pytest.MonkeyPatch) -> None:
    """Mitsuba is not importable and building an object fails: a refusal must need neither."""
    monkeypatch.setitem(sys.modules, "mitsuba", None)

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the generator started working on a refused output folder")

    monkeypatch.setattr(generator, "build_object", refuse)


def snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def user_folder(root: Path) -> Path:
    """A folder holding someone's unrelated files (and one generated dataset)."""
    (root / "notes.txt").parent.mkdir(parents=True, exist_ok=True)
    (root / "notes.txt").write_text("my notes\n")
    (root / "photos").mkdir()
    (root / "photos" / "cat.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    fake_dataset(root / "teapot")
    return root


def fake_dataset(folder: Path) -> Path:
    folder.mkdir(parents=True)
    (folder / "generator.json").write_text(json.dumps({"object": "teapot"}))
    (folder / "transforms_train.json").write_text("{}")
    return folder


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = synthetic_cli.main(args + ["--quiet"])
    return code, capsys.readouterr().err


def test_force_refuses_a_folder_the_generator_did_not_write(
        tmp_path: Path, no_rendering: None, capsys: pytest.CaptureFixture[str]) -> None:
    data = user_folder(tmp_path / "data")
    before = snapshot(data)
    code, err = run(["--object", "teapot", "--out", f"{data}/", "--force"], capsys)
    assert code == 2
    assert err.splitlines() == [
        f"error: {data}/: exists and was not written by this generator (no generator.json); "
        "--force only replaces generated datasets, so choose another --out (e.g. a sub-folder) "
        "or remove it yourself"]
    assert snapshot(data) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data"]   # no staging folder either


def test_object_all_refuses_before_rendering_anything(
        tmp_path: Path, no_rendering: None, capsys: pytest.CaptureFixture[str]) -> None:
    """--object all: the teapot could be replaced, but bowl/ is someone else's folder."""
    data = user_folder(tmp_path / "data")
    (data / "bowl").mkdir()
    (data / "bowl" / "thesis.tex").write_text("\\chapter{}")
    before = snapshot(data)
    code, err = run(["--object", "all", "--out", str(data), "--force"], capsys)
    assert code == 2
    assert err.startswith(f"error: {data / 'bowl'}: exists and was not written by this generator")
    assert snapshot(data) == before


@pytest.mark.parametrize("force", [False, True])
def test_out_is_a_file(tmp_path: Path, force: bool, no_rendering: None,
                       capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "teapot"
    target.write_text("a file\n")
    code, err = run(["--object", "teapot", "--out", str(target)] + ["--force"] * force, capsys)
    assert code == 2
    assert err == f"error: {target}: exists and is not a folder; choose another --out\n"
    assert target.read_text() == "a file\n"


def test_existing_dataset_needs_force(tmp_path: Path, no_rendering: None,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    dataset = fake_dataset(tmp_path / "teapot")
    code, err = run(["--object", "teapot", "--out", str(dataset)], capsys)
    assert code == 2
    assert err == f"error: {dataset}: already exists (use --force to replace it)\n"
    generator.check_output_folder(str(dataset), overwrite=True)   # with --force it may go


def test_foreign_staging_folder_is_not_deleted(tmp_path: Path, no_rendering: None,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    staging = tmp_path / "teapot.partial"
    staging.mkdir()
    (staging / "keep.txt").write_text("mine\n")
    code, err = run(["--object", "teapot", "--out", str(tmp_path / "teapot")], capsys)
    assert code == 2
    assert err.startswith(f"error: {staging}: exists and is not a staging folder of this "
                          "generator")
    assert (staging / "keep.txt").read_text() == "mine\n"


def test_new_folder_is_accepted_and_an_empty_one_with_force(tmp_path: Path) -> None:
    generator.check_output_folder(str(tmp_path / "new" / "teapot"), overwrite=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileExistsError, match="already exists"):
        generator.check_output_folder(str(tmp_path / "empty"), overwrite=False)
    generator.check_output_folder(str(tmp_path / "empty"), overwrite=True)   # nothing to lose
