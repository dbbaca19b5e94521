"""The evaluate stage: self-referenced fracture metrics of simulations, static metrics
of a trained model, and the paper's experiments.

* :func:`evaluate_simulation` — fracture onset, reference frame, window and the
  self-referenced PSNR / LPIPS / FID of a run (``compare``: also without FPGO, and an mls run
  without FPGO); writes ``<sim>/evaluation/{metrics.json, report.md, momentum.png, energy.png,
  strip.png}``.
* :func:`evaluate_trained_model` — PSNR / SSIM / LPIPS on a model's test views.
* :func:`run_experiments` — the paper's experiments, each under ``<out>/<name>/``.

Every check of the input happens before the first file is written; errors are
:class:`~fracture_gs.pipeline.experiments.sim_eval.EvaluationError` (one line). An evaluation
folder is written by one evaluation at a time and only where no file is in the way that the
tools did not write there (:func:`~fracture_gs.pipeline.experiments.sim_report.evaluation_folder`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.model_layout import EVALUATION_DIR, latest_point_cloud
from fracture_gs.io.output_folder import prepare_output_folder
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.metrics.protocol import MetricNetworks
from fracture_gs.pipeline.experiments.sim_eval import (EvalOptions, EvaluationError, RunSpec, check_run,
                                                      check_same_scene, run_of_renders)
from fracture_gs.pipeline.experiments.static_eval import StaticResult
from fracture_gs.render.views import ViewSpecError, check_image_size

EXPERIMENTS = ("ablation", "hardening", "nv-sweep", "momentum", "energy")


@dataclass(frozen=True)
class MetricChoice:
    """Which learned metrics to compute and where their weights are."""

    weights_dir: str | None = None
    lpips: bool = True
    fid: bool = True

    def load(self, device: torch.device, fid: bool = True) -> MetricNetworks:
        """The metric networks (EvaluationError for a missing ``weights_dir``)."""
        if self.weights_dir is not None and not Path(self.weights_dir).is_dir():
            raise EvaluationError(f"--weights-dir {self.weights_dir}: no such folder")
        return MetricNetworks.load(device, self.weights_dir, lpips=self.lpips,
                                   fid=fid and self.fid)


def checked_eval_options(views: str, resolution: tuple[int, int], window: int,
                         background: str | None,
                         device: torch.device, backend: str) -> EvalOptions:
    """:class:`EvalOptions` after checking them (EvaluationError naming the option)."""
    if min(resolution) < 8:
        raise EvaluationError(f"--resolution {resolution[0]} {resolution[1]}: sizes must be >= 8")
    try:
        check_image_size(*resolution, "--resolution")
    except ViewSpecError as exc:
        raise EvaluationError(str(exc)) from None
    if window < 1:
        raise EvaluationError(f"--window {window}: must be >= 1")
    from fracture_gs._backend import use_compiled

    try:
        use_compiled(device, backend)
    except RuntimeError as exc:
        raise EvaluationError(f"--backend: {exc}") from None
    return EvalOptions(views=views, resolution=(resolution[0], resolution[1]), window=window,
                       background=background, device=device, backend=backend)


def evaluate_simulation(sim: Path, *, options: EvalOptions, metrics: MetricChoice,
                        out: Path | None = None, fpgo: bool = True, renders: Path | None = None,
                        compare: bool = False, mls: Path | None = None,
                        progress: bool = True) -> tuple[dict[str, Any], Path]:
    """Evaluate the run in ``sim`` (module docstring); returns the metrics and the folder they
    were written to (``<sim>/evaluation`` unless ``out``)."""
    from fracture_gs.pipeline.experiments.sim_report import (evaluate_and_report,
                                                             evaluation_folder, report_files)

    if mls and not compare:
        raise EvaluationError("--mls: only used with --compare")
    if compare:
        if renders is not None:
            raise EvaluationError("--renders: not used with --compare (each run is rendered)")
        specs = [RunSpec("ours (collision + FPGO)", sim, True, contact="collision"),
                 RunSpec("collision, no FPGO", sim, False, contact="collision")]
        if mls:
            specs.append(RunSpec("mls, no FPGO (PhysGaussian / GIC)", mls, False, contact="mls"))
    elif renders is not None:  # labelled from the folder's render.json; fpgo=False must agree
        specs = [run_of_renders(sim, renders, None if fpgo else False)]
    else:
        specs = [RunSpec("FPGO" if fpgo else "no FPGO", sim, fpgo)]
    opened = [check_run(spec) for spec in specs]  # a wrong simulation fails here, before the
    if mls:                                         # folder probe and the networks
        check_same_scene(opened[-1], opened[0])
    out_dir = prepare_output_folder(out if out is not None else SimLayout(sim).evaluation_dir,
                                    "--out", keep=False)  # made when the results are written
    networks = metrics.load(options.device)
    with evaluation_folder(out_dir, report_files(specs, out_dir)) as before_writing:
        result = evaluate_and_report(specs, options, networks, out_dir,
                                     f"Evaluation of {sim.name}", with_paper=compare,
                                     progress=progress, before_writing=before_writing)
    return result, out_dir


def evaluate_trained_model(model: Path, *, split: str, device: torch.device,
                           metrics: MetricChoice, out: Path | None = None
                           ) -> tuple[StaticResult, Path]:
    """PSNR / SSIM / LPIPS of a trained model's ``split`` views; writes ``metrics.json``,
    ``report.md`` and ``strip.png`` into ``out`` (default ``<model>/evaluation``). Returns the
    result and that folder."""
    from fracture_gs.pipeline.experiments.sim_report import REPORT_FILES, evaluation_folder
    from fracture_gs.pipeline.experiments.static_eval import evaluate_model

    latest_point_cloud(model)  # a trained model before an output folder is made inside it
    out_dir = prepare_output_folder(out if out is not None else model / EVALUATION_DIR, "--out",
                                    keep=False)  # checked now, made when the results are written
    networks = metrics.load(device, fid=False)
    with evaluation_folder(out_dir, [out_dir / name for name in REPORT_FILES]) as before_writing:
        result = evaluate_model(model, networks, split, device)
        before_writing()
        _write_model_report(model, result, out_dir)
    return result, out_dir


def _write_model_report(model: Path, result: StaticResult, out_dir: Path) -> None:
    """``metrics.json``, ``report.md`` and ``strip.png`` of a model's static evaluation."""
    from fracture_gs.report.markdown import table, write_report
    from fracture_gs.report.plots import frame_strip

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


def run_experiments(names: tuple[str, ...], *, out_root: Path, configs: Path, device: torch.device,
                    eval_options: EvalOptions, metrics: MetricChoice, workers: int = 1,
                    ray_address: str | None = None, frames: int | None = None,
                    grid: int | None = None, force: bool = False, progress: bool = True,
                    nv_values: list[int] | None = None,
                    alpha0_values: list[float] | None = None) -> None:
    """Run the experiments ``names`` (of :data:`EXPERIMENTS`), each under ``out_root/<name>``;
    ``force`` re-runs simulations that are complete (replacing only the files the tools wrote
    for them)."""
    from fracture_gs.pipeline.experiments.suites import ExperimentSettings, run_experiment

    if workers < 1:
        raise EvaluationError(f"--workers {workers}: must be >= 1")
    if nv_values is not None and (len(nv_values) < 2 or min(nv_values) < 0):
        raise EvaluationError("--nv-values: give at least two values >= 0")
    if alpha0_values is not None and max(alpha0_values) > 0:
        raise EvaluationError("--alpha0-values: alpha0 = ln(J_p0) must be <= 0")
    extra: dict[str, Any] = {}
    if nv_values is not None:
        extra["nv_values"] = tuple(sorted(set(nv_values)))
    if alpha0_values is not None:
        extra["alpha0_values"] = tuple(alpha0_values)
    out_root = prepare_output_folder(out_root, "--out", keep=False)
    settings = ExperimentSettings(
        configs=configs, out_root=out_root, workers=workers, ray_address=ray_address,
        frames=frames, grid=grid, force=force, device=device, eval_options=eval_options,
        weights_dir=metrics.weights_dir, lpips=metrics.lpips, fid=metrics.fid,
        progress=progress, **extra)
    for name in names:
        run_experiment(name, settings)
