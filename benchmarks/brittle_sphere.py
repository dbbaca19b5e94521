"""A brittle sphere dropped on the ground at four speeds, with and without crack opening (prints JSON).

The sphere (r = 0.1 m, ~30k particles on a 96³ grid, the glass-like material of docs/materials.md:
E 2 MPa, ν 0.2, ρ 100 kg/m³, σ_F 20 kPa, G_f 2 J/m², Weibull m 6) starts just above a ground of
friction 0.3 and falls at speeds whose impact stress ρ c v is 0.5, 1.26, 3.17 and 8 times the
strength. Every run is a simulate.py folder under --out (``v<speed>_fragments_<on|off>``), which
``tools/figures/brittle_sphere_strip.py`` draws. Per run the JSON gives the pieces of >= 1 % of
the particles per frame (the ``fragments`` column of diagnostics.csv: connected pieces, brittle
particles with complete damage linking to nothing), the largest count after the onset and at the
last frame, the share of particles with complete damage, the fracture energy and the largest
(kinetic + elastic + gravitational + fracture) energy over its start.

    python benchmarks/brittle_sphere.py [--out output/brittle_sphere] [--frames 20] [--grid 96]
                                        [--fracture-energy 2.0] [--seed 0] [--ratios 0.5 1.26 3.17 8]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from fracture_gs.pipeline.simulate import run_simulation
from fracture_gs.config.scene import parse_scene
from fracture_gs.folders.sim_reader import load_frame, read_diagnostics_csv

RADIUS = 0.1
GROUND = 0.05
MATERIAL = {"part": 0, "model": "brittle", "E": 2.0e6, "nu": 0.2, "density": 100.0, "strength": 2.0e4,
            "fracture_energy": 2.0, "weibull_m": 6}
STRESS_RATIOS = (0.5, 0.5 * 16 ** (1 / 3), 0.5 * 16 ** (2 / 3), 8.0)   # rho c v / sigma_F, geometric


def p_wave_speed(material: dict) -> float:
    E, nu, rho = material["E"], material["nu"], material["density"]
    return math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)) / rho)


def scene(speed: float, fragments: bool, grid: int, frames: int, frame_dt: float, material: dict,
          seed: int) -> dict:
    dx = 1.0 / grid
    return {"name": f"brittle_sphere_v{speed:.2f}", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": grid},
            "frames": frames, "frame_dt": frame_dt, "gravity": [0, 0, -9.8], "contact": {"fragments": fragments},
            "seed": seed,
            "boundaries": [{"type": "ground", "height": GROUND, "friction": 0.3}],
            "objects": [{"name": "sphere", "primitive": {"shape": "sphere", "radius": RADIUS},
                         "transform": {"translate": [0.5, 0.5, GROUND + RADIUS + 1.5 * dx]},
                         "velocity": [0, 0, -speed], "materials": [material]}]}


def summary(folder: Path, speed: float, ratio: float, fragments: bool, wall: float) -> dict:
    table = read_diagnostics_csv(folder / "diagnostics.csv")
    pieces = [int(p) for p in table["fragments"]]
    fractured = table["fractured"]
    onset = int(np.argmax(fractured > 0)) if (fractured > 0).any() else len(pieces)
    after = pieces[onset:] or [pieces[-1]]
    last = load_frame(folder / "frames" / f"frame_{len(pieces) - 1:05d}.npz")
    total = table["total_energy"] + table["dissipated_energy"]
    return {"speed": round(speed, 3), "stress_over_strength": round(ratio, 3), "fragments": fragments,
            "pieces_per_frame": pieces, "largest_pieces_after_onset": max(after), "pieces_last_frame": pieces[-1],
            "complete_damage_share": round(float((last["damage"] >= 1).mean()), 4),
            "fractured_share": round(float(last["fractured"].mean()), 4),
            "fracture_energy": round(float(table["dissipated_energy"][-1]), 5),
            "energy_peak_over_start": round(float(total.max() / total[0]), 5), "wall_s": round(wall, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("output/brittle_sphere"))
    parser.add_argument("--grid", type=int, default=96)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--frame-dt", type=float, default=0.004)
    parser.add_argument("--fracture-energy", type=float, default=MATERIAL["fracture_energy"], help="G_f in J/m^2")
    parser.add_argument("--seed", type=int, default=0, help="the scene's seed (Weibull strengths)")
    parser.add_argument("--ratios", type=float, nargs="+", default=list(STRESS_RATIOS),
                        help="impact stress rho c v over the strength, one run (pair) each")
    parser.add_argument("--fragments-only", action="store_true", help="skip the runs without crack opening")
    args = parser.parse_args()
    material = {**MATERIAL, "fracture_energy": args.fracture_energy}
    c = p_wave_speed(material)
    runs = []
    for ratio in args.ratios:
        speed = ratio * material["strength"] / (material["density"] * c)
        for fragments in (True,) if args.fragments_only else (True, False):
            folder = args.out / f"v{speed:.2f}_fragments_{'on' if fragments else 'off'}"
            config = parse_scene(scene(speed, fragments, args.grid, args.frames, args.frame_dt, material, args.seed))
            start = time.perf_counter()
            with open(Path("/dev/null"), "w") as quiet:
                run_simulation(config, folder, device=torch.device("cpu"), progress=False, log=quiet)
            runs.append(summary(folder, speed, ratio, fragments, time.perf_counter() - start))
    print(json.dumps({"benchmark": "brittle_sphere", "grid": args.grid, "radius": RADIUS, "material": material,
                      "seed": args.seed, "p_wave_speed": round(c, 2), "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
