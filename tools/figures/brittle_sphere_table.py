"""The table of the brittle sphere drop, from the JSON of benchmarks/brittle_sphere.py.

    python benchmarks/brittle_sphere.py --fracture-energy 2 > g2.json
    python benchmarks/brittle_sphere.py --fracture-energy 3.5 > g35.json
    python tools/figures/brittle_sphere_table.py g2.json g35.json

Prints a markdown table: one column per impact stress, one row per (G_f, fragments on / off), each
cell the largest piece count after the onset / the count at the last frame, and the share of
particles with complete damage where it is 10 % or more.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def cell(run: dict) -> str:
    text = f"{run['largest_pieces_after_onset']} / {run['pieces_last_frame']}"
    if run["complete_damage_share"] >= 0.1:
        text += f" ({run['complete_damage_share']:.0%} crushed)"
    return text


def table(results: list[dict]) -> list[str]:
    """The markdown lines of the table for the parsed JSON outputs ``results``."""
    ratios = sorted({(run["stress_over_strength"], run["speed"]) for result in results for run in result["runs"]})
    lines = ["| ρ c v / σ_F (speed) | " + " | ".join(f"{r:g} ({v:.2f} m/s)" for r, v in ratios) + " |",
             "|---" * (len(ratios) + 1) + "|"]
    for result in results:
        for fragments in (True, False):
            runs = {run["stress_over_strength"]: run for run in result["runs"] if run["fragments"] == fragments}
            if not runs:
                continue
            label = f"G_f {result['material']['fracture_energy']:g} J/m², fragments {'on' if fragments else 'off'}"
            lines.append(f"| {label} | " + " | ".join(cell(runs[r]) if r in runs else "—" for r, _ in ratios) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("json", type=Path, nargs="+", help="outputs of benchmarks/brittle_sphere.py")
    args = parser.parse_args()
    try:
        results = [json.loads(path.read_text()) for path in args.json]
    except (OSError, ValueError) as error:   # one line, not a traceback
        parser.exit(2, f"error: {error}\n")
    print("\n".join(table(results)))

if __name__ == "__main__":
    main()
