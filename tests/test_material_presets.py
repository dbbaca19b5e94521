"""Material presets (configs/materials/): the softening rule holds the numbers that decide breaking."""
from __future__ import annotations

import math

import pytest

from fracture_gs.config.scene import SceneError, parse_scene
from fracture_gs.materials import BrittleMaterial, ElasticMaterial, NACCMaterial, material_from_yaml
from fracture_gs.materials.presets import (available, characteristic_length, impact_ratio, load_preset,
                                           p_wave_speed)

PRESETS = available()
BRITTLE = [name for name in PRESETS if load_preset(name).model == "brittle"]
SCALED = [name for name in PRESETS if load_preset(name).real]
MODEL_CLASSES = {"brittle": BrittleMaterial, "nacc": NACCMaterial, "elastic": ElasticMaterial}


def test_the_presets_the_docs_promise_exist() -> None:
    for name in ("porcelain", "glass", "ceramic_tile", "stone", "paper_teapot", "paper_bowl", "paper_table_top",
                 "paper_table_leg", "paper_ficus_leaf", "paper_ficus_branch", "paper_ficus_pot", "wood"):
        assert name in PRESETS


@pytest.mark.parametrize("name", BRITTLE)
def test_scaled_impact_stress_over_strength_is_the_real_materials(name: str) -> None:
    preset = load_preset(name)
    assert preset.speed is not None and preset.source
    real, scaled = preset.real, preset.keys
    assert impact_ratio(scaled, preset.speed) == pytest.approx(impact_ratio(real, preset.speed), rel=0.10)
    # Hillerborg's length (so L / l_ch) and the impact energy per crack area rho v^2 L / G_f are kept too.
    assert characteristic_length(scaled) == pytest.approx(characteristic_length(real), rel=0.01)
    assert scaled["density"] / scaled["fracture_energy"] == pytest.approx(real["density"] / real["fracture_energy"])


@pytest.mark.parametrize("name", SCALED)
def test_scaled_values_follow_the_softening_rule(name: str) -> None:
    preset = load_preset(name)
    assert preset.softening > 1
    for key, value in preset.scaled().items():
        assert preset.keys[key] == pytest.approx(value, rel=1e-3), key
    # what the rule buys: a wave speed (and so a time step) sqrt(k) times slower (larger)
    slower = p_wave_speed(preset.real["E"], preset.real["nu"], preset.real["density"]) / p_wave_speed(
        preset.keys["E"], preset.keys["nu"], preset.keys["density"])
    assert slower == pytest.approx(math.sqrt(preset.softening), rel=1e-3)


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_makes_a_valid_material(name: str) -> None:
    material = material_from_yaml({"part": 0, "preset": name}, "materials[0]")
    assert isinstance(material, MODEL_CLASSES[load_preset(name).model])


def test_keys_beside_a_preset_override_it() -> None:
    material = material_from_yaml({"part": 0, "preset": "porcelain", "fracture_energy": 40.0}, "m")
    assert material.fracture_energy == 40.0
    assert material.E == load_preset("porcelain").keys["E"]


def test_a_scene_can_soften_a_preset_less() -> None:
    preset = load_preset("porcelain")
    stiffer = material_from_yaml({"part": 0, "preset": "porcelain", "softening": 100}, "m")
    assert stiffer.E == pytest.approx(preset.real["E"] / 100)
    assert stiffer.strength == pytest.approx(preset.real["strength"] / 10)
    assert impact_ratio(stiffer.to_yaml(), preset.speed) == pytest.approx(impact_ratio(preset.real, preset.speed))


def test_the_paper_rows_are_table_1_as_printed() -> None:
    teapot = material_from_yaml({"part": 0, "preset": "paper_teapot"}, "m")
    assert (teapot.E, teapot.nu, teapot.density, teapot.beta, teapot.xi, teapot.M) == (5.0e5, 0.46, 5, 0.5, 1, 2.36)


@pytest.mark.parametrize("material, message", [
    ({"part": 0, "preset": "porcelian"}, "unknown preset 'porcelian' (presets: "),
    ({"part": 0, "preset": 3}, "expected a preset name"),
    ({"part": 0, "preset": "../../etc/passwd"}, "unknown preset"),
    ({"part": 0, "preset": "porcelain", "model": "nacc"}, "preset 'porcelain' is a brittle material, not nacc"),
    ({"part": 0, "preset": "porcelain", "beta": 0.5}, "unknown key for model brittle"),
    ({"part": 0, "preset": "porcelain", "softening": 0.5}, "softening: 0.5 is not >= 1"),
    ({"part": 0, "preset": "paper_teapot", "softening": 10}, "preset 'paper_teapot' has no real values to soften"),
])
def test_bad_presets_name_the_key(material: dict, message: str) -> None:
    scene = {"name": "presets", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
             "objects": [{"name": "ball", "primitive": {"shape": "sphere", "radius": 0.1},
                          "transform": {"translate": [0.5, 0.5, 0.5]}, "materials": [material]}]}
    with pytest.raises(SceneError, match="objects\\[0\\].materials\\[0\\]") as error:
        parse_scene(scene)
    assert message in str(error.value)
