"""``demo.py``: the command line of the demo (:mod:`fracture_gs.pipeline.demo`): the whole
pipeline in one command — a teapot dropped on a table shatters.

Exit status 0, 2 on invalid input or a failed stage's bad input (one ``error: ...`` line), 1
when a simulation fails, 130 when interrupted (finished stages are kept and skipped next time).
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from fracture_gs.cli.exit_codes import run_guarded
from fracture_gs.io.device import DEVICE_CHOICES, DeviceError, resolve_device
from fracture_gs.pipeline.demo import PROFILES, Demo, run_demo
from fracture_gs.pipeline.experiments.sim_eval import EvaluationError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="demo.py", description="Train a teapot and a table from synthetic photos, drop the "
        "teapot on the table, render it with and without FPGO, simulate the MLS-MPM baseline "
        "and compare them (PSNR / LPIPS / FID).")
    parser.add_argument("--quick", action="store_true", help="the small version (profile quick)")
    parser.add_argument("--profile", choices=sorted(PROFILES), default=None,
                        help="default | quick | tiny (tiny: the test suite's version)")
    parser.add_argument("--out", default=None, help="output folder (default output/demo, "
                        "output/demo_<profile>)")
    parser.add_argument("--data", default=None, help="dataset folder holding teapot/ and table/ "
                        "(default data/ for the default profile, <out>/data otherwise)")
    parser.add_argument("--force", action="store_true", help="redo every stage")
    parser.add_argument("--weights-dir", default=None,
                        help="folder with alexnet.ckpt and default_1.pt (LPIPS / FID weights)")
    parser.add_argument("--workers", type=int, default=1,
                        help="run the two simulations in parallel processes (default 1)")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=None)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    profile = PROFILES["quick" if args.quick else (args.profile or "default")]
    out = Path(args.out) if args.out else Path("output") / (
        "demo" if profile.name == "default" else f"demo_{profile.name}")
    data = Path(args.data) if args.data else (Path("data") if profile.name == "default"
                                               else out / "data")

    def run() -> None:
        if args.quick and args.profile not in (None, "quick"):
            raise EvaluationError(f"--quick and --profile {args.profile} contradict each other")
        if args.workers < 1:
            raise EvaluationError(f"--workers {args.workers}: must be >= 1")
        if out.exists() and not out.is_dir():
            raise EvaluationError(f"--out {out}: exists and is not a folder")
        try:
            device = resolve_device(args.device)
        except DeviceError as exc:
            raise EvaluationError(str(exc)) from None
        run_demo(Demo(out=out, data=data, profile=profile, force=args.force, device=device,
                      weights_dir=args.weights_dir, workers=args.workers))

    return run_guarded(run, f"interrupted; finished stages are kept in {out / 'stages.json'} "
                       "and skipped next time")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
