"""Generates the results tables of README.md, docs/results.md and docs/materials.md from
benchmarks/results/*.json.

    python tools/results_table.py            # print every generated block
    python tools/results_table.py --write    # rewrite the blocks in README.md and docs/
    python tools/results_table.py --check    # exit 1 when a document differs from the JSON

A generated block sits between ``<!-- generated:NAME -->`` and ``<!-- /generated:NAME -->`` and
is never edited by hand: re-run the benchmark named in the table, store its JSON under
benchmarks/results/ (the commands are in benchmarks/results/README.md), then ``--write``.
``tests/test_results_table.py`` runs ``--check``.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT / "tools" / "figures"))
from brittle_sphere_table import table as sphere_table  # noqa: E402  (a sibling tool)
sys.path.insert(0, str(ROOT / "benchmarks"))
from scene_pieces import markdown as pieces_table  # noqa: E402  (the benchmark's own table)

SPHERE_FILES = ("brittle_sphere_gf2.json", "brittle_sphere_gf3.5.json", "brittle_sphere_gf5.json")
NOTCHED_BAR_FILE = "brittle_bar_notched.json"
PLATE_FILES = ("notched_plate_64.json", "notched_plate_128.json")
DISC_FILE = "brittle_disc.json"


def load(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def _sphere_runs() -> tuple[list[dict], dict]:
    results = [load(name) for name in SPHERE_FILES]
    return results, results[-1]


def _span(values: list, form: str) -> str:
    """'low–high' of the values in the given format, one value where both ends print alike."""
    low, high = format(min(values), form), format(max(values), form)
    return low if low == high else f"{low}–{high}"


def scene_pieces_row(name: str, what: str) -> str:
    """A results row of one ``benchmarks/scene_pieces.py`` JSON: the first object's pieces of >= 1 %,
    largest piece and crushed share over the seeds."""
    result = load(name)
    runs = [run["objects"][0] for run in result["runs"]]
    pieces = [run["pieces"] for run in runs]
    largest = [run["largest_share"] for run in runs]
    crushed = [run["complete_damage_share"] for run in runs]
    return (f"| {what} (`{result['scene']}`, grid {result['grid']}), {len(runs)} seeds: pieces of ≥ 1 % / "
            f"largest piece / crushed | {_span(pieces, 'd')} / {_span(largest, '.0%')} / "
            f"{_span(crushed, '.0%')} | `benchmarks/scene_pieces.py` |")


def notched_bar_row() -> str:
    """The README row of the notched bar: fracture energy per broken area over G_f at each grid."""
    bar = load(NOTCHED_BAR_FILE)
    grids = sorted({run["grid"] for run in bar["runs"]})
    factors = sorted({run["factor"] for run in bar["runs"]})
    ratios = [run["energy_per_broken_area_over_Gf"] for run in bar["runs"]]
    shown = _span(ratios, ".2f") if None not in ratios else "no break"
    return (f"| notched brittle bar ({bar['ligament']:.0%} of the cross-section left) pulled apart at "
            f"{' and '.join(f'{f:g}' for f in factors)} × its strength, grids {' and '.join(map(str, grids))}: "
            f"fracture energy per broken area / G_f | {shown} | `benchmarks/brittle_bar.py --ligament "
            f"{bar['ligament']:g}` |")


def plate_row() -> str:
    """The README row of the notched plate at its finest grid: the angle of each tip's crack."""
    run = max((run for name in PLATE_FILES for run in load(name)["runs"]), key=lambda run: run["grid"])
    angles = " / ".join("none" if crack["angle_deg"] is None else f"{crack['angle_deg']:.0f}°"
                        for crack in run["cracks"])
    return (f"| edge-notched plate struck between its notches at {run['speed']:g} m/s (Kalthoff and Winkler; "
            f"about 70° in experiments), grid {run['grid']}: angle of the crack from each notch tip | {angles} | "
            f"`benchmarks/notched_plate.py` |")


def disc_row() -> str:
    """The README row of the spun disc above its burst speed (uniform strength)."""
    disc = load(DISC_FILE)
    run = max((run for run in disc["runs"] if run["weibull_m"] == 0), key=lambda run: run["ratio"])
    return (f"| free brittle disc suddenly spun at {run['ratio']:g} × its burst speed, grid {run['grid']}: pieces of "
            f"≥ 1 % / completely damaged | {run['pieces']} / {run['cracked_share']:.0%} | "
            f"`benchmarks/brittle_disc.py` |")


def readme_block() -> list[str]:
    """The README's one results table: each row names the benchmark whose JSON holds the figure."""
    spheres, strong = _sphere_runs()
    top = max(run["stress_over_strength"] for run in strong["runs"])
    breaking = next(run for run in strong["runs"] if run["stress_over_strength"] == top and run["fragments"])
    below = [run for run in strong["runs"] if run["stress_over_strength"] < top]
    energy_peak = max(run["energy_peak_over_start"] for result in spheres for run in result["runs"])
    bar = load("brittle_bar.json")
    bar_fine = max(run["grid"] for run in bar["runs"])
    bar_top = max((run for run in bar["runs"] if run["grid"] == bar_fine), key=lambda run: run["factor"])
    mpm = load("bench_mpm.json")
    largest = max(entry["particles"] for entry in mpm["brittle_cost"])
    fragment_cost = next(entry["ratio"] for entry in mpm["fragment_cost"] if entry["particles"] == largest)
    brittle_cost = next(entry["ratio"] for entry in mpm["brittle_cost"] if entry["particles"] == largest)
    sphere_cmd = f"`benchmarks/brittle_sphere.py --fracture-energy {strong['material']['fracture_energy']:g}`"
    return [
        "| result | value | printed by |",
        "|---|---|---|",
        f"| brittle sphere dropped at {top:g} × its strength (G_f {strong['material']['fracture_energy']:g} J/m², "
        f"cracks opening): pieces of ≥ 1 % after the impact / at the last frame | "
        f"{breaking['largest_pieces_after_onset']} / {breaking['pieces_last_frame']} "
        f"({breaking['complete_damage_share']:.0%} of the particles crushed) | {sphere_cmd} |",
        f"| the same sphere at ≤ {max(run['stress_over_strength'] for run in below):g} × its strength: pieces | "
        f"{max(run['pieces_last_frame'] for run in below)} (it stays whole) | {sphere_cmd} |",
        f"| largest total energy (kinetic + elastic + gravitational + fracture) over its start, "
        f"{sum(len(result['runs']) for result in spheres)} sphere runs | {energy_peak:.4f} | "
        "`benchmarks/brittle_sphere.py` |",
        scene_pieces_row("scene_pieces_teapot_ground_porcelain.json",
                         "trained porcelain teapot thrown onto the floor"),
        scene_pieces_row("scene_pieces_teapot_table_porcelain.json",
                         "the same teapot thrown onto a trained table at 10 m/s"),
        scene_pieces_row("scene_pieces_demo_default.json", "`demo.py`: its porcelain teapot (softened 300 times) thrown onto its rigid table"),
        scene_pieces_row("scene_pieces_demo_quick.json", "`demo.py --quick`: the same"),
        f"| brittle bar pulled apart at {bar_top['factor']:g} × its strength, grid {bar_fine}: pieces | "
        f"{bar_top['pieces']} | `benchmarks/brittle_bar.py` |",
        notched_bar_row(),
        plate_row(),
        disc_row(),
        *mpm_rows(mpm),
        f"| step time with cracks opening (`fragments: true`) / without, NACC, {largest:,} particles | "
        f"× {fragment_cost:.2f} | `benchmarks/bench_mpm.py` |",
        f"| step time, brittle / NACC material (both with cracks opening), {largest:,} particles | "
        f"× {brittle_cost:.2f} | `benchmarks/bench_mpm.py` |",
    ]


def mpm_rows(mpm: dict) -> list[str]:
    """One README row per material and crack opening: the compiled step's speed at each particle count."""
    rows = []
    for material in ("nacc", "brittle"):
        for fragments in (False, True):
            runs = sorted((row for row in mpm["results"] if row["backend"] == "cpp" and row["material"] == material
                           and row["fragments"] == fragments), key=lambda row: row["particles"])
            if not runs:
                continue
            counts = " / ".join(f"{row['particles']:,}" for row in runs)
            speeds = " / ".join(f"{row['particle_steps_per_s'] / 1e6:.1f}" for row in runs)
            rows.append(f"| Collision-MPM step, {material.replace('nacc', 'NACC')}, cracks "
                        f"{'opening' if fragments else 'not opening'}, grid {mpm['grid']}, {mpm['device']} "
                        f"({mpm['threads']} threads): M particle-steps/s at {counts} particles | {speeds} | "
                        "`benchmarks/bench_mpm.py` |")
    return rows


def profile_block() -> list[str]:
    """``benchmarks/profile_step.py``'s JSON: milliseconds per step of each op, per configuration."""
    profile = load("profile_step.json")
    widest = max(profile["results"], key=lambda row: len(row["ops_ms_per_step"]))
    ops = list(widest["ops_ms_per_step"])   # the order the step calls them, then other
    lines = ["| material | cracks opening | particles | ms per step | " + " | ".join(ops) + " |",
             "|---|---|---|---|" + "---|" * len(ops)]
    for row in profile["results"]:
        cells = [f"{row['ops_ms_per_step'][op]:.1f}" if op in row["ops_ms_per_step"] else "—" for op in ops]
        lines.append(f"| {row['material']} | {'on' if row['fragments'] else 'off'} | {row['particles']:,} | "
                     f"{row['ms_per_step']:.1f} | " + " | ".join(cells) + " |")
    return lines


def bar_block(name: str = "brittle_bar.json") -> list[str]:
    """The runs of one ``benchmarks/brittle_bar.py`` JSON (a plain or a notched bar), one row each; a
    notched bar's rows also give how wide its damaged band is."""
    bar = load(name)
    notched = "ligament" in bar
    head = "| grid | strength multiple | pieces | damaged particles | fracture energy per broken area / G_f |"
    rule = "|---|---|---|---|---|"
    if notched:
        head += " damaged particles within one cell of the crack | band width holding 90 % of them (cells) |"
        rule += "---|---|"
    lines = [head, rule]
    for run in bar["runs"]:
        ratio = run["energy_per_broken_area_over_Gf"]
        row = (f"| {run['grid']} ({run['particles']:,} particles) | {run['factor']:g} | {run['pieces']} | "
               f"{run['damaged_particles']:,} | {'—' if ratio is None else f'{ratio:.2f}'} |")
        if notched:
            band = run["band"]
            row += (" — | — |" if band["within_one_cell"] is None
                    else f" {band['within_one_cell']:.0%} | {band['width_90_cells']:.1f} |")
        lines.append(row)
    return lines


def plate_block() -> list[str]:
    """``benchmarks/notched_plate.py`` at each grid: per notch tip, the crack that leaves it."""
    lines = ["| grid (plate particles) | impact speed | notch tip | crack angle to the notch | damaged particles "
             "within one cell of the crack line | crack length | plate particles damaged / completely |",
             "|---|---|---|---|---|---|---|"]
    for name in PLATE_FILES:
        for run in load(name)["runs"]:
            for tip, crack in zip(("upper", "lower"), run["cracks"]):
                angle = "no crack" if crack["angle_deg"] is None else f"{crack['angle_deg']:.0f}°"
                within = "—" if crack["within_one_cell"] is None else f"{crack['within_one_cell']:.0%}"
                lines.append(f"| {run['grid']} ({run['particles']:,}) | {run['speed']:g} m/s | {tip} | {angle} | "
                             f"{within} | {crack['length'] * 100:.1f} cm | {run['damaged_particles']:,} / "
                             f"{run['cracked_particles']:,} |")
    return lines


def disc_block() -> list[str]:
    """``benchmarks/brittle_disc.py``: each run's pieces and damage at the end."""
    disc = load(DISC_FILE)
    lines = ["| strength | spin / burst speed | pieces of ≥ 1 % | largest piece | completely damaged | "
             "any damage | momentum drift | energy peak / start |",
             "|---|---|---|---|---|---|---|---|"]
    for run in disc["runs"]:
        strength = "uniform" if run["weibull_m"] == 0 else f"Weibull m = {run['weibull_m']:g}"
        lines.append(f"| {strength} | {run['ratio']:g} | {run['pieces']} | {run['largest_share']:.0%} | "
                     f"{run['cracked_share']:.0%} | {run['damaged_share']:.1%} | {run['momentum_drift']:.1e} | "
                     f"{run['energy_peak_over_start']:.4f} |")
    return lines


def mpm_block() -> list[str]:
    mpm = load("bench_mpm.json")
    lines = ["| material | cracks opening | particles | ms per step | M particle-steps/s (range of the blocks) |",
             "|---|---|---|---|---|"]
    for row in mpm["results"]:
        low, high = row["particle_steps_per_s_range"]
        lines.append(f"| {row['material']} ({row['backend']}) | {'on' if row['fragments'] else 'off'} | "
                     f"{row['particles']:,} | {row['ms_per_step']:.1f} | "
                     f"{row['particle_steps_per_s'] / 1e6:.2f} ({low / 1e6:.2f}–{high / 1e6:.2f}) |")
    return lines


def gaussianfluent_block() -> list[str]:
    """``benchmarks/bench_gaussianfluent.py``'s JSON: both steps per configuration and size, their ratio,
    and the two runs' motion after the same steps."""
    result = load("bench_gaussianfluent.json")
    lines = ["| material | cracks opening | particles | ours: ms per step | GaussianFluent (Warp CPU): ms per step | "
             "GaussianFluent / ours (range of the rounds) | fastest block / fastest block |",
             "|---|---|---|---|---|---|---|"]
    for row in result["results"]:
        ratio = row["gaussianfluent_over_ours"]
        low, high = ratio["round_ratio_range"]
        lines.append(f"| {row['configuration']['material']} | {'on' if row['configuration']['fragments'] else 'off'} | "
                     f"{row['particles']:,} | {row['ours']['ms_per_step']:.1f} | "
                     f"{row['gaussianfluent']['ms_per_step']:.0f} | × {ratio['ratio']:.1f} ({low:.1f}–{high:.1f}) | "
                     f"× {ratio['fastest_block_ratio']:.1f} |")
    lines += ["", "| particles | steps (simulated time) | sphere centre moved along x: ours / GaussianFluent | "
              "sphere mean velocity along x: ours / GaussianFluent | total momentum along z | particles with NaN | "
              "GaussianFluent unguarded, first step: particles with NaN |", "|---|---|---|---|---|---|---|"]
    for scene in result["same_scene"]:
        ours, theirs = scene["ours"], scene["gaussianfluent"]
        moved = " / ".join(f"{run['spheres'][0]['centre_displacement'][0] * 1e3:.1f} mm" for run in (ours, theirs))
        speed = " / ".join(f"{run['spheres'][0]['mean_velocity'][0]:.2f} m/s" for run in (ours, theirs))
        lines.append(f"| {scene['particles']:,} | {scene['steps']} ({scene['simulated_time_s'] * 1e3:.2f} ms) | {moved} | "
                     f"{speed} | {ours['momentum'][2]:.4g} / {theirs['momentum'][2]:.4g} kg m/s | "
                     f"{ours['nan_particles']} / {theirs['nan_particles']} | "
                     f"{scene['unguarded_g2p_nan_particles_first_step']} |")
    return lines


def pieces_blocks(*scenes: str) -> dict:
    """Generated blocks ``pieces-<scene>`` of a document: each scene's ``scene_pieces_<scene>.json`` as
    ``benchmarks/scene_pieces.py --markdown`` prints it."""
    return {f"pieces-{scene.replace('_', '-')}": (lambda scene=scene: pieces_table(
        load(f"scene_pieces_{scene}.json")).splitlines()) for scene in scenes}


BLOCKS = {
    "README.md": {"results": readme_block},
    "docs/results.md": {"brittle-sphere": lambda: sphere_table([load(name) for name in SPHERE_FILES]),
                        "gaussianfluent": gaussianfluent_block,
                        "brittle-bar": bar_block, "brittle-bar-notched": lambda: bar_block(NOTCHED_BAR_FILE),
                        "notched-plate": plate_block, "brittle-disc": disc_block,
                        "mpm-step": mpm_block, "mpm-profile": profile_block, **pieces_blocks("demo_default", "demo_quick")},
    "docs/materials.md": pieces_blocks("teapot_ground_porcelain", "teapot_table_porcelain",
                                       "bowl_teapot_porcelain", "ficus_table_porcelain"),
}


def render(text: str, name: str, lines: list[str]) -> str:
    pattern = re.compile(rf"(<!-- generated:{re.escape(name)} -->\n).*?(<!-- /generated:{re.escape(name)} -->)",
                         re.DOTALL)
    if not pattern.search(text):
        raise SystemExit(f"error: no block '{name}' (<!-- generated:{name} --> ... <!-- /generated:{name} -->)")
    return pattern.sub(lambda match: match.group(1) + "\n".join(lines) + "\n" + match.group(2), text)


def expected(document: str) -> tuple[str, str]:
    """(the document as it is, the document with its generated blocks regenerated)."""
    text = (ROOT / document).read_text()
    new = text
    for name, make in BLOCKS[document].items():
        new = render(new, name, make())
    return text, new


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite the generated blocks in place")
    mode.add_argument("--check", action="store_true", help="exit 1 if a document's blocks differ from the JSON")
    args = parser.parse_args(argv)
    stale = []
    for document, blocks in BLOCKS.items():
        if not args.write and not args.check:
            for name, make in blocks.items():
                print(f"<!-- {document}: {name} -->\n" + "\n".join(make()) + "\n")
            continue
        text, new = expected(document)
        if args.write and new != text:
            (ROOT / document).write_text(new)
        elif args.check and new != text:
            stale.append(document)
    if stale:
        print("stale generated blocks in " + ", ".join(stale) + ": run python tools/results_table.py --write",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
