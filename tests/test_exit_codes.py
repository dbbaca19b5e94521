"""run_guarded (evaluate.py and demo.py): each kind of failure becomes one stderr line and its
exit status; anything else propagates."""
from __future__ import annotations

import errno

import pytest

from fracture_gs.cli.exit_codes import run_guarded
from fracture_gs.io.output_folder import OutputFolderError
from fracture_gs.pipeline.experiments.runner import RunFailed
from fracture_gs.pipeline.experiments.sim_eval import EvaluationError


def _raising(exc: BaseException):
    def function() -> None:
        raise exc
    return function


@pytest.mark.parametrize("exc, status, line", [
    (EvaluationError("/x/sim: no such simulation folder"), 2, "error: /x/sim: no such simulation folder"),
    (OutputFolderError("--out", "/proc/x: Permission denied"), 2, "error: --out"),
    (RunFailed("job teapot_ground: blew up at t=0.1s"), 1, "error: job teapot_ground: blew up at t=0.1s"),
    (OSError(errno.ENOSPC, "No space left on device", "/x/metrics.json"), 1,
     "error: /x/metrics.json: No space left on device"),
    (KeyboardInterrupt(), 130, "interrupted here"),
])
def test_each_failure_is_one_line_and_its_status(exc: BaseException, status: int, line: str, capsys) -> None:
    assert run_guarded(_raising(exc), "interrupted here") == status
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), lines


def test_status_of_the_function_is_kept() -> None:
    assert run_guarded(lambda: None, "") == 0
    assert run_guarded(lambda: 3, "") == 3


def test_programming_errors_are_not_swallowed() -> None:
    with pytest.raises(ZeroDivisionError):
        run_guarded(lambda: 1 // 0, "")
