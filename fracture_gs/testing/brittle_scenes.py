"""Brittle scenes of the crack checks (docs/results.md, "Cracks from notch tips, and a disc that
bursts"), shared by tests and benchmarks, and the measurements made on them.

* :func:`spun_disc` — a free disc suddenly spun about its axis (no gravity, no walls): it bursts
  where its hoop stress reaches the strength (:func:`burst_speed`, the plane-stress formula);
* :func:`notched_plate` — an edge-notched plate whose strip between the two notches is struck by
  an elastic impactor (Kalthoff and Winkler's experiment): a crack runs from each notch tip at
  about 70° to the notch;
* :func:`crack_from_tip` measures such a crack (its angle to the notch and how many of its damaged
  particles lie within one cell of its line), :func:`band_profile` a planar crack's width.

Sizes are parameters so that the tests run a small version and the benchmarks the full one. All
scenes use the glass-like material of ``benchmarks/brittle_bar.py`` (E 2 MPa, ν 0.2, ρ 100 kg/m³,
σ_F 20 kPa, G_f 2 J/m²).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from fracture_gs.config.scene import parse_scene
from fracture_gs.mpm.scene import BuiltScene, build_scene
from fracture_gs.mpm.solver import CollisionMPM

GLASS: dict[str, Any] = {"part": 0, "model": "brittle", "E": 2.0e6, "nu": 0.2, "density": 100.0,
                         "strength": 2.0e4, "fracture_energy": 2.0}
CENTRE = 0.5                 # scenes sit at the centre of the unit cube


def add_run_arguments(parser: argparse.ArgumentParser, duration: float) -> None:
    """The options every crack-check benchmark takes: --duration (simulated seconds), --seed (the
    Weibull strengths) and --dump (a folder for each run's last state)."""
    parser.add_argument("--duration", type=float, default=duration, help="simulated time (s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--dump", type=_dump_folder, default=None,
                        help="folder for each run's last state (npz: x, damage, normal, piece labels)")


def _dump_folder(text: str) -> Path:
    """--dump's value: a folder, or a path where one can be made (not an existing file)."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a folder")
    return path


def advance_sampled(solver: CollisionMPM, steps: Sequence[float]) -> tuple[dict, list[dict], float]:
    """Advances ``solver`` by each of ``steps`` (seconds) in turn. Returns the diagnostics at the start
    and after each step, and the largest kinetic + elastic + gravitational + dissipated energy after
    a step over the total energy at the start (never above 1 for a sound run)."""
    start = solver.diagnostics()
    samples = []
    peak = start["total_energy"]
    for step in steps:
        solver.advance(step)
        diagnostics = solver.diagnostics()
        peak = max(peak, diagnostics["total_energy"] + diagnostics["dissipated_energy"])
        samples.append(diagnostics)
    return start, samples, peak / start["total_energy"]


def solver_of(built: BuiltScene, seed: int) -> CollisionMPM:
    """The solver of a built scene."""
    return CollisionMPM(built.particles, built.materials, built.domain, contact=built.contact,
                        boundaries=built.boundaries, gravity=built.gravity, cfl=built.cfl,
                        object_names=built.object_names, seed=seed)


# ----------------------------------------------------------------------------- the spun disc


def burst_speed(material: dict[str, Any], radius: float) -> float:
    """Angular speed (rad/s) at which the centre of a free spinning disc reaches the strength:
    σ_r = σ_θ = (3 + ν)/8 ρ ω² R² at r = 0 (plane stress, the largest stress in the disc)."""
    return math.sqrt(8.0 * material["strength"] / ((3.0 + material["nu"]) * material["density"] * radius ** 2))


def spun_disc(grid: int, ratio: float, *, weibull_m: float = 0.0, seed: int = 0, radius: float = 0.2,
              height_cells: float = 4.0, material: dict[str, Any] | None = None) -> CollisionMPM:
    """A disc (a cylinder of ``height_cells`` cells along z, jittered particles, 8 per cell) spinning
    at ``ratio`` times :func:`burst_speed` from an unstressed start, crack opening on."""
    material = dict(material or GLASS, weibull_m=weibull_m)
    omega = ratio * burst_speed(material, radius)
    height = height_cells / grid
    scene = {"name": "spun_disc", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": grid}, "frames": 1,
             "frame_dt": 0.001, "gravity": [0, 0, 0], "boundaries": [], "contact": {"fragments": True},
             "seed": seed,
             "objects": [{"name": "disc", "primitive": {"shape": "cylinder", "radius": radius, "height": height},
                          "transform": {"translate": [CENTRE] * 3}, "angular_velocity": [0, 0, omega],
                          "materials": [material]}]}
    config = parse_scene(scene)
    return solver_of(build_scene(config), config.seed)


# ----------------------------------------------------------------------------- the notched plate


@dataclass(frozen=True)
class PlateGeometry:
    """Kalthoff and Winkler's plate scaled to the unit cube: ``width`` along x (the notches' direction,
    struck at x = CENTRE − width/2), ``height`` along y, notches ``notch`` long at y = CENTRE ± gap/2,
    ``thickness_cells`` cells thick along z."""

    width: float = 0.25
    height: float = 0.5
    notch: float = 0.125
    gap: float = 0.125
    thickness_cells: float = 4.0

    def tips(self) -> list[tuple[float, float]]:
        """(x, y) of the two notch tips."""
        x = CENTRE - 0.5 * self.width + self.notch
        return [(x, CENTRE + 0.5 * self.gap), (x, CENTRE - 0.5 * self.gap)]


def notched_plate(grid: int, speed: float, *, geometry: PlateGeometry = PlateGeometry(), notch_cells: float = 2.0,
                  seed: int = 0, material: dict[str, Any] | None = None) -> CollisionMPM:
    """The plate (object 0) and an elastic impactor (object 1, as wide as the strip between the
    notches, 20 times as dense as the plate, the plate's stiffness) moving at ``speed`` along +x into
    the strip's edge. Each notch is a slot ``notch_cells`` cells wide with a square end, cut out of
    the particles. Crack opening on, no gravity, no walls."""
    material = dict(material or GLASS)
    g = geometry
    dx = 1.0 / grid
    thickness = g.thickness_cells * dx
    impactor_length = 0.25 * g.width
    left = CENTRE - 0.5 * g.width
    impactor = {"part": 0, "model": "elastic", "E": material["E"], "nu": material["nu"],
                "density": 20.0 * material["density"]}
    scene = {"name": "notched_plate", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": grid}, "frames": 1,
             "frame_dt": 0.001, "gravity": [0, 0, 0], "boundaries": [], "contact": {"fragments": True},
             "seed": seed,
             "objects": [{"name": "plate", "primitive": {"shape": "box", "size": [g.width, g.height, thickness]},
                          "transform": {"translate": [CENTRE] * 3}, "materials": [material]},
                         {"name": "impactor",
                          "primitive": {"shape": "box", "size": [impactor_length, g.gap - notch_cells * dx, thickness]},
                          "transform": {"translate": [left - 0.5 * impactor_length - 0.5 * dx, CENTRE, CENTRE]},
                          "velocity": [speed, 0, 0], "materials": [impactor]}]}
    config = parse_scene(scene)
    built = build_scene(config)
    x = built.particles.x
    half_slot = 0.5 * notch_cells * dx
    in_notch = torch.zeros(len(x), dtype=torch.bool)
    for _, tip_y in g.tips():
        in_notch |= ((x[:, 1] - tip_y).abs() < half_slot) & (x[:, 0] < left + g.notch)
    in_notch &= built.particles.obj_id == 0
    built = dataclasses.replace(built, particles=built.particles.take(torch.nonzero(~in_notch).flatten()))
    return solver_of(built, config.seed)


def crack_from_tip(x: np.ndarray, damage: np.ndarray, tip: tuple[float, float], side: float, dx: float,
                   reach: float, cracked: float = 1.0) -> dict[str, float | int | None]:
    """The crack that leaves a notch tip (in the x-y plane), from the particles' positions x (n, 3)
    and damage. Its particles are the completely damaged ones (damage >= ``cracked``) connected to the
    tip: chains of them less than 2 cells apart, starting within 2 cells of the tip, within ``reach``
    of it, on the ``side`` of the notch (+1: y above the tip, -1: below) and ahead of it (x > tip x − 1
    cell); other cracks (a spall at the far edge) do not count. Gives the angle of the line through the
    tip that best fits them to the notch direction (+x) in degrees, the share of the damaged particles
    (damage > 0) within one cell of that line among those within 2 cells of the crack, its length and
    the counts."""
    offset = x[:, :2] - np.asarray(tip)[None, :]
    distance = np.linalg.norm(offset, axis=1)
    region = (distance < reach) & (side * offset[:, 1] > -dx) & (offset[:, 0] > -dx)
    points = np.nonzero(region & (damage >= cracked))[0]
    chain = np.zeros(0, dtype=np.int64)
    if len(points):
        pairs = cKDTree(x[points]).query_pairs(2.0 * dx, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
        labels = connected_components(graph, directed=False)[1]
        at_tip = np.unique(labels[distance[points] < 2.0 * dx])
        chain = points[np.isin(labels, at_tip) & (distance[points] > 2.0 * dx)]
    if len(chain) < 3:
        return {"angle_deg": None, "within_one_cell": None, "cracked": int(len(chain)), "damaged": 0, "length": 0.0}
    crack_points = offset[chain]
    # Line through the tip: the direction maximising the second moment of the crack's points about it.
    direction = np.linalg.eigh(crack_points.T @ crack_points)[1][:, -1]
    direction = direction if direction @ crack_points.mean(0) > 0 else -direction
    normal = np.array([-direction[1], direction[0]])
    near = cKDTree(x[chain]).query(x, distance_upper_bound=2.0 * dx)[0] < np.inf
    damaged = region & near & (damage > 0) & (distance > 2.0 * dx)
    across = np.abs(offset[damaged] @ normal)
    return {"angle_deg": math.degrees(math.atan2(abs(direction[1]), direction[0])),
            "within_one_cell": float((across <= dx).mean()), "cracked": int(len(chain)),
            "damaged": int(damaged.sum()), "length": float((crack_points @ direction).max())}


def band_profile(coordinate: np.ndarray, damage: np.ndarray, dx: float, cracked: float = 1.0
                 ) -> dict[str, float | int | None]:
    """Width of a planar crack across ``coordinate`` (the particles' position along the crack's
    normal): the crack plane is the median coordinate of the cracked particles (damage >=
    ``cracked``); gives the share of the damaged particles (damage > 0) within one cell of it, the
    width holding 90 % of them (in cells, twice the 90th percentile of their distance) and the counts."""
    cracked_at = coordinate[damage >= cracked]
    damaged_at = coordinate[damage > 0]
    if len(cracked_at) == 0 or len(damaged_at) == 0:
        return {"within_one_cell": None, "width_90_cells": None, "cracked": int(len(cracked_at)),
                "damaged": int(len(damaged_at))}
    distance = np.abs(damaged_at - np.median(cracked_at))
    return {"within_one_cell": float((distance <= dx).mean()),
            "width_90_cells": float(2.0 * np.quantile(distance, 0.9) / dx),
            "cracked": int(len(cracked_at)), "damaged": int(len(damaged_at))}
