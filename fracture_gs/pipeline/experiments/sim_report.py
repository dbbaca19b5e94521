"""The evaluation folder of one or more runs: ``metrics.json``, ``report.md``, the momentum and
energy plots of every simulation, and a frame strip (reference frame + window, first view).

One evaluation at a time writes a folder (its lock ``.evaluate.lock``, :func:`evaluation_folder`);
it writes only where no file is in the way that the tools did not write there, and replaces the
files of the earlier evaluation in the folder once the new one is computed."""
from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from fracture_gs.folders.sim_reader import Simulation, SimulationError, load_frame
from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import claim_folder, replace_written
from fracture_gs.metrics.pieces import last_frame_pieces, object_pieces
from fracture_gs.metrics.paired import DEFAULT_CONFIDENCE, paired_differences
from fracture_gs.metrics.protocol import MetricNetworks
from fracture_gs.pipeline.experiments.sim_eval import EvalOptions, RunResult, RunSpec, evaluate_run
from fracture_gs.report.markdown import (COMPARISON_HEADER, PAIRED_HEADER, PAPER_ABLATION,
                                         advantage_text, comparison_rows, paired_rows, table,
                                         unavailable_notes, write_report)
from fracture_gs.report.plots import diagnostics_plots, frame_strip

PAPER_ROWS = [[f"paper: {name}", *(f"{v:g}" for v in values), "—", "paper Fig. 5"]
              for name, values in PAPER_ABLATION.items()]


LOCK_FILE = ".evaluate.lock"
KIND = "evaluation"          # the manifest kind of an evaluation folder
REPORT_FILES = ("metrics.json", "report.md", "strip.png")


def _slug(label: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in label.lower()).strip("_") or "run"


def _plot_prefix(sim: Path, specs: Sequence[RunSpec]) -> str:
    """The prefix of a simulation's momentum and energy plots ('' when there is one)."""
    return "" if len({spec.sim for spec in specs}) == 1 else f"{_slug(sim.name)}_"


def report_files(specs: Sequence[RunSpec], out_dir: Path) -> list[Path]:
    """Every file :func:`evaluate_and_report` may write into ``out_dir``."""
    plots = [out_dir / f"{_plot_prefix(sim, specs)}{name}"
             for sim in dict.fromkeys(spec.sim for spec in specs)
             for name in ("momentum.png", "energy.png")]
    return [*(out_dir / name for name in REPORT_FILES), *plots]


@contextlib.contextmanager
def evaluation_folder(out_dir: Path, files: Sequence[Path]) -> Iterator[Callable[[], None]]:
    """Hold ``out_dir``'s lock and claim it for ``files`` (FolderBusy, FolderTaken); yields the
    call that, once the results are computed, removes the earlier evaluation's files and
    records ``files`` before they are written."""
    with folder_lock(out_dir, LOCK_FILE, "evaluate.py", "evaluation folder"):
        manifest = claim_folder(out_dir, KIND, files)
        yield lambda: replace_written(manifest, files)


def evaluate_and_report(specs: Sequence[RunSpec], options: EvalOptions, networks: MetricNetworks,
                        out_dir: Path, title: str, with_paper: bool = False,
                        progress: bool = False,
                        before_writing: Callable[[], object] | None = None) -> dict:
    """Evaluate every run, write ``out_dir``'s files and return the metrics.json content;
    ``before_writing`` (from :func:`evaluation_folder`) is called once every run is evaluated,
    before the first file is written."""
    started = time.perf_counter()
    results: list[RunResult] = [evaluate_run(spec, options, networks, progress) for spec in specs]
    if before_writing is not None:
        before_writing()
    out_dir.mkdir(parents=True, exist_ok=True)
    runs = [result.to_json() for result in results]

    sections: list[tuple[str, str]] = []
    rows = comparison_rows(runs) + (PAPER_ROWS if with_paper else [])
    body = table(COMPARISON_HEADER, rows)
    body += ("\nSelf-referenced protocol (docs/formulas.md §14, paper App. A.3): every window frame of every "
             "view against that view's reference frame I_ref = t_f − 1; PSNR and LPIPS are means "
             f"over {len(runs[0]['views'])} views × window frames, FID is between the set of "
             "reference renders and the set of window renders. "
             f"Views: `{options.views}` at {options.resolution[0]}×{options.resolution[1]} "
             "(or the images of the render folder given).\n")
    if with_paper:
        body += ("\nThe paper's rows are its Fig. 5 (its renders, its N); FIDs from different N "
                 "and different images are not comparable.\n")
    for note in unavailable_notes(runs):
        body += f"\n* {note}"
    sections.append(("Fracture metrics", body))
    paired = paired_comparisons(results)
    if paired:
        sections.append(("Paired comparison", paired_section(paired)))

    pieces = run_pieces(specs)
    if pieces:
        sections.append(("Pieces", pieces_section(pieces)))

    strip_rows = [(result.spec.label, result.strip,
                   [f"ref {f}" if i == 0 else f"t={f}" for i, f in enumerate(result.strip_frames)])
                  for result in results if result.strip]
    if strip_rows:
        frame_strip(strip_rows, out_dir / "strip.png")
        sections.append(("Frames", "Reference frame and window frames, first view:\n\n"
                         "![frame strip](strip.png)\n"))

    conservation = {}
    for sim in dict.fromkeys(spec.sim for spec in specs):
        prefix = _plot_prefix(sim, specs)
        momentum_png, energy_png, summary = diagnostics_plots(sim, out_dir, prefix)
        conservation[str(sim)] = summary.to_json()
        sections.append((f"Momentum and energy: `{sim.name}`",
                         table(("momentum drift (max, relative)",
                                "momentum balance p − p(0) − J (max, relative)",
                                "energy rise (max, relative)", "start energy [J]",
                                "largest momentum exchanged"),
                               [[summary.momentum_drift,
                                 summary.momentum_balance if math.isfinite(summary.momentum_balance)
                                 else "— (diagnostics.csv without impulse columns)",
                                 summary.energy_rise, summary.energy_start,
                                 summary.exchanged_momentum]])
                         + "\nJ is the impulse gravity and the boundaries (walls, ground) gave "
                         "the particles; where they act, the drift is physics and the balance is "
                         "the conservation check.\n"
                         + f"\n![momentum]({momentum_png.name})\n\n![energy]({energy_png.name})\n"))

    metrics = {"title": title, "views": options.views, "resolution": list(options.resolution),
               "window": options.window, "runs": runs, "paired": paired, "pieces": pieces,
               "conservation": conservation,
               "seconds": time.perf_counter() - started}
    write_text_atomic(out_dir / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    write_report(out_dir / "report.md", title, sections)
    return metrics


def sim_pieces(path: Path) -> list[dict]:
    """Per object of one simulation: the pieces at the first and the last frame
    (:mod:`fracture_gs.metrics.pieces`); [] where it cannot be read or its frames carry no
    fragment labels."""
    try:
        sim = Simulation.open(path)
        last = last_frame_pieces(sim)
        if last is None:
            return []
        start = load_frame(sim.frame_path(sim.frames[0]))
    except SimulationError:
        return []
    first = object_pieces(start["fragment_id"], sim.particles.obj_id, sim.object_names,
                          sim.frames[0], start.get("damage"))
    return [{"object": end.name, "pieces_first_frame": begin.pieces, **end.to_json()}
            for begin, end in zip(first, last)]


def run_pieces(specs: Sequence[RunSpec]) -> list[dict]:
    """:func:`sim_pieces` per run (label); runs of one simulation share its rows."""
    per_sim = {path: sim_pieces(path) for path in dict.fromkeys(spec.sim for spec in specs)}
    return [{"label": spec.label, **row} for spec in specs for row in per_sim[spec.sim]]


def pieces_section(pieces: Sequence[dict]) -> str:
    """Markdown of :func:`run_pieces`: one row per run and object."""
    rows = [[row["label"], row["object"], f"{row['pieces_first_frame']} → {row['pieces']}",
             f"{100 * row['largest_share']:.1f} %", f"{100 * row['complete_damage_share']:.1f} %"]
            for row in pieces]
    return (table(("run", "object", "pieces (first → last frame)", "largest piece",
                   "completely damaged"), rows)
            + "\nA piece is a connected fragment holding at least 1 % of its object's particles "
            "(docs/formulas.md §8); the largest piece is its share of the object's "
            "particles at the last frame; completely damaged: brittle particles with damage 1 "
            "(crushed material and crack faces, which belong to no piece). An intact object counts "
            "more than one piece at the first frame only where parts of it are sampled more "
            "sparsely than the rest of it.\n")


def paired_comparisons(results: Sequence[RunResult]) -> list[dict]:
    """The first run against each other run with metrics on the same (views, window frames):
    :func:`fracture_gs.metrics.paired.paired_differences` as JSON (none with fewer than 2 views)."""
    first = results[0].metrics if results else None
    if first is None or first.psnr.shape[0] < 2:
        return []
    comparisons = []
    for other in results[1:]:
        if other.metrics is None or other.metrics.psnr.shape != first.psnr.shape \
                or other.view_names != results[0].view_names:
            continue
        differences = paired_differences(first, other.metrics)
        comparisons.append({"first": results[0].spec.label, "second": other.spec.label,
                            **{name: d.to_json() for name, d in differences.items()}})
    return comparisons


def paired_section(paired: Sequence[dict]) -> str:
    """Markdown of the paired comparisons: the table and how to read it."""
    views = next((c[m]["views"] for c in paired for m in ("psnr", "lpips", "fid") if m in c), 0)
    return (table(PAIRED_HEADER, paired_rows(paired))
            + f"\nAdvantage of `{paired[0]['first']}` over each other run (positive: closer to "
            "the intact reference; PSNR(first) − PSNR(other), LPIPS(other) − LPIPS(first), "
            f"FID(other) − FID(first)), with its {DEFAULT_CONFIDENCE:.0%} interval from a bootstrap "
            f"over the {views} views (views drawn with replacement, the window frames of a view "
            "kept together; FID recomputed on each draw) and the number of views whose window "
            "mean is better. An interval that contains 0 means these views cannot tell the two "
            "runs apart.\n")


def _text_cell(value: object, digits: int) -> str:
    """A number of the plain-text table with ``digits`` decimals; a reason ('unavailable') or '—'."""
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value if value is not None else "—")


def print_comparison(metrics: dict, with_paper: bool = False) -> str:
    """The comparison table as plain text (what evaluate.py / demo.py print). Each number column is
    at least as wide as its header's default and two characters wider than its widest cell."""
    rows = comparison_rows(metrics["runs"]) + (PAPER_ROWS if with_paper else [])
    width = max(len(str(r[0])) for r in rows) + 2
    cells = [(str(label), _text_cell(psnr, 2), _text_cell(lpips, 3), _text_cell(fid, 2), n if n else "—")
             for label, psnr, lpips, fid, n, _ in rows]
    widths = [max([minimum] + [len(row[column]) + 2 for row in cells])
              for column, minimum in ((1, 9), (2, 9), (3, 10))]
    lines = [f"{'run':<{width}}{'PSNR':>{widths[0]}}{'LPIPS':>{widths[1]}}{'FID':>{widths[2]}}  N (ref/window)"]
    for label, psnr, lpips, fid, n in cells:
        lines.append(f"{label:<{width}}{psnr:>{widths[0]}}{lpips:>{widths[1]}}{fid:>{widths[2]}}  {n}")
    for comparison in metrics.get("paired", []):
        lines.append(f"{comparison['first']} vs {comparison['second']}: " + "; ".join(
            f"{name.upper()} {advantage_text(comparison[name], name)}"
            for name in ("psnr", "lpips", "fid") if name in comparison))
    for row in metrics.get("pieces", []):
        plural = "" if row["pieces"] == 1 else "s"
        lines.append(f"{row['label']}: {row['object']} in {row['pieces']} piece{plural} of >= 1 % at "
                     f"frame {row['frame']} (largest {100 * row['largest_share']:.0f} %)")
    return "\n".join(lines)
