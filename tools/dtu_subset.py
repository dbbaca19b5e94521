"""A few views of a DTU / NeuS folder, shrunk, in the same layout: small real captures for tests.

``tests/data/dtu_skull_mini`` was made with (from the DTU scan65 folder of the NeuF repository,
see that folder's README.md)::

    python tools/dtu_subset.py <dtu_scan65> tests/data/dtu_skull_mini --views 0 4 8 12 16 20 24 28 32 36 40 44 --factor 16

Usage: python tools/dtu_subset.py SOURCE OUT --views I [I ...] --factor F
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from fracture_gs.data import DatasetError  # noqa: E402
from fracture_gs.data.dtu import write_dtu_subset  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="DTU / NeuS folder (cameras_sphere.npz, image/, mask/)")
    parser.add_argument("out", help="folder to write")
    parser.add_argument("--views", type=int, nargs="+", required=True, help="view indices")
    parser.add_argument("--factor", type=int, default=16, help="shrink factor (default 16)")
    args = parser.parse_args(argv)
    if args.factor < 1:
        print(f"error: --factor {args.factor}: must be >= 1", file=sys.stderr)
        return 2
    try:
        write_dtu_subset(args.source, args.out, args.views, args.factor)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {len(args.views)} views to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
