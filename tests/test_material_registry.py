"""The material registry: the Python classes and the C++ headers describe the same models (names, codes,
parameter columns, state fields), docs/design_mpm.md's layout table is the registry's, and each
model's identifiers stand in at most four source files (its class, its header, the two registries)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from fracture_gs import _backend
from fracture_gs.materials import MODELS, TABLE_COLUMNS, MaterialTable, model_by_code, model_columns
from fracture_gs.materials.model import PARAMETER_SLOTS

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import material_docs  # noqa: E402
import material_footprint  # noqa: E402


@pytest.mark.extension
def test_the_kernels_know_the_models_the_classes_describe() -> None:
    compiled = _backend.compiled_module()
    described = compiled.material_models()
    assert [entry["code"] for entry in described] == list(range(len(MODELS)))
    for cls, entry in zip(MODELS, described):
        assert entry["name"] == cls.name and entry["code"] == cls.code
        assert tuple(entry["parameters"]) == cls.parameter_columns, cls.name
        assert tuple(entry["state"]) == cls.state_fields, cls.name
    assert compiled.max_state_fields == max(len(cls.state_fields) for cls in MODELS)


def test_every_model_fills_its_row_and_names_its_columns() -> None:
    for code, cls in enumerate(MODELS):
        assert model_by_code(code) is cls and cls.code == code
        assert len(cls.parameter_columns) == PARAMETER_SLOTS and len(cls.state_fields) >= 1
        columns = model_columns(cls)
        named = [name for name in cls.parameter_columns if name]
        assert [columns[name] for name in named] == [4 + cls.parameter_columns.index(name) for name in named]
        assert columns["model"] == 0 and columns["fracture_threshold"] == len(TABLE_COLUMNS) - 1
        if cls.split_direction is not None:   # three consecutive fields
            first = cls.state_fields.index(cls.split_direction)
            assert first + 3 <= len(cls.state_fields)
        assert set(cls.frame_fields) <= set(cls.state_fields)
    with pytest.raises(ValueError, match="unknown material model code"):
        model_by_code(len(MODELS))


def test_the_state_block_starts_with_each_models_initial_state() -> None:
    import numpy as np
    import torch

    from fracture_gs.materials import BrittleMaterial, ElasticMaterial, NACCMaterial

    materials = [NACCMaterial(E=1e4, nu=0.3, density=1.0, alpha0=-0.02, beta=0.5, xi=1.0, M=2.36),
                 BrittleMaterial(E=1e6, nu=0.2, density=10.0, strength=1e4, fracture_energy=1.0),
                 ElasticMaterial(E=1e4, nu=0.3, density=1.0)]
    table = MaterialTable(materials, cell_size=0.01)
    ids = torch.tensor([0, 1, 2, 1, 0], dtype=torch.int32)
    state = table.initial_state(ids, torch.full((5,), 1e-6), seed=0)
    assert state.shape == (5, table.state_width) and table.state_width == len(BrittleMaterial.state_fields)
    assert torch.allclose(state[:, 0], torch.tensor([-0.02, 0.0, 0.0, 0.0, -0.02]))
    strength = BrittleMaterial.state_fields.index("strength")
    assert torch.equal(state[[1, 3], strength], torch.full((2,), 1e4))
    assert float(state[[0, 2, 4], 1:].abs().sum()) == 0.0          # columns a model does not own stay 0
    directions = table.split_directions(state, ids)
    assert directions is not None and directions.shape == (5, 3) and float(directions.abs().sum()) == 0.0
    assert set(table.frame_fields(state, ids)) == {"damage"}
    assert np.isinf(table.piece_thresholds().numpy()[[0, 2]]).all()


def test_design_doc_layout_is_the_registry_s() -> None:
    text = material_docs.DOC.read_text(encoding="utf-8")
    assert material_docs.rendered(text) == text, "run python tools/material_docs.py --write"


def test_each_model_stands_in_at_most_four_source_files(capsys: pytest.CaptureFixture[str]) -> None:
    found = material_footprint.footprint(ROOT)
    print({model: len(files) for model, files in found.items()})
    for model, files in found.items():
        assert 1 <= len(files) <= material_footprint.LIMIT, (model, files)
    # The counting finds identifiers, not words: a model named only in comments does not count, a
    # camel-case or snake-case identifier does, another word containing the letters does not.
    assert material_footprint.cpp_identifiers('// BrittleModel\n x = "nacc"; int kModelNacc;') >= {"kModelNacc"}
    assert "BrittleModel" not in material_footprint.cpp_identifiers("// BrittleModel\n int x;")
    pattern = "|".join(material_footprint.PATTERNS["nacc"])
    import re
    assert re.search(pattern, "is_nacc") and re.search(pattern, "kModelNacc") and not re.search(pattern, "fibonacci")
