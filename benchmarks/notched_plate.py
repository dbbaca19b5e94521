"""Kalthoff and Winkler's edge-notched plate, its strip struck between the notches (prints JSON).

The plate (0.25 × 0.5 m, 4 cells thick, the glass-like material of ``benchmarks/brittle_bar.py``,
no gravity, no walls) has two notches 0.125 m long, 2 cells wide, 0.125 m apart, cut from its left
edge; an elastic impactor as wide as the strip between them (the plate's stiffness, 20 times its
density) strikes the strip at --speed. Loaded in shear at the notch tips, the plate cracks from
each tip at about 70° to the notch (Kalthoff and Winkler 1988; the maximum tangential stress
criterion gives 70.5°). Per tip the JSON gives, in the plate's rest shape, the angle of the crack to
the notch direction (the line through the tip fitted to the completely damaged particles connected
to it within --reach: ``fracture_gs.testing.brittle_scenes.crack_from_tip``), the
share of the damaged particles there within one cell of that line, the crack's length and the
particle counts; and the largest (kinetic + elastic + fracture) energy over its start.

    python benchmarks/notched_plate.py [--grid 128] [--speed 8] [--duration 0.006] [--reach 0.1]
"""
from __future__ import annotations

import argparse
from pathlib import Path
import json
import time

import numpy as np
import torch

from fracture_gs.testing.brittle_scenes import (GLASS, PlateGeometry, add_run_arguments, advance_sampled,
                                                crack_from_tip, notched_plate)


def run(grid: int, speed: float, duration: float, reach: float, seed: int, dump: Path | None = None) -> dict:
    solver = notched_plate(grid, speed, seed=seed)
    began = time.perf_counter()
    frames = max(1, round(duration / 0.0005))
    _, samples, peak = advance_sampled(solver, [duration / frames] * frames)
    state = solver.state_in_input_order()
    plate = (solver.input_particles.obj_id == 0).numpy()
    x = solver.input_particles.x.numpy()[plate]   # the crack's path in the plate's rest shape
    damage = solver.frame_fields_in_input_order()["damage"].numpy()[plate]
    dx = solver.geometry.dx
    if dump is not None:
        dump.mkdir(parents=True, exist_ok=True)
        np.savez(dump / f"plate_g{grid}_v{speed:g}_s{seed}.npz", x=state.x.numpy()[plate], rest=x, damage=damage,
                 normal=state.material_state.numpy()[plate][:, 2:5], labels=solver.fragment_ids().numpy()[plate])
    tips = PlateGeometry().tips()
    cracks = [{"tip": list(tip), **crack_from_tip(x, damage, tip, side, dx, reach)}
              for tip, side in zip(tips, (1.0, -1.0))]
    return {"grid": grid, "speed": speed, "particles": int(plate.sum()), "cracks": cracks,
            "damaged_particles": int((damage > 0).sum()), "cracked_particles": int((damage >= 1).sum()),
            "fragments": int(samples[-1]["fragments"]),
            "energy_peak_over_start": round(peak, 5), "wall_s": round(time.perf_counter() - began, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=128)
    parser.add_argument("--speed", type=float, nargs="+", default=[8.0])
    parser.add_argument("--reach", type=float, default=0.1, help="distance from the tip that is measured (m)")
    add_run_arguments(parser, duration=0.006)
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    runs = [run(args.grid, speed, args.duration, args.reach, args.seed, args.dump) for speed in args.speed]
    print(json.dumps({"benchmark": "notched_plate", "material": GLASS, "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
