"""Part specs: parsing, validation errors, first-match-wins assignment, transforms."""
import json

import numpy as np
import pytest
import torch

from fracture_gs.data.parts import (PartSpecError, assign_part_ids, load_part_spec,
                                    part_spec_from_dict, save_part_spec, single_part_spec,
                                    transform_part_spec)

SPEC = {
    "parts": [{"id": 0, "name": "pot"}, {"id": 1, "name": "branches"}, {"id": 2, "name": "leaves"}],
    "default_part": 2,
    "rules": [
        {"part": 1, "box": {"min": [-0.1, -0.1, 0.0], "max": [0.1, 0.1, 1.0]}},
        {"part": 0, "halfspace": {"point": [0, 0, 0.5], "normal": [0, 0, -1]}},
    ],
}


def test_first_matching_rule_wins_and_default():
    points = np.array([[0.0, 0.0, 0.2],    # in the box and below z=0.5: box is first -> 1
                       [0.5, 0.0, 0.2],    # below z=0.5 only -> 0
                       [0.5, 0.0, 0.8],    # nothing -> default 2
                       [0.1, -0.1, 1.0],   # box bounds are inclusive -> 1
                       [0.5, 0.5, 0.5]])   # half-space is closed -> 0
    ids = assign_part_ids(points, SPEC)
    assert ids.dtype == np.int32
    assert ids.tolist() == [1, 0, 2, 1, 0]


def test_torch_points_and_roundtrip(tmp_path):
    spec = part_spec_from_dict(SPEC)
    path = tmp_path / "parts.json"
    save_part_spec(spec, path, extra={"object": "ficus"})
    loaded = load_part_spec(path)
    assert loaded == spec
    assert json.loads(path.read_text())["object"] == "ficus"
    points = torch.rand(200, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
    assert np.array_equal(assign_part_ids(points, loaded), assign_part_ids(points.numpy(), spec))


def test_transform_keeps_assignment():
    spec = part_spec_from_dict(SPEC)
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1.5, (500, 3))
    center, scale = np.array([0.3, -0.2, 0.7]), 1.7
    moved = transform_part_spec(spec, center, scale)
    assert np.array_equal(assign_part_ids(points, spec),
                          assign_part_ids((points - center) * scale, moved))


def test_single_part():
    ids = assign_part_ids(np.zeros((3, 3)), single_part_spec())
    assert ids.tolist() == [0, 0, 0]


@pytest.mark.parametrize("change, message", [
    (lambda s: s.update(parts=[]), "'parts' must be a non-empty list"),
    (lambda s: s["parts"][1].update(id=5), "parts[1].id"),
    (lambda s: s.update(default_part=3), "default_part: part id 3"),
    (lambda s: s["rules"][0].update(part=-1), "rules[0].part"),
    (lambda s: s["rules"][0]["box"].update(min=[0, 0]), "rules[0].box.min"),
    (lambda s: s["rules"][0]["box"].update(min=[1, 1, 1]), "rules[0].box: min"),
    (lambda s: s["rules"][1]["halfspace"].update(normal=[0, 0, 0]), "must not be zero"),
    (lambda s: s["rules"][1]["halfspace"].update(point=[0, float("nan"), 0]), "NaN"),
    (lambda s: s["rules"][1].update(box={"min": [0] * 3, "max": [1] * 3}), "exactly one of"),
])
def test_bad_specs_name_the_key(change, message):
    spec = json.loads(json.dumps(SPEC))
    change(spec)
    with pytest.raises(PartSpecError, match=message.replace("[", r"\[").replace("]", r"\]")):
        part_spec_from_dict(spec, source="parts.json")


def test_bad_files(tmp_path):
    with pytest.raises(PartSpecError, match="file not found"):
        load_part_spec(tmp_path / "missing.json")
    bad = tmp_path / "parts.json"
    bad.write_text("{not json")
    with pytest.raises(PartSpecError, match="invalid JSON"):
        load_part_spec(bad)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        assign_part_ids(np.zeros((4, 2)), SPEC)
