"""How far a body's particles depart from a rigid motion of their rest shape."""
from __future__ import annotations

import numpy as np


def rigid_fit_residual(rest: np.ndarray, now: np.ndarray) -> float:
    """RMS residual of the best rigid motion (Kabsch: rotation and translation, no scaling) taking
    the (n, 3) ``rest`` positions to ``now``, over the RMS distance of ``rest`` from its centroid:
    0 for a body that moved rigidly, about the strain for one that deformed."""
    rest = np.asarray(rest, dtype=np.float64)
    now = np.asarray(now, dtype=np.float64)
    if rest.shape != now.shape or rest.ndim != 2 or rest.shape[1] != 3:
        raise ValueError(f"rest and now must be (n, 3) alike, got {rest.shape} and {now.shape}")
    a, b = rest - rest.mean(0), now - now.mean(0)
    size = float(np.sqrt((a * a).sum(1).mean()))
    if size == 0.0:
        return 0.0
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt))
    rotation = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    return float(np.sqrt(((b - a @ rotation.T) ** 2).sum(1).mean())) / size
