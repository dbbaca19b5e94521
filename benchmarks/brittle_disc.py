"""A free brittle disc suddenly spun at multiples of its burst speed (prints JSON).

The disc (radius 0.2 m, 4 cells thick, the glass-like material of ``benchmarks/brittle_bar.py``,
no gravity, no walls) starts unstressed, rotating rigidly at --ratios times the speed at which
the centre of a spinning disc reaches the strength (plane stress: (3 + ν)/8 ρ ω² R² = σ_F). It
expands until the hoop stress breaks it. Per run (uniform strength and each --weibull modulus) the
JSON gives, at the end: the pieces of >= 1 % of the disc, the largest piece's share, the share of
particles with complete damage (cracked), the share of those outside every piece of >= 1 %
(crushed) and of particles with any damage; the piece count per --sample interval, and the
largest (kinetic + elastic + fracture) energy over its start.

    python benchmarks/brittle_disc.py [--grid 64] [--ratios 0.5 1.6] [--weibull 0 10] [--duration 0.008]
"""
from __future__ import annotations

import argparse
from pathlib import Path
import json
import time

import numpy as np
import torch

from fracture_gs.metrics.pieces import object_pieces
from fracture_gs.testing.brittle_scenes import GLASS, add_run_arguments, advance_sampled, burst_speed, spun_disc

RADIUS = 0.2


def run(grid: int, ratio: float, weibull_m: float, duration: float, sample: float, seed: int,
        dump: Path | None = None) -> dict:
    solver = spun_disc(grid, ratio, weibull_m=weibull_m, seed=seed, radius=RADIUS)
    began = time.perf_counter()
    steps, elapsed = [], 0.0
    while elapsed < duration - 1e-12:
        steps.append(min(sample, duration - elapsed))
        elapsed += steps[-1]
    start, samples, peak = advance_sampled(solver, steps)
    diagnostics = samples[-1]
    damage = solver.frame_fields_in_input_order()["damage"].numpy()
    labels = solver.fragment_ids().numpy()
    obj = solver.input_particles.obj_id.numpy()
    pieces = object_pieces(labels, obj, solver.object_names, solver.state.step, damage)[0]
    if dump is not None:
        dump.mkdir(parents=True, exist_ok=True)
        state = solver.state_in_input_order()
        np.savez(dump / f"disc_g{grid}_r{ratio:g}_m{weibull_m:g}_s{seed}.npz", x=state.x.numpy(), damage=damage,
                 normal=state.material_state[:, 2:5].numpy(), labels=labels, obj=obj)
    return {"grid": grid, "ratio": ratio, "weibull_m": weibull_m, "seed": seed, "particles": len(damage),
            "omega": round(ratio * burst_speed(GLASS, RADIUS), 3), "pieces": pieces.pieces,
            "largest_share": round(pieces.largest_share, 4), "cracked_share": round(float((damage >= 1).mean()), 4),
            "crushed_share": round(pieces.complete_damage_share, 4),
            "damaged_share": round(float((damage > 0).mean()), 4),
            "pieces_per_sample": [int(sample["fragments"]) for sample in samples],
            "momentum_drift": float(np.abs(diagnostics["momentum"] - start["momentum"]).max()
                                    / max(1e-30, float(solver.particles.mass.double().sum())
                                          * float(np.linalg.norm(solver.input_particles.v.double().numpy(),
                                                                 axis=1).max()))),
            "energy_peak_over_start": round(peak, 5), "wall_s": round(time.perf_counter() - began, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=64)
    parser.add_argument("--ratios", type=float, nargs="+", default=[0.5, 1.6])
    parser.add_argument("--weibull", type=float, nargs="+", default=[0.0, 10.0])
    parser.add_argument("--sample", type=float, default=0.001, help="interval of the piece counts (s)")
    add_run_arguments(parser, duration=0.008)
    args = parser.parse_args()
    torch.set_grad_enabled(False)
    runs = [run(args.grid, ratio, m, args.duration, args.sample, args.seed, args.dump)
            for m in args.weibull for ratio in args.ratios]
    print(json.dumps({"benchmark": "brittle_disc", "radius": RADIUS, "material": GLASS, "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
