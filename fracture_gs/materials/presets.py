"""Material presets: ``preset: porcelain`` in a scene's material mapping.

A preset is a YAML file in ``configs/materials/`` (the repository's, beside this package) holding
the keys a scene gets (``keys``), and for the brittle presets the real material they stand for
(``real``, with its ``source``) and the softening that makes it affordable to simulate:

* ``softening`` k: E / k and the strength / √k; density, ν, the fracture energy and the Weibull
  modulus unchanged. The wave speed falls by √k, so the time step grows by √k, while the numbers
  that decide how a body breaks stay the real material's: the impact stress over the strength
  ρ c v / σ_F, the impact's energy per crack area ρ v² L / G_f and Hillerborg's brittleness
  L / l_ch with l_ch = E G_f / σ_F². What changes is the strain at failure σ_F / E (√k larger).
* ``speed``: the impact speed (m/s) the preset is documented for.

Keys given beside ``preset`` override the preset's (``{part: 0, preset: porcelain,
fracture_energy: 40}``); ``softening`` beside it applies the rule with another k to the real values
(``{preset: porcelain, softening: 100}``: stiffer, a smaller time step; gravity's share
ρ g L / E, which the rule does not hold, k times smaller). docs/materials.md lists the presets and states the rule.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from fracture_gs import bounds, keys

PRESET_FOLDER = Path(__file__).resolve().parents[2] / "configs" / "materials"
SOFTENED_KEYS = {"E": 1.0, "strength": 0.5}   # key -> exponent p: value / k^p


@dataclass(frozen=True)
class Preset:
    """One preset file: ``model``, the scene keys, and for scaled presets the real values."""

    name: str
    model: str
    keys: dict[str, float]
    source: str
    real: dict[str, float] = field(default_factory=dict)
    softening: float = 1.0
    speed: float | None = None

    def scaled(self) -> dict[str, float]:
        """The real values under the softening rule (what ``keys`` must hold)."""
        return softened(self.real, self.softening)


def softened(real: Mapping[str, float], softening: float) -> dict[str, float]:
    """E / k, strength / √k, every other value unchanged."""
    return {key: value / softening ** SOFTENED_KEYS.get(key, 0.0) for key, value in real.items()}


def p_wave_speed(E: float, nu: float, density: float) -> float:
    """√(M / ρ), M = E (1 − ν) / ((1 + ν)(1 − 2ν)): the speed of a plane compression wave (m/s)."""
    return math.sqrt(E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu)) / density)


def impact_ratio(values: Mapping[str, float], speed: float) -> float:
    """ρ c v / σ_F: the stress of a plane impact at ``speed`` over the tensile strength."""
    c = p_wave_speed(values["E"], values["nu"], values["density"])
    return values["density"] * c * speed / values["strength"]


def characteristic_length(values: Mapping[str, float]) -> float:
    """Hillerborg's l_ch = E G_f / σ_F² (m)."""
    return values["E"] * values["fracture_energy"] / values["strength"] ** 2


def available() -> list[str]:
    """Names of the presets in ``configs/materials/``."""
    return sorted(path.stem for path in PRESET_FOLDER.glob("*.yaml"))


def load_preset(name: str, path: str = "preset") -> Preset:
    """The preset called ``name``; a SceneError naming ``path`` if there is none or it is malformed."""
    file = PRESET_FOLDER / f"{name}.yaml"
    if not keys.NAME_PATTERN.match(name) or not file.is_file():
        names = ", ".join(available()) or f"none in {PRESET_FOLDER}"
        raise keys.SceneError(path, f"unknown preset {name!r} (presets: {names})")
    try:
        data = yaml.safe_load(file.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise keys.SceneError(path, f"{file}: {error}") from None
    where = str(file)
    data = keys.mapping(data, where)
    keys.check_keys(data, where, ("model", "keys", "source", "real", "softening", "speed"),
                    required=("model", "keys", "source"))
    real = dict(keys.mapping(data.get("real", {}), f"{where}.real"))
    return Preset(name=name, model=str(data["model"]), keys=dict(keys.mapping(data["keys"], f"{where}.keys")),
                  source=str(data["source"]), real=real,
                  softening=keys.number(data, "softening", where, 1.0, gt=0.0),
                  speed=keys.number(data, "speed", where, None, gt=0.0))


def expand(data: Mapping[str, Any], path: str) -> Mapping[str, Any]:
    """A material mapping with its ``preset`` replaced by the preset's model and keys (keys given
    beside the preset win); a mapping without ``preset`` as it is."""
    if "preset" not in data:
        return data
    name = data["preset"]
    if not isinstance(name, str):
        raise keys.SceneError(f"{path}.preset", f"expected a preset name, got {keys.type_name(name)}")
    preset = load_preset(name, f"{path}.preset")
    if "model" in data and data["model"] != preset.model:
        raise keys.SceneError(f"{path}.model", f"preset {name!r} is a {preset.model} material, not {data['model']}")
    base = preset.keys
    if "softening" in data:
        if not preset.real:
            raise keys.SceneError(f"{path}.softening", f"preset {name!r} has no real values to soften")
        base = {**base, **softened(preset.real, keys.number(data, "softening", path, ge=1.0,
                                                            within=bounds.SOFTENING))}
    overrides = {key: value for key, value in data.items() if key not in ("preset", "softening")}
    return {"model": preset.model, **base, **overrides}
