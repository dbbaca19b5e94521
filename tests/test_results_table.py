"""The generated results tables of README.md and docs/ equal what
tools/results_table.py makes of the JSON in benchmarks/results/, so they cannot drift."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_generated_tables_equal_the_benchmark_json() -> None:
    result = subprocess.run([sys.executable, str(ROOT / "tools" / "results_table.py"), "--check"],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


def test_every_results_file_is_named_in_its_readme() -> None:
    listed = (ROOT / "benchmarks" / "results" / "README.md").read_text()
    for path in (ROOT / "benchmarks" / "results").glob("*.json"):
        assert f"`{path.name}`" in listed, path.name
