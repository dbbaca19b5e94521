"""A brittle bar pulled apart by an initial velocity gradient, at two grid resolutions (prints JSON).

The bar (0.4 × 0.05 × 0.05 m, the glass-like material of docs/materials.md with Weibull off, no
gravity, no boundaries) starts unstressed with v(x) = L (x − c), L = [[r, 0, 0], 0, 0]. The free
ends release the stress, so the centre's stress peaks at ρ c v_end = ρ c r 0.2 when the release
waves meet there; r is chosen so that this peak is --factors times the strength. Per run the JSON
gives the pieces (>= 1 % of the particles), the fracture energy and the fracture energy per unit
broken cross-section over G_f, fracture_energy / ((pieces − 1) · A · G_f), the particles with any
and with complete damage, the damaged band's width across the bar (``band``: around the median rest
position of the completely damaged particles, the share of the damaged particles within one cell
and the width in cells that holds 90 % of them; meaningful where one crack formed) and the largest
(kinetic + elastic + fracture) energy over its start.

A plain bar overloads the central 1 − 1/factor of its length at once (the stress at x peaks at
ρ c r times the distance to the nearer end), and all of it softens before one crack takes the
load. --ligament s notches the bar as fracture-energy tests do: a slot SLOT_WIDTH wide at the
centre cuts the top 1 − s of the cross-section, so that with factors below 1 only the remaining
ligament (area s · A, the broken cross-section) reaches the strength and one crack forms there.

    python benchmarks/brittle_bar.py [--grids 64 128] [--factors 1.1 1.5 2 3] [--frames 40]
    python benchmarks/brittle_bar.py --ligament 0.5 --grids 128 256 --factors 0.8 1
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time

import torch

from fracture_gs.config.scene import parse_scene
from fracture_gs.mpm.scene import BuiltScene, build_scene
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.testing.brittle_scenes import advance_sampled, band_profile

LENGTH, WIDTH = 0.4, 0.05
CENTRE = 0.5               # the bar's centre on every axis (the domain is the unit cube)
SLOT_WIDTH = 1.0 / 128     # width of the notch's slot along the bar (m), the same at every grid
MATERIAL = {"part": 0, "model": "brittle", "E": 2.0e6, "nu": 0.2, "density": 100.0, "strength": 2.0e4,
            "fracture_energy": 2.0}


def p_wave_speed() -> float:
    E, nu, rho = MATERIAL["E"], MATERIAL["nu"], MATERIAL["density"]
    return math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu)) / rho)


def bar_scene(grid: int, rate: float, frames: int, frame_dt: float) -> dict:
    return {"name": "brittle_bar", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": grid}, "frames": frames,
            "frame_dt": frame_dt, "gravity": [0, 0, 0], "boundaries": [], "contact": {"fragments": True},
            "objects": [{"name": "bar", "primitive": {"shape": "box", "size": [LENGTH, WIDTH, WIDTH]},
                         "transform": {"translate": [CENTRE] * 3},
                         "velocity_gradient": [[rate, 0, 0], [0, 0, 0], [0, 0, 0]], "materials": [MATERIAL]}]}


def notch(built: BuiltScene, ligament: float) -> BuiltScene:
    """The scene without the particles of the slot: |x − c| < SLOT_WIDTH / 2 along the bar, and
    above the ligament (the bottom ``ligament`` share of the cross-section stays)."""
    x = built.particles.x
    in_slot = ((x[:, 0] - CENTRE).abs() < 0.5 * SLOT_WIDTH) & (x[:, 2] - CENTRE > (ligament - 0.5) * WIDTH)
    keep = torch.nonzero(~in_slot).flatten()
    return dataclasses.replace(built, particles=built.particles.take(keep))


def run(grid: int, factor: float, frames: int, frame_dt: float, ligament: float | None = None) -> dict:
    rate = factor * 2.0 * MATERIAL["strength"] / (MATERIAL["density"] * p_wave_speed() * LENGTH)
    config = parse_scene(bar_scene(grid, rate, frames, frame_dt))
    built = build_scene(config)
    if ligament is not None:
        built = notch(built, ligament)
    solver = CollisionMPM(built.particles, built.materials, built.domain, contact=built.contact,
                          boundaries=built.boundaries, gravity=built.gravity, cfl=built.cfl,
                          object_names=built.object_names, seed=config.seed)
    began = time.perf_counter()
    _, samples, peak = advance_sampled(solver, [frame_dt] * frames)
    diagnostics = samples[-1]
    damage = solver.frame_fields_in_input_order()["damage"]
    pieces = int(diagnostics["fragments"])
    fracture = float(diagnostics["dissipated_energy"])
    section = WIDTH * WIDTH * (1.0 if ligament is None else ligament)
    per_area = fracture / ((pieces - 1) * section * MATERIAL["fracture_energy"]) if pieces > 1 else None
    return {"grid": grid, "dx": round(config.domain.dx, 6), "particles": len(built.particles), "factor": factor,
            "strain_rate": round(rate, 3), "pieces": pieces, "fracture_energy": round(fracture, 6),
            "energy_per_broken_area_over_Gf": round(per_area, 3) if per_area is not None else None,
            "damaged_particles": int((damage > 0).sum()), "complete_particles": int((damage >= 1).sum()),
            "band": band_profile(built.particles.x[:, 0].numpy(), damage.numpy(), config.domain.dx),
            "energy_peak_over_start": round(peak, 5), "wall_s": round(time.perf_counter() - began, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", type=int, nargs="+", default=[64, 128])
    parser.add_argument("--factors", type=float, nargs="+", default=[1.1, 1.5, 2.0, 3.0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--frame-dt", type=float, default=0.002)
    parser.add_argument("--ligament", type=float, default=None,
                        help="notch the bar: the share of its cross-section left at the centre, in (0, 1)")
    args = parser.parse_args()
    if args.ligament is not None and not 0.0 < args.ligament < 1.0:
        parser.exit(2, f"error: --ligament must be in (0, 1), got {args.ligament:g}\n")
    torch.set_grad_enabled(False)
    runs = [run(grid, factor, args.frames, args.frame_dt, args.ligament)
            for grid in args.grids for factor in args.factors]
    notched = {} if args.ligament is None else {"ligament": args.ligament, "slot_width": SLOT_WIDTH}
    print(json.dumps({"benchmark": "brittle_bar", "length": LENGTH, "width": WIDTH, **notched, "material": MATERIAL,
                      "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
