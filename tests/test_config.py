"""Scene YAML validation (docs/scenes.md): typed config, defaults, key-path errors."""
from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from fracture_gs.config import (BoxBoundary, GroundBoundary, SceneConfig, SceneError, load_scene,
                                parse_scene)


def base_scene() -> dict[str, Any]:
    return {
        "name": "unit",
        "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
        "frames": 3,
        "frame_dt": 0.01,
        "gravity": [0, 0, 0],
        "boundaries": [{"type": "ground", "height": 0.1}, {"type": "box"}],
        "objects": [
            {"name": "ball", "primitive": {"shape": "sphere", "radius": 0.1},
             "transform": {"translate": [0.3, 0.5, 0.5]}, "velocity": [1, 0, 0],
             "materials": [{"part": 0, "model": "nacc", "E": 1e4, "nu": 0.3, "density": 10,
                            "Jp0": 0.98}]},
            {"name": "block", "primitive": {"shape": "box", "size": [0.2, 0.2, 0.2]},
             "transform": {"translate": [0.7, 0.5, 0.5]},
             "materials": [{"model": "elastic", "E": 2e4, "nu": 0.2, "density": 5}]},
        ],
    }


def test_valid_scene_fills_defaults() -> None:
    config = parse_scene(base_scene())
    assert isinstance(config, SceneConfig)
    assert config.cfl == 0.3 and config.contact.mode == "collision"
    assert config.contact.impulse_scale == 1.0 and config.contact.friction == 0.0
    assert config.boundaries == (GroundBoundary(height=0.1, friction=0.5), BoxBoundary("slip"))
    ball, block = config.objects
    assert ball.primitive is not None and ball.primitive.particles_per_cell == 8
    assert ball.transform.scale == 1.0 and ball.transform.rotate_deg == (0.0, 0.0, 0.0)
    mat = ball.materials[0].material
    assert mat.alpha0 == pytest.approx(math.log(0.98))
    assert (mat.beta, mat.xi, mat.M, mat.alpha_threshold) == (0.5, 1.0, 2.36, 0.0)
    assert block.velocity == (0.0, 0.0, 0.0)
    assert block.materials[0].part == 0 and "alpha0" not in block.materials[0].material.to_yaml()


def test_to_dict_round_trips_through_yaml(tmp_path: Path) -> None:
    config = parse_scene(base_scene())
    path = tmp_path / "resolved.yaml"
    path.write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
    again = load_scene(path)
    assert again == config
    # the resolved form holds alpha0 / M, never Jp0 / friction_angle
    material = again.to_dict()["objects"][0]["materials"][0]
    assert "Jp0" not in material and material["alpha0"] == pytest.approx(math.log(0.98))


def test_friction_angle_gives_M() -> None:
    scene = base_scene()
    scene["objects"][0]["materials"][0]["friction_angle"] = 30.0
    mat = parse_scene(scene).objects[0].materials[0].material
    assert mat.M == pytest.approx(6 * 0.5 / (3 - 0.5))


def test_yaml_1_2_floats_are_numbers(tmp_path: Path) -> None:
    """PyYAML alone reads ``5.0e5`` as a string; the scene loader must not."""
    text = yaml.safe_dump(base_scene(), sort_keys=False).replace("10000.0", "5.0e5")
    assert "5.0e5" in text
    path = tmp_path / "s.yaml"
    path.write_text(text)
    assert load_scene(path).objects[0].materials[0].material.E == 5.0e5


def test_name_defaults_to_file_stem(tmp_path: Path) -> None:
    scene = base_scene()
    del scene["name"]
    path = tmp_path / "my_scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    assert load_scene(path).name == "my_scene"


def _set(scene: dict[str, Any], path: str, value: Any) -> None:
    """Set (or with value=DELETE, remove) a dotted/indexed key of a nested scene dict."""
    tokens = path.replace("]", "").replace("[", ".").split(".")
    node: Any = scene
    for token in tokens[:-1]:
        node = node[int(token)] if token.isdigit() else node[token]
    last = tokens[-1]
    key: Any = int(last) if last.isdigit() else last
    if value is DELETE:
        del node[key]
    else:
        node[key] = value


DELETE = object()

# (what to change, new value, expected key path, expected fragment of the problem)
MALFORMED = [
    ("objects.1.materials.0.nu", 0.5, "objects[1].materials[0].nu", "0.5 is not < 0.5"),
    ("objects.0.materials.0.nu", -0.1, "objects[0].materials[0].nu", "-0.1 is not >= 0"),
    ("objects.0.materials.0.E", -5, "objects[0].materials[0].E", "-5 is not > 0"),
    ("objects.0.materials.0.density", 0, "objects[0].materials[0].density", "0 is not > 0"),
    ("objects.0.materials.0.beta", -1, "objects[0].materials[0].beta", "-1 is not >= 0"),
    ("objects.0.materials.0.xi", -0.5, "objects[0].materials[0].xi", "-0.5 is not >= 0"),
    ("objects.0.materials.0.M", 0, "objects[0].materials[0].M", "0 is not > 0"),
    ("objects.0.materials.0.E", "stiff", "objects[0].materials[0].E",
     "expected a number, got str 'stiff'"),
    ("objects.0.materials.0.E", True, "objects[0].materials[0].E", "expected a number"),
    ("objects.0.materials.0.E", float("nan"), "objects[0].materials[0].E", "not finite"),
    ("objects.0.materials.0.model", "rubber", "objects[0].materials[0].model",
     "'rubber' is not one of elastic, nacc, brittle"),
    ("objects.0.materials.0.Jp0", DELETE, "objects[0].materials[0].alpha0",
     "required key is missing"),
    ("objects.0.materials.0.alpha0", -0.02, "objects[0].materials[0].Jp0", "both given"),
    ("objects.0.materials.0.Jp0", 0.0, "objects[0].materials[0].Jp0", "0 is not > 0"),
    ("objects.0.materials.0.friction_angle", 95, "objects[0].materials[0].friction_angle",
     "95 is not < 90"),
    ("objects.1.materials.0.beta", 0.5, "objects[1].materials[0].beta", "unknown key"),
    ("objects.0.materials.0.part", -1, "objects[0].materials[0].part", "-1 is not >= 0"),
    ("objects.0.materials.0.E", DELETE, "objects[0].materials[0].E", "required key is missing"),
    ("objects.0.materials", [], "objects[0].materials", "at least one material"),
    ("objects.0.materails", [], "objects[0].materails", "did you mean 'materials'"),
    ("objects.0.velocity", [1, 2], "objects[0].velocity", "expected a list of 3 numbers"),
    ("objects.0.transform.scale", 0, "objects[0].transform.scale", "0 is not > 0"),
    ("objects.0.transform.rotate", [0, 0, 1], "objects[0].transform.rotate",
     "did you mean 'rotate_deg'"),
    ("objects.0.primitive.radius", -0.1, "objects[0].primitive.radius", "-0.1 is not > 0"),
    ("objects.0.primitive.shape", "cone", "objects[0].primitive.shape", "is not one of"),
    ("objects.0.primitive.size", [1, 1, 1], "objects[0].primitive.size", "unknown key"),
    ("objects.0.primitive.particles_per_cell", 0, "objects[0].primitive.particles_per_cell",
     "0 is not >= 1"),
    ("objects.1.primitive.size", [0.2, 0, 0.2], "objects[1].primitive.size[1]", "0 is not > 0"),
    ("objects.0.primitive", DELETE, "objects[0]", "exactly one of 'model' and 'primitive'"),
    ("objects.0.model", "somewhere/model", "objects[0]", "both given"),
    ("objects.1.name", "ball", "objects[1].name", "already the name of objects[0]"),
    ("objects.1.name", "my block", "objects[1].name", "not a valid name"),
    ("objects", [], "objects", "at least one object"),
    ("objects", DELETE, "objects", "required key is missing"),
    ("domain.grid", 4, "domain.grid", "4 is not >= 8"),
    ("domain.grid", 16.5, "domain.grid", "expected an integer"),
    ("domain.grid", DELETE, "domain.grid", "required key is missing"),
    ("domain.max", [1, 0, 1], "domain.max[1]", "is not > domain.min[1]"),
    ("domain", [0, 1], "domain", "expected a mapping"),
    ("frames", 0, "frames", "0 is not >= 1"),
    ("frame_dt", 0, "frame_dt", "0 is not > 0"),
    ("cfl", 1.5, "cfl", "1.5 is not <= 1"),
    ("cfl", 0, "cfl", "0 is not > 0"),
    ("gravity", "down", "gravity", "expected a list of 3 numbers"),
    ("contact", {"mode": "glue"}, "contact.mode", "'glue' is not one of collision, mls"),
    ("contact", {"friction": -1}, "contact.friction", "-1 is not >= 0"),
    ("contact", {"impulse_scale": 2.5}, "contact.impulse_scale", "2.5 is not <= 2"),
    ("contact", {"impulse_scale": -0.5}, "contact.impulse_scale", "-0.5 is not >= 0"),
    ("contact", {"strength": 1.0}, "contact.strength", "this key is now called 'impulse_scale'"),
    ("boundaries.1.condition", "bouncy", "boundaries[1].condition", "is not one of"),
    ("boundaries.0.type", "wall", "boundaries[0].type", "is not one of ground, box"),
    ("boundaries.0.height", 2.0, "boundaries[0].height", "2 is not < 1"),
    ("boundaries.0.friction", -0.1, "boundaries[0].friction", "-0.1 is not >= 0"),
    ("boundaries.0.height", DELETE, "boundaries[0].height", "required key is missing"),
    ("boundaries.1.type", "ground", "boundaries[1].type", "a second 'ground' boundary"),
    ("fps", 30, "fps", "unknown key"),
]


@pytest.mark.parametrize("path,value,key_path,problem", MALFORMED,
                         ids=[f"{m[0]}={m[1]!r}"[:60] for m in MALFORMED])
def test_malformed_scene_names_key_path(path: str, value: Any, key_path: str,
                                        problem: str) -> None:
    scene = copy.deepcopy(base_scene())
    _set(scene, path, value)
    with pytest.raises(SceneError) as info:
        parse_scene(scene)
    assert info.value.key_path == key_path
    assert problem in info.value.problem
    assert str(info.value).startswith(f"{key_path}: ")
    assert "\n" not in str(info.value)


def test_model_paths_are_checked(tmp_path: Path) -> None:
    scene = base_scene()
    del scene["objects"][0]["primitive"]
    scene["objects"][0]["model"] = str(tmp_path / "missing_model")
    with pytest.raises(SceneError, match=r"^objects\[0\]\.model: .* does not exist"):
        parse_scene(scene)
    (tmp_path / "empty_model").mkdir()
    scene["objects"][0]["model"] = str(tmp_path / "empty_model")
    with pytest.raises(SceneError, match=r"has no particles\.ply"):
        parse_scene(scene)
    not_ply = tmp_path / "points.txt"
    not_ply.write_text("1 2 3\n")
    scene["objects"][0]["model"] = str(not_ply)
    with pytest.raises(SceneError, match=r"neither a train\.py output folder nor a \.ply"):
        parse_scene(scene)
    fake_ply = tmp_path / "fake.ply"
    fake_ply.write_text("not a ply\n")
    scene["objects"][0]["model"] = str(fake_ply)
    with pytest.raises(SceneError, match=r"is not a PLY file"):
        parse_scene(scene)


def test_model_path_relative_to_scene_file(tmp_path: Path) -> None:
    (tmp_path / "models" / "rock").mkdir(parents=True)
    (tmp_path / "models" / "rock" / "particles.ply").write_bytes(b"ply\n")
    scene = base_scene()
    del scene["objects"][0]["primitive"]
    scene["objects"][0]["model"] = "models/rock"
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    obj = load_scene(path).objects[0]
    assert obj.model == (tmp_path / "models" / "rock").resolve()
    assert obj.particles_file == obj.model / "particles.ply"


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(SceneError, match="file not found"):
        load_scene(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ndomain: {min: [0, 0\n")
    with pytest.raises(SceneError, match=r"invalid YAML at line"):
        load_scene(bad)
    top_list = tmp_path / "list.yaml"
    top_list.write_text("- 1\n- 2\n")
    with pytest.raises(SceneError, match="expected a mapping"):
        load_scene(top_list)


def test_a_key_given_twice_is_refused_with_both_lines(tmp_path: Path) -> None:
    twice = tmp_path / "twice.yaml"
    twice.write_text(yaml.safe_dump(base_scene(), sort_keys=False) + "frames: 99\n")
    first = next(i for i, line in enumerate(twice.read_text().splitlines(), 1)
                 if line.startswith("frames:"))
    last = len(twice.read_text().splitlines())
    with pytest.raises(SceneError) as error:
        load_scene(twice)
    assert str(error.value) == (f"{twice}: invalid YAML at line {last}: duplicate key 'frames' "
                                f"(first given at line {first})")
    nested = tmp_path / "nested.yaml"
    nested.write_text("domain: {min: [0, 0, 0], max: [1, 1, 1], grid: 16}\n"
                      "objects:\n"
                      "  - name: a\n"
                      "    primitive: {shape: sphere, radius: 0.1, radius: 0.2}\n")
    with pytest.raises(SceneError, match=r"line 4: duplicate key 'radius' \(first given at line 4\)"):
        load_scene(nested)


def test_merge_keys_are_not_duplicates(tmp_path: Path) -> None:
    merged = tmp_path / "merged.yaml"
    merged.write_text("domain: {min: [0, 0, 0], max: [1, 1, 1], grid: 16}\n"
                      "objects:\n"
                      "  - name: a\n"
                      "    primitive: &p {shape: sphere, radius: 0.1}\n"
                      "    transform: {translate: [0.5, 0.5, 0.5]}\n"
                      "    materials: [{part: 0, model: nacc, E: 1.0e4, nu: 0.3, density: 10, Jp0: 0.98}]\n"
                      "  - name: b\n"
                      "    primitive: {<<: *p, radius: 0.05}\n"
                      "    transform: {translate: [0.2, 0.2, 0.2]}\n"
                      "    materials: [{part: 0, model: nacc, E: 1.0e4, nu: 0.3, density: 10, Jp0: 0.98}]\n")
    config = load_scene(merged)
    assert [obj.primitive.radius for obj in config.objects] == [0.1, 0.05]
