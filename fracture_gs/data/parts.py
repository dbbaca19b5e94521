"""Part specs: which part (material) a point of an object belongs to (docs/file_formats.md §1, parts.json).

A part spec lives in ``parts.json`` next to a dataset (or is embedded in a scene). It is a list
of rules in object coordinates; a point gets the part of the **first** rule that contains it,
or ``default_part`` if none does. Rule shapes:

* ``{"part": 1, "box": {"min": [x, y, z], "max": [x, y, z]}}`` — an axis-aligned box,
  bounds inclusive;
* ``{"part": 0, "halfspace": {"point": [x, y, z], "normal": [nx, ny, nz]}}`` — the closed
  half-space ``(p - point) . normal >= 0`` (the side the normal points to).

Example (a table whose top is part 0 and legs part 1)::

    {"format": "fracture_gs/parts-v1",
     "parts": [{"id": 0, "name": "top"}, {"id": 1, "name": "legs"}],
     "default_part": 1,
     "rules": [{"part": 0, "halfspace": {"point": [0, 0, 0.3], "normal": [0, 0, 1]}}]}

A missing file means one part (id 0) for the whole object: see :func:`single_part_spec`.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence, Union

import numpy as np

from fracture_gs.data.files import read_json
from fracture_gs.io.output_folder import naming_file

PARTS_FORMAT = "fracture_gs/parts-v1"


class PartSpecError(ValueError):
    """A part spec is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class BoxRule:
    """Axis-aligned box ``lower <= p <= upper`` (component-wise, inclusive)."""

    part: int
    lower: tuple[float, float, float]
    upper: tuple[float, float, float]

    def contains(self, points: np.ndarray) -> np.ndarray:
        lower = np.asarray(self.lower)
        upper = np.asarray(self.upper)
        return np.all((points >= lower) & (points <= upper), axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {"part": self.part, "box": {"min": list(self.lower), "max": list(self.upper)}}


@dataclass(frozen=True)
class HalfSpaceRule:
    """Closed half-space ``(p - point) . normal >= 0``."""

    part: int
    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def contains(self, points: np.ndarray) -> np.ndarray:
        offsets = points - np.asarray(self.point)
        return offsets @ np.asarray(self.normal) >= 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"part": self.part,
                "halfspace": {"point": list(self.point), "normal": list(self.normal)}}


Rule = Union[BoxRule, HalfSpaceRule]


@dataclass(frozen=True)
class PartSpec:
    """Ordered part rules; the first rule containing a point decides its part."""

    part_names: tuple[str, ...]
    default_part: int = 0
    rules: tuple[Rule, ...] = field(default_factory=tuple)

    @property
    def num_parts(self) -> int:
        return len(self.part_names)

    def to_dict(self) -> dict[str, Any]:
        return {"format": PARTS_FORMAT,
                "parts": [{"id": index, "name": name}
                          for index, name in enumerate(self.part_names)],
                "default_part": self.default_part,
                "rules": [rule.to_dict() for rule in self.rules]}


def single_part_spec(name: str = "object") -> PartSpec:
    """The spec of a homogeneous object: every point is part 0."""
    return PartSpec(part_names=(name,), default_part=0, rules=())


def _vector3(value: Any, where: str) -> tuple[float, float, float]:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PartSpecError(f"{where}: expected 3 numbers, got {value!r}") from None
    if array.shape != (3,):
        raise PartSpecError(f"{where}: expected 3 numbers, got {value!r}")
    if not np.all(np.isfinite(array)):
        raise PartSpecError(f"{where}: contains NaN or Inf")
    return (float(array[0]), float(array[1]), float(array[2]))


def _part_index(value: Any, num_parts: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise PartSpecError(f"{where}: expected an integer part id, got {value!r}")
    if not 0 <= int(value) < num_parts:
        raise PartSpecError(f"{where}: part id {value} is not in [0, {num_parts})")
    return int(value)


def _parse_rule(entry: Any, num_parts: int, where: str) -> Rule:
    if not isinstance(entry, Mapping):
        raise PartSpecError(f"{where}: expected an object, got {entry!r}")
    if "part" not in entry:
        raise PartSpecError(f"{where}: missing key 'part'")
    part = _part_index(entry["part"], num_parts, f"{where}.part")
    shapes = [key for key in ("box", "halfspace") if key in entry]
    if len(shapes) != 1:
        raise PartSpecError(f"{where}: needs exactly one of 'box' or 'halfspace'")
    body = entry[shapes[0]]
    if not isinstance(body, Mapping):
        raise PartSpecError(f"{where}.{shapes[0]}: expected an object")
    if shapes[0] == "box":
        for key in ("min", "max"):
            if key not in body:
                raise PartSpecError(f"{where}.box: missing key '{key}'")
        lower = _vector3(body["min"], f"{where}.box.min")
        upper = _vector3(body["max"], f"{where}.box.max")
        if any(lo > hi for lo, hi in zip(lower, upper)):
            raise PartSpecError(f"{where}.box: min {list(lower)} exceeds max {list(upper)}")
        return BoxRule(part, lower, upper)
    for key in ("point", "normal"):
        if key not in body:
            raise PartSpecError(f"{where}.halfspace: missing key '{key}'")
    normal = _vector3(body["normal"], f"{where}.halfspace.normal")
    if np.linalg.norm(normal) < 1e-12:
        raise PartSpecError(f"{where}.halfspace.normal: must not be zero")
    return HalfSpaceRule(part, _vector3(body["point"], f"{where}.halfspace.point"), normal)


def part_spec_from_dict(content: Mapping[str, Any], source: str = "parts") -> PartSpec:
    """Validate and convert the JSON form of a part spec; errors name ``source`` and the key."""
    if not isinstance(content, Mapping):
        raise PartSpecError(f"{source}: expected a JSON object at the top level")
    if content.get("format", PARTS_FORMAT) != PARTS_FORMAT:
        raise PartSpecError(f"{source}: format {content['format']!r} is not {PARTS_FORMAT!r}")
    parts = content.get("parts")
    if not isinstance(parts, list) or not parts:
        raise PartSpecError(f"{source}: 'parts' must be a non-empty list")
    names = []
    for index, part in enumerate(parts):
        where = f"{source}: parts[{index}]"
        if not isinstance(part, Mapping) or "id" not in part:
            raise PartSpecError(f"{where}: expected an object with key 'id'")
        if part["id"] != index:
            raise PartSpecError(f"{where}.id: expected {index} (ids are 0, 1, 2, ... in order), "
                                f"got {part['id']!r}")
        names.append(str(part.get("name", f"part{index}")))
    default_part = _part_index(content.get("default_part", 0), len(names),
                               f"{source}: default_part")
    rules_json = content.get("rules", [])
    if not isinstance(rules_json, list):
        raise PartSpecError(f"{source}: 'rules' must be a list")
    rules = tuple(_parse_rule(entry, len(names), f"{source}: rules[{index}]")
                  for index, entry in enumerate(rules_json))
    return PartSpec(part_names=tuple(names), default_part=default_part, rules=rules)


def load_part_spec(path: str | os.PathLike) -> PartSpec:
    """Read a ``parts.json`` file."""
    path = os.fspath(path)
    return part_spec_from_dict(read_json(path, PartSpecError), source=path)


def save_part_spec(spec: PartSpec, path: str | os.PathLike,
                   extra: Mapping[str, Any] | None = None) -> None:
    """Write ``spec`` as JSON; ``extra`` keys (e.g. documentation) are stored alongside."""
    content = spec.to_dict()
    if extra:
        content.update({key: value for key, value in extra.items() if key not in content})
    with naming_file(path), open(os.fspath(path), "w", encoding="utf-8") as handle:
        json.dump(content, handle, indent=2)
        handle.write("\n")


def assign_part_ids(points: Any, spec: PartSpec | Mapping[str, Any]) -> np.ndarray:
    """Part id (int32, shape (N,)) of each point of ``points`` (N,3) in object coordinates.

    ``spec`` is a :class:`PartSpec` or its JSON dict. Torch tensors are accepted for points.
    """
    if not isinstance(spec, PartSpec):
        spec = part_spec_from_dict(spec)
    if hasattr(points, "detach"):
        points = points.detach().cpu().numpy()
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"assign_part_ids: points must have shape (N, 3), got {points.shape}")
    part_ids = np.full(len(points), spec.default_part, dtype=np.int32)
    undecided = np.ones(len(points), dtype=bool)
    for rule in spec.rules:
        hit = undecided & rule.contains(points)
        part_ids[hit] = rule.part
        undecided &= ~hit
    return part_ids


def transform_part_spec(spec: PartSpec, center: Sequence[float], scale: float) -> PartSpec:
    """The same spec in coordinates ``p' = (p - center) * scale`` (scale > 0)."""
    if not scale > 0:
        raise ValueError(f"transform_part_spec: scale must be positive, got {scale}")
    center_array = np.asarray(center, dtype=np.float64)

    def moved(point: Sequence[float]) -> tuple[float, float, float]:
        return _vector3((np.asarray(point) - center_array) * scale, "point")

    rules: list[Rule] = []
    for rule in spec.rules:
        if isinstance(rule, BoxRule):
            rules.append(BoxRule(rule.part, moved(rule.lower), moved(rule.upper)))
        else:
            rules.append(HalfSpaceRule(rule.part, moved(rule.point), rule.normal))
    return PartSpec(spec.part_names, spec.default_part, tuple(rules))
