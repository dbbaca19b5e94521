"""``object.json`` of a model folder: where the trained object lies in its model coordinates.

``train.py`` writes it from the final particles and the up direction of the dataset (estimated
from the cameras, or given with ``--up``); a scene's ``placement`` reads it to stand the object
the right way up without a hand-computed rotation::

    {"format": "fracture_gs/object-frame-v1",
     "frame": "model coordinates = the dataset's world coordinates",
     "bbox_min": [x, y, z], "bbox_max": [x, y, z], "centre": [x, y, z],
     "up": [x, y, z], "up_source": "level cameras",
     "height": h, "footprint": [a, b], "bottom": [x, y, z]}

``centre`` is the centre of the axis-aligned box; ``height`` the object's extent along ``up``;
``footprint`` its extents across ``up`` (longer first, along the principal axes of the
particles projected onto the plane perpendicular to ``up``); ``bottom`` the centre of the
object's lowest face along ``up`` (the box centre moved down to the lowest particle).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fracture_gs.io.atomic import write_text_atomic
OBJECT_FORMAT = "fracture_gs/object-frame-v1"
FRAME_NOTE = "model coordinates = the dataset's world coordinates"


@dataclass(frozen=True)
class ObjectFrame:
    """Box, centre and up direction of a trained object (module docstring)."""

    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]
    centre: tuple[float, float, float]
    up: tuple[float, float, float]
    up_source: str
    height: float
    footprint: tuple[float, float]
    bottom: tuple[float, float, float]

    def summary(self) -> str:
        """One line for train.py's output."""
        def vec(values: tuple[float, ...]) -> str:
            return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"
        return (f"box {vec(self.bbox_min)} .. {vec(self.bbox_max)}, centre {vec(self.centre)}, "
                f"up [{self.up[0]:.3f}, {self.up[1]:.3f}, {self.up[2]:.3f}] ({self.up_source}); along up {self.height:.4g} high, "
                f"{self.footprint[0]:.4g} x {self.footprint[1]:.4g} across")


def measure_object(points: np.ndarray, up: np.ndarray, up_source: str) -> ObjectFrame:
    """The :class:`ObjectFrame` of an object whose particles are ``points`` (n, 3)."""
    points = np.asarray(points, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    lower, upper = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lower + upper)
    heights = points @ up
    across = points - np.outer(heights, up)
    across = across - across.mean(axis=0)
    _, _, axes = np.linalg.svd(across[:: max(1, len(across) // 20000)], full_matrices=False)
    spans = [float(np.ptp(across @ axis)) for axis in axes[:2]]
    bottom = centre + (heights.min() - centre @ up) * up
    return ObjectFrame(tuple(map(float, lower)), tuple(map(float, upper)),
                       tuple(map(float, centre)), tuple(map(float, up)), up_source,
                       float(np.ptp(heights)), (max(spans), min(spans)),
                       tuple(map(float, bottom)))


def write_object_frame(path: str | Path, frame: ObjectFrame) -> None:
    """Write ``object.json`` (atomically)."""
    content = {"format": OBJECT_FORMAT, "frame": FRAME_NOTE,
               **{key: list(value) if isinstance(value, tuple) else value
                  for key, value in asdict(frame).items()}}
    write_text_atomic(Path(path), json.dumps(content, indent=2) + "\n")


def read_object_frame(path: str | Path) -> ObjectFrame:
    """Read an ``object.json``; a ValueError naming the file and the problem otherwise."""
    path = Path(path)
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not readable as JSON ({type(exc).__name__})") from None
    if not isinstance(content, dict) or content.get("format") != OBJECT_FORMAT:
        raise ValueError(f"{path}: not an object.json of train.py (no format "
                         f"'{OBJECT_FORMAT}')")

    def vector(key: str, length: int) -> tuple[float, ...]:
        value = content.get(key)
        if not (isinstance(value, list) and len(value) == length
                and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                        and math.isfinite(v) for v in value)):
            raise ValueError(f"{path}: '{key}' is not a list of {length} finite numbers")
        return tuple(float(v) for v in value)

    up = np.asarray(vector("up", 3))
    if not 0.5 < np.linalg.norm(up) < 2.0:
        raise ValueError(f"{path}: 'up' {up.tolist()} is not a unit vector")
    height = content.get("height")
    if not isinstance(height, (int, float)) or not height >= 0:
        raise ValueError(f"{path}: 'height' is not a number >= 0")
    return ObjectFrame(vector("bbox_min", 3), vector("bbox_max", 3), vector("centre", 3),
                       tuple(map(float, up / np.linalg.norm(up))),
                       str(content.get("up_source", "")), float(height),
                       vector("footprint", 2), vector("bottom", 3))
