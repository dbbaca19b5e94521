"""Reading YAML mappings key by key, with errors that name the key path.

A problem raises :class:`SceneError`, whose message names the key, e.g.
``objects[1].materials[0].nu: 0.5 is not < 0.5``. The scene parser
(:mod:`fracture_gs.config.scene`) and the materials (:mod:`fracture_gs.materials`) read their keys
with these functions.
"""
from __future__ import annotations

import difflib
import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
NAME_RULE = "letters, digits, '_', '-', '.'; no spaces or slashes"


class SceneError(ValueError):
    """An invalid scene: ``key_path`` names the bad key (or the file), ``problem`` says why."""

    def __init__(self, key_path: str, problem: str) -> None:
        self.key_path = key_path
        self.problem = problem
        super().__init__(f"{key_path}: {problem}" if key_path else problem)


MISSING = object()


def fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, str):
        return repr(value)
    return str(value)


def type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"{type(value).__name__} {fmt(value)}"


def join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def mapping(value: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise SceneError(path or "<scene>", f"expected a mapping, got {type_name(value)}")
    for key in value:
        if not isinstance(key, str):
            raise SceneError(join(path, str(key)), "keys must be strings")
    return value


def check_keys(data: Mapping[str, Any], path: str, allowed: Sequence[str],
                required: Sequence[str] = ()) -> None:
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else \
                f" (allowed: {', '.join(allowed)})"
            raise SceneError(join(path, key), f"unknown key{hint}")
    for key in required:
        if key not in data:
            raise SceneError(join(path, key), "required key is missing")


def absent(keypath: str, default: Any) -> Any:
    """The default of an absent key, or the error if the key is required."""
    if default is MISSING:
        raise SceneError(keypath, "required key is missing")
    return default


def number(data: Mapping[str, Any], key: str, path: str, default: Any = MISSING, *,
            gt: float | None = None, ge: float | None = None,
            lt: float | None = None, le: float | None = None,
            within: tuple[float, float] | None = None, off: float | None = None) -> float:
    """The number at ``key`` (``default`` when absent): ``gt`` ... ``le`` are checked first,
    then the range ``within`` (the value's documented bounds, ``bounds.py``), which the value
    ``off`` may skip (``weibull_m: 0`` turns the Weibull scatter off)."""
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    return check_number(data[key], keypath, gt=gt, ge=ge, lt=lt, le=le, within=within, off=off)


def check_number(value: Any, keypath: str, *, gt: float | None = None,
                  ge: float | None = None, lt: float | None = None,
                  le: float | None = None, within: tuple[float, float] | None = None,
                  off: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(keypath, f"expected a number, got {type_name(value)}")
    if not math.isfinite(value):
        raise SceneError(keypath, f"{fmt(value)} is not finite")
    if gt is not None and not value > gt:
        raise SceneError(keypath, f"{fmt(value)} is not > {fmt(gt)}")
    if ge is not None and not value >= ge:
        raise SceneError(keypath, f"{fmt(value)} is not >= {fmt(ge)}")
    if lt is not None and not value < lt:
        raise SceneError(keypath, f"{fmt(value)} is not < {fmt(lt)}")
    if le is not None and not value <= le:
        raise SceneError(keypath, f"{fmt(value)} is not <= {fmt(le)}")
    if within is not None and not within[0] <= value <= within[1] and value != off:
        unless = f" (nor exactly {fmt(float(off))})" if off is not None else ""
        raise SceneError(keypath, f"{fmt(float(value))} is not within [{fmt(float(within[0]))}, "
                                  f"{fmt(float(within[1]))}]{unless}")
    return float(value)


def boolean(data: Mapping[str, Any], key: str, path: str, default: Any = MISSING) -> bool:
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    value = data[key]
    if not isinstance(value, bool):
        raise SceneError(keypath, f"expected true or false, got {type_name(value)}")
    return value


def integer(data: Mapping[str, Any], key: str, path: str, default: Any = MISSING, *,
             ge: int | None = None, le: int | None = None) -> int:
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    value = data[key]
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise SceneError(keypath, f"expected an integer, got {type_name(value)}")
    if ge is not None and value < ge:
        raise SceneError(keypath, f"{value} is not >= {ge}")
    if le is not None and value > le:
        raise SceneError(keypath, f"{value} is not <= {le}")
    return value


def vec3(data: Mapping[str, Any], key: str, path: str,
          default: Any = MISSING, *, gt: float | None = None,
          within: tuple[float, float] | None = None) -> tuple[float, float, float]:
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    value = data[key]
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise SceneError(keypath, f"expected a list of 3 numbers, got {type_name(value)}")
    return tuple(check_number(v, f"{keypath}[{i}]", gt=gt, within=within)  # type: ignore[return-value]
                 for i, v in enumerate(value))


def choice(data: Mapping[str, Any], key: str, path: str, choices: Sequence[str],
            default: Any = MISSING) -> str:
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    value = data[key]
    if not isinstance(value, str) or value not in choices:
        raise SceneError(keypath, f"{fmt(value)} is not one of {', '.join(choices)}")
    return value


def listing(data: Mapping[str, Any], key: str, path: str, default: Any = MISSING) -> list[Any]:
    keypath = join(path, key)
    if key not in data:
        return absent(keypath, default)
    value = data[key]
    if not isinstance(value, list):
        raise SceneError(keypath, f"expected a list, got {type_name(value)}")
    return value


def name(value: Any, keypath: str) -> str:
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise SceneError(keypath, f"{fmt(value)} is not a valid name ({NAME_RULE})")
    return value
