"""benchmarks/bench_gaussianfluent.py without GaussianFluent or Warp: its command line refuses a
folder that is not a GaussianFluent checkout with one line and status 2, and the guard it puts
into GaussianFluent's G2P floors exactly the divisions by the grid mass."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import bench_gaussianfluent as bench  # noqa: E402


def test_a_folder_without_its_solver_is_one_error_line_and_status_2(tmp_path: Path, capsys) -> None:
    (tmp_path / "mpm_solver_warp").mkdir()
    (tmp_path / "mpm_solver_warp" / "mpm_solver_warp.py").write_text("")
    assert bench.main(["--gaussianfluent", str(tmp_path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --gaussianfluent") and "mpm_utils.py" in lines[0]


@pytest.mark.parametrize("argv, word", [(["--steps", "0"], "--steps"), (["--particles", "10"], "--particles"),
                                        (["--grid", "4"], "--grid")])
def test_bad_sizes_are_refused(tmp_path: Path, argv: list[str], word: str) -> None:
    (tmp_path / "mpm_solver_warp").mkdir()
    for name in bench.SOLVER_FILES:
        (tmp_path / "mpm_solver_warp" / name).write_text("")
    with pytest.raises(bench.BadInput, match=word):
        bench.parse_args(["--gaussianfluent", str(tmp_path), *argv])


def test_the_guard_floors_only_the_division_by_the_grid_mass() -> None:
    source = ("def g2p(state, model, p):\n"
              "    old_v = old_v + state.grid_v_in[ix, iy, iz] * weight / state.grid_m[ix, iy, iz]\n"
              "    scale = weight / model.dx\n"
              "    mass = state.grid_m[ix, iy, iz] * 2.0\n")
    guard = bench._GuardGridMassDivision(1e-30)
    tree = guard.visit(ast.parse(source))
    assert guard.replaced == 1
    lines = ast.unparse(tree).splitlines()
    assert lines[1].strip() == ("old_v = old_v + state.grid_v_in[ix, iy, iz] * weight / "
                                "wp.max(state.grid_m[ix, iy, iz], 1e-30)")
    assert lines[2].strip() == "scale = weight / model.dx"
    assert lines[3].strip() == "mass = state.grid_m[ix, iy, iz] * 2.0"
