"""The measurements of the crack checks (fracture_gs/testing/brittle_scenes.py; the full-size runs are
benchmarks/notched_plate.py, benchmarks/brittle_disc.py and benchmarks/brittle_bar.py) on point sets
whose answer is known, and the scenes' builders."""
from __future__ import annotations

import math

import numpy as np
import torch

from fracture_gs.testing.brittle_scenes import (GLASS, PlateGeometry, advance_sampled, band_profile, burst_speed,
                                                crack_from_tip, notched_plate, spun_disc)

DX = 0.01


def test_a_straight_crack_from_a_tip_has_its_angle_and_no_spread() -> None:
    tip = (0.5, 0.5)
    angle = math.radians(70.0)
    along = np.arange(0.0, 0.09, 0.25 * DX)
    line = np.stack([tip[0] + along * math.cos(angle), tip[1] + along * math.sin(angle), np.zeros_like(along)], 1)
    # Intact material around it, and a partly damaged particle 3 cells off the line.
    rng = np.random.default_rng(0)
    bulk = np.concatenate([rng.uniform(0.4, 0.62, (4000, 2)), np.zeros((4000, 1))], 1)
    off = np.array([[tip[0] + 0.05 * math.cos(angle) - 3 * DX * math.sin(angle),
                     tip[1] + 0.05 * math.sin(angle) + 3 * DX * math.cos(angle), 0.0]])
    x = np.concatenate([line, bulk, off])
    damage = np.concatenate([np.ones(len(line)), np.zeros(len(bulk)), [0.5]])
    crack = crack_from_tip(x, damage, tip, 1.0, DX, reach=0.1)
    assert abs(crack["angle_deg"] - 70.0) < 0.5
    assert crack["within_one_cell"] == 1.0 and crack["cracked"] > 20
    assert abs(crack["length"] - along.max()) < DX
    # The same crack seen from the tip below it is not there (it lies on the other side).
    assert crack_from_tip(x, damage, tip, -1.0, DX, reach=0.1)["angle_deg"] is None


def test_a_spread_crack_counts_what_lies_off_its_line() -> None:
    tip = (0.5, 0.5)
    along = np.arange(0.0, 0.08, 0.25 * DX)
    line = np.stack([tip[0] + along, tip[1] + 0.0 * along + 2 * DX, np.zeros_like(along)], 1)
    line[:, 1] = tip[1] + along * math.tan(math.radians(45.0))
    beside = line + np.array([1.6 * DX / math.sqrt(2), -1.6 * DX / math.sqrt(2), 0.0])[None, :]
    x = np.concatenate([line, beside])
    damage = np.concatenate([np.ones(len(line)), np.full(len(beside), 0.3)])
    crack = crack_from_tip(x, damage, tip, 1.0, DX, reach=0.1)
    assert abs(crack["angle_deg"] - 45.0) < 1.0
    assert 0.4 < crack["within_one_cell"] < 0.6   # the damaged row beside it is 1.6 cells off


def test_band_profile_of_a_plane_crack() -> None:
    coordinate = np.linspace(0.0, 1.0, 1001)
    damage = np.where(np.abs(coordinate - 0.5) <= 0.5 * DX, 1.0, 0.0)
    damage[np.abs(coordinate - 0.5 - 1.5 * DX) < 0.25 * DX] = 0.2   # a partly damaged layer 1.5 cells off
    band = band_profile(coordinate, damage, DX)
    cracked, damaged = int((damage >= 1).sum()), int((damage > 0).sum())
    assert band["cracked"] == cracked and band["damaged"] == damaged and damaged > cracked >= 9
    assert band["within_one_cell"] == cracked / damaged
    assert 2.5 < band["width_90_cells"] <= 3.5
    assert band_profile(coordinate, np.zeros_like(coordinate), DX)["width_90_cells"] is None


def test_the_plate_has_its_notches_and_the_impactor_its_speed() -> None:
    geometry = PlateGeometry()
    solver = notched_plate(32, 8.0, geometry=geometry)
    x, obj, v = solver.input_particles.x, solver.input_particles.obj_id, solver.input_particles.v
    plate, impactor = x[obj == 0], obj == 1
    for _, tip_y in geometry.tips():
        in_slot = ((plate[:, 1] - tip_y).abs() < 0.5 / 32) & (plate[:, 0] < 0.5 - 0.5 * geometry.width + geometry.notch)
        assert int(in_slot.sum()) == 0
    assert torch.allclose(v[impactor], torch.tensor([8.0, 0.0, 0.0]).expand(int(impactor.sum()), 3))
    assert float(v[obj == 0].abs().max()) == 0.0


def test_a_disc_spun_below_its_burst_speed_takes_no_damage() -> None:
    solver = spun_disc(32, 0.5, radius=0.2)
    omega = 0.5 * burst_speed(GLASS, 0.2)
    x, v = solver.input_particles.x, solver.input_particles.v
    r = x[:, :2] - x[:, :2].double().mean(0).float()   # about the disc's centre of mass
    assert torch.allclose(v[:, :2], omega * torch.stack([-r[:, 1], r[:, 0]], 1), atol=1e-3 * omega * 0.2)
    start, samples, peak = advance_sampled(solver, [0.002, 0.002])
    assert float(solver.state.material_state[:, 0].max()) == 0.0
    assert len(samples) == 2 and abs(solver.state.time - 0.004) < 1e-12
    assert peak <= 1.0 + 1e-6 and peak == max(1.0, *((d["total_energy"] + d["dissipated_energy"])
                                                     / start["total_energy"] for d in samples))
