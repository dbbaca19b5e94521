#!/usr/bin/env python3
"""Whether a placed object stands the right way up and rests, as JSON.

    python simulate.py --scene skull_on_the_floor.yaml      # an object with a `placement`
    python benchmarks/placement_rest.py --sim output/sims/skull_on_the_floor \\
        [--object skull] [--reference-up X Y Z]

For one object of a simulation of a trained model: the angle between +z and its up direction
after the scene's transform (the up ``object.json`` records, and ``--reference-up``, an up
measured some other way, in model coordinates); the face it rests on at the first frame (the
face of its particles' convex hull straight below its centre of mass: the angle of that face's
normal from -z, and whether the centre of mass lies over the particles touching the ground); and
how it moved from the first to the last frame (the rotation of the best rigid fit of its
particles, the drop of its centre of mass and of its lowest particle).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from scipy.spatial import ConvexHull, Delaunay

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from fracture_gs.config.scene import GroundBoundary  # noqa: E402
from fracture_gs.folders.sim_reader import Simulation, SimulationError  # noqa: E402
from fracture_gs.io.model_layout import OBJECT_FILE  # noqa: E402
from fracture_gs.io.object_frame import read_object_frame  # noqa: E402
from fracture_gs.mpm.scene import rotation_matrix_xyz  # noqa: E402

Z = np.array([0.0, 0.0, 1.0])


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cosine = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def rotation_deg(start: np.ndarray, end: np.ndarray) -> float:
    """Angle of the rotation of the least-squares rigid fit from ``start`` to ``end`` (Kabsch)."""
    a, b = start - start.mean(axis=0), end - end.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    sign = np.sign(np.linalg.det(vt.T @ u.T))
    turn = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return float(np.degrees(np.arccos(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0))))


def resting_face(points: np.ndarray, weights: np.ndarray) -> dict:
    """The convex-hull face straight below the centre of mass of ``points``: its normal's angle
    from -z and its height below the centre of mass."""
    hull = ConvexHull(points)
    centre = (weights[:, None] * points).sum(axis=0) / weights.sum()
    best = None
    for equation in hull.equations:       # normal . x + offset <= 0 inside, normal outward
        normal, offset = equation[:3], equation[3]
        if normal[2] >= 0:
            continue
        distance = -(normal @ centre + offset) / -normal[2]   # along -z to the face's plane
        if best is None or distance < best[0]:
            best = (distance, normal)
    assert best is not None
    return {"normal": best[1].tolist(), "tilt_from_down_deg": angle_deg(best[1], -Z),
            "depth_below_centre_of_mass": float(best[0])}


def measure(sim_path: str, name: str | None, reference_up: list[float] | None) -> dict:
    sim = Simulation.open(sim_path)
    names = sim.object_names
    index = names.index(name) if name is not None else next(
        i for i, obj in enumerate(sim.scene.objects) if obj.model is not None and obj.model.is_dir())
    obj = sim.scene.objects[index]
    rotation = rotation_matrix_xyz(obj.transform.rotate_deg)
    frame = read_object_frame(obj.model / OBJECT_FILE)
    mine = sim.particles.obj_id == index
    mass = sim.particles.rest_volume[mine].astype(np.float64)
    first, last = sim.frames[0], sim.frames[-1]
    start = sim.load_frame(first).x.numpy()[mine].astype(np.float64)
    end = sim.load_frame(last).x.numpy()[mine].astype(np.float64)
    ground = next((b.height for b in sim.scene.boundaries if isinstance(b, GroundBoundary)), None)
    result = {"sim": sim_path, "object": obj.name, "particles": int(mine.sum()),
              "transform": {"scale": obj.transform.scale,
                            "rotate_deg": list(obj.transform.rotate_deg),
                            "translate": list(obj.transform.translate)},
              "up_after_placement_deg": angle_deg(rotation @ np.asarray(frame.up), Z),
              "up_source": frame.up_source}
    if reference_up is not None:
        result["reference_up_after_placement_deg"] = angle_deg(rotation @ np.asarray(reference_up), Z)
    result["resting_face"] = resting_face(start, mass)
    if ground is not None:
        dx = sim.scene.domain.dx
        touching = start[start[:, 2] < ground + 0.5 * dx]
        centre = (mass[:, None] * start).sum(axis=0) / mass.sum()
        inside = len(touching) >= 4 and bool(
            Delaunay(touching[:, :2]).find_simplex(centre[None, :2])[0] >= 0)
        result["ground"] = {"height": ground, "particles_touching": int(len(touching)),
                            "centre_of_mass_over_contact": inside}
    centre_start = (mass[:, None] * start).sum(axis=0) / mass.sum()
    centre_end = (mass[:, None] * end).sum(axis=0) / mass.sum()
    result["motion"] = {"first_frame": first, "last_frame": last,
                        "rotation_deg": rotation_deg(start, end),
                        "centre_of_mass_drop": float(centre_start[2] - centre_end[2]),
                        "lowest_z_first": float(start[:, 2].min()),
                        "lowest_z_last": float(end[:, 2].min()),
                        "size": (end.max(axis=0) - end.min(axis=0)).tolist()}
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim", required=True, help="simulation folder")
    parser.add_argument("--object", default=None, help="object name (default: the first model)")
    parser.add_argument("--reference-up", type=float, nargs=3, default=None,
                        metavar=("X", "Y", "Z"), help="an independently measured up direction, "
                        "model coordinates")
    args = parser.parse_args(argv)
    try:
        result = measure(args.sim, args.object, args.reference_up)
    except (SimulationError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
