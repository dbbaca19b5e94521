#!/usr/bin/env python
"""Wall time per stage and peak memory of ``demo.py`` (docs/results.md), printed as JSON.

    python benchmarks/bench_pipeline.py [--profile tiny|quick|default] [--out DIR] [--keep]

Runs the demo from scratch (``--force``) in a child process into ``--out`` (default a temporary
folder, removed afterwards unless ``--keep``) and reports the stage times from its
``stages.json`` and the child's peak resident memory.
"""
from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", choices=("tiny", "quick", "default"), default="tiny")
    parser.add_argument("--out", default=None)
    parser.add_argument("--keep", action="store_true")
    args = parser.parse_args()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="bench_pipeline_"))
    started = time.perf_counter()
    result = subprocess.run([sys.executable, str(ROOT / "demo.py"), "--profile", args.profile,
                             "--out", str(out), "--force"], capture_output=True, text=True)
    wall = time.perf_counter() - started
    if result.returncode != 0:
        print(result.stderr[-2000:], file=sys.stderr)
        return result.returncode
    stages = json.loads((out / "stages.json").read_text())["stages"]
    peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(json.dumps({"profile": args.profile, "wall_seconds": round(wall, 1),
                      "stage_seconds": {k: round(v["seconds"], 1) for k, v in stages.items()},
                      "peak_rss_mib": round(peak_kib / 1024, 1)}, indent=2))
    if not args.keep and args.out is None:
        shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
