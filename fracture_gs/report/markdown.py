"""Markdown of the evaluation reports: tables of numbers and the report.md files."""
from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from fracture_gs.io.atomic import write_text_atomic

# The paper's Fig. 5 numbers (PSNR / LPIPS / FID), printed beside ours in comparisons.
PAPER_ABLATION = {"ours": (21.1, 0.29, 90.75), "PhysGaussian": (17.2, 0.43, 120.92),
                  "GIC": (16.8, 0.45, 129.33)}


def fmt(value: object, digits: int = 4) -> str:
    """A number for a table: floats with ``digits`` significant digits, '—' for None."""
    if value is None:
        return "—"
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    number = float(value)
    if not math.isfinite(number):
        return str(number)
    return f"{number:.{digits}g}"


def table(header: Sequence[str], rows: Sequence[Sequence[object]], digits: int = 4) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(cell, digits) for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def metric_cells(metrics: dict | None) -> tuple[object, object, object, object]:
    """(PSNR mean, LPIPS mean, FID, N) of a ``SelfReferencedMetrics.to_json()`` dict; an
    unavailable metric shows its reason in short."""
    if metrics is None:
        return None, None, None, None
    lpips = metrics["lpips"]
    lpips = lpips["mean"] if isinstance(lpips, dict) else "unavailable"
    fid = metrics["fid"]
    fid = fid if not isinstance(fid, str) or fid in ("inf", "nan") else "unavailable"
    n = f"{metrics['n_reference']} / {metrics['n_window']}"
    return metrics["psnr"]["mean"], lpips, fid, n


def comparison_rows(runs: Sequence[dict]) -> list[list[object]]:
    """One table row per evaluated run (``RunResult.to_json()`` dicts)."""
    rows = []
    for run in runs:
        psnr, lpips, fid, n = metric_cells(run["metrics"])
        rows.append([run["label"], psnr, lpips, fid, n, run["window"]["note"]])
    return rows


COMPARISON_HEADER = ("run", "PSNR ↑ [dB]", "LPIPS ↓", "FID ↓", "N (ref / window)", "window")


PAIRED_HEADER = ("first vs", "PSNR advantage [dB]", "views better (PSNR)", "LPIPS advantage",
                 "views better (LPIPS)", "FID advantage", "verdict (PSNR / LPIPS / FID)")
PAIRED_DIGITS = {"psnr": 3, "lpips": 4, "fid": 2}


def advantage_text(difference: dict, metric: str) -> str:
    """'+0.012 [−0.030, +0.051]' of a ``PairedDifference.to_json()`` dict."""
    digits = PAIRED_DIGITS[metric]
    low, high = difference["interval"]
    return f"{difference['advantage']:+.{digits}f} [{low:+.{digits}f}, {high:+.{digits}f}]"


def paired_rows(comparisons: Sequence[dict]) -> list[list[object]]:
    """One table row per paired comparison (``paired_comparisons`` dicts); '—' where a metric
    is missing."""
    rows = []
    for comparison in comparisons:
        row: list[object] = [comparison["second"]]
        verdicts = []
        for metric in ("psnr", "lpips", "fid"):
            difference = comparison.get(metric)
            row.append(advantage_text(difference, metric) if difference else None)
            if metric != "fid":
                row.append(f"{difference['views_better']} of {difference['views']}"
                           if difference else None)
            verdicts.append(difference["verdict"] if difference else "—")
        row.append(" / ".join(verdicts))
        rows.append(row)
    return rows


def unavailable_notes(runs: Sequence[dict]) -> list[str]:
    """The distinct 'unavailable: expected <file>' lines and FID warnings of the runs."""
    notes: list[str] = []
    for run in runs:
        metrics = run["metrics"] or {}
        for key in ("lpips", "fid"):
            value = metrics.get(key)
            if isinstance(value, str) and value not in ("inf", "nan"):
                notes.append(f"{key.upper()} {value}")
        if metrics.get("fid_warning"):
            notes.append(f"FID: {metrics['fid_warning']}")
    return list(dict.fromkeys(notes))


def write_report(path: Path, title: str, sections: Sequence[tuple[str, str]]) -> None:
    """``report.md``: a title and (heading, markdown body) sections."""
    parts = [f"# {title}\n"]
    for heading, body in sections:
        parts.append(f"## {heading}\n\n{body.rstrip()}\n")
    write_text_atomic(Path(path), "\n".join(parts))
