"""How much of the generated bowl's volume is the recess under it, inside the foot ring.

The bowl of ``python -m fracture_gs.data.synthetic --object bowl`` is a surface of revolution: a
wall of constant thickness around a quarter-ellipse mid curve, standing on a foot ring. Inside
the ring, under the wall, lies a recess that the silhouettes cannot see and that the cameras
(elevations -30 to +72 degrees) see only at grazing angles from the lowest views. A
reconstruction that fills it overestimates the volume by the recess's share. This script
integrates the generator's own cross-section (``shapes.bowl_profile_sdf``) over an (r, z) grid
and prints, as JSON, the bowl's and the recess's volumes and the recess's share of the bowl.

Usage: python tools/bowl_recess.py [--step 0.002]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root

from fracture_gs.data.synthetic import shapes  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=float, default=0.002, help="(r, z) cell size, model units")
    args = parser.parse_args(argv)
    if not 0.0 < args.step <= 0.05:
        parser.error(f"--step must be in (0, 0.05] (model units; the wall is 0.08 thick), got {args.step}")
    mid = shapes.bowl_mid_curve()
    top = float(mid[-1, 1]) + 2 * shapes.BOWL_HALF_THICKNESS
    r = np.arange(0.5 * args.step, float(mid[-1, 0]) + 2 * shapes.BOWL_HALF_THICKNESS, args.step)
    z = np.arange(0.5 * args.step, top, args.step)
    rr, zz = np.meshgrid(r, z, indexing="ij")
    solid = shapes.bowl_profile_sdf(np.stack([rr.ravel(), zz.ravel()], 1)).reshape(rr.shape) < 0
    ring = 2.0 * np.pi * rr * args.step ** 2      # volume of the revolved (r, z) cell
    # The recess: empty cells inside the foot ring (r < its inner radius) below the wall's mid
    # curve (the mid curve rises monotonically with r).
    foot_inner = shapes.BOWL_FOOT_CENTER[0] - shapes.BOWL_FOOT_HALF[0]
    below_wall = zz < np.interp(rr, mid[:, 0], mid[:, 1])
    recess = ~solid & below_wall & (rr < foot_inner)
    bowl = float((ring * solid).sum())
    hollow = float((ring * recess).sum())
    print(json.dumps({"bowl_volume": round(bowl, 5), "recess_volume": round(hollow, 5),
                      "recess_share_of_bowl": round(hollow / bowl, 4), "cell": args.step,
                      "units": "generator model units (the dataset scales them; shares do not "
                               "change)"}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
