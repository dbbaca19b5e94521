"""Run a Python snippet under several OpenMP thread counts (the determinism tests)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def last_lines_per_thread_count(script: str, threads: tuple[str, ...] = ("1", "2", "3")) -> list[str]:
    """The last stdout line of ``python -c script`` run from the repository root with each
    ``OMP_NUM_THREADS`` in ``threads`` (in that order); the script can import the test modules
    (``tests/`` is on its path) and the shared scenes of :mod:`fracture_gs.testing`."""
    lines = []
    path = os.pathsep.join(filter(None, [str(ROOT / "tests"), os.environ.get("PYTHONPATH")]))
    for count in threads:
        env = dict(os.environ, OMP_NUM_THREADS=count, PYTHONPATH=path)
        result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                                check=True, cwd=ROOT)
        lines.append(result.stdout.strip().splitlines()[-1])
    return lines
