"""The conservation numbers of report.md / metrics.json (fracture_gs.report.plots), on hand-made
diagnostics columns: drift, the momentum balance against the external impulse J, energy rise."""
from __future__ import annotations

import json
import math

import numpy as np

from fracture_gs.report.plots import conservation_summary, momentum_balance_residual


def columns(with_impulse: bool) -> dict[str, np.ndarray]:
    """A 1 kg block falling from rest for 0.3 s under g = 9.8, momentum off by 1e-6 at the end."""
    time = np.array([0.0, 0.1, 0.2, 0.3])
    pz = -9.8 * time
    pz[-1] += 1e-6
    out = {"time": time, "px": np.zeros(4), "py": np.zeros(4), "pz": pz,
           "block_px": np.zeros(4), "block_py": np.zeros(4), "block_pz": pz,
           "block_kinetic": 0.5 * pz ** 2, "total_energy": np.array([10.0, 10.0, 9.9, 9.8])}
    if with_impulse:
        out.update(impulse_x=np.zeros(4), impulse_y=np.zeros(4), impulse_z=-9.8 * time)
    return out


def test_balance_subtracts_the_external_impulse() -> None:
    summary = conservation_summary(columns(True))
    # starts at rest: the drift has no start momentum to compare with, the balance uses max |J|
    assert math.isclose(summary.momentum_balance, 1e-6 / (9.8 * 0.3), rel_tol=1e-6)
    residual = momentum_balance_residual(columns(True), summary.momentum_scale)
    assert residual is not None and residual[:3].max() < 1e-15
    assert summary.energy_rise == 0.0


def test_runs_without_impulse_columns_give_no_balance() -> None:
    summary = conservation_summary(columns(False))
    assert momentum_balance_residual(columns(False), 1.0) is None
    assert math.isnan(summary.momentum_balance)
    encoded = json.dumps(summary.to_json(), allow_nan=False)  # valid JSON: null, not NaN
    assert json.loads(encoded)["momentum_balance"] is None
