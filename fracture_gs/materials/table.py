"""The kernels' material table and particle state block, and the twins of the compiled material ops.

The compiled kernels (``csrc/common/constitutive.h``) read a float32 table, one row of 8 numbers per
material (``TABLE_COLUMNS``): model code, μ, λ, K, three parameters named by the row's model
(``model_columns``) and the fracture threshold on state field 0. The particles' state is one
float32 block (N, S) (:mod:`fracture_gs.materials.model`). :class:`MaterialTable` builds both;
:func:`constitutive_update_reference` and :func:`elastic_energy_reference` are the vectorised torch
twins of ``_C.constitutive_update`` and ``_C.elastic_energy`` (mixed materials handled with one mask
per model). Nothing here names a model: the models come from the registry,
``fracture_gs.materials.MODELS``.
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Sequence, Union

import numpy as np
import torch

from fracture_gs import _backend, keys
from fracture_gs.materials import presets
from fracture_gs.materials.model import (BASE_COLUMNS, FIRST_PARAMETER, PARAMETER_SLOTS, THRESHOLD_COLUMN,
                                         MaterialModel)

TABLE_COLUMNS = BASE_COLUMNS + tuple(f"parameter_{i + 1}" for i in range(PARAMETER_SLOTS)) + (THRESHOLD_COLUMN,)
# The columns every row has, by name.
COLUMN = {name: TABLE_COLUMNS.index(name) for name in BASE_COLUMNS + (THRESHOLD_COLUMN,)}

__all__ = ["COLUMN", "MaterialTable", "TABLE_COLUMNS", "constitutive_update", "constitutive_update_reference",
           "elastic_energy", "elastic_energy_reference", "frame_field_names", "material_from_yaml",
           "model_by_code", "model_by_name", "model_columns"]


def _models() -> tuple[type[MaterialModel], ...]:
    from fracture_gs.materials import MODELS  # the registry (this module is imported while it loads)
    return MODELS


def model_by_name() -> dict[str, type[MaterialModel]]:
    """The model classes by YAML name, in the order of their codes."""
    return {cls.name: cls for cls in _models()}


def model_by_code(code: int) -> type[MaterialModel]:
    """The model class of a table's model code (ValueError for an unknown one)."""
    models = _models()
    if not 0 <= code < len(models):
        raise ValueError(f"unknown material model code {code}")
    return models[code]


def model_columns(cls: type[MaterialModel]) -> dict[str, int]:
    """Column of every name a row of ``cls`` has: the shared columns and the model's parameters."""
    named = {name: FIRST_PARAMETER + i for i, name in enumerate(cls.parameter_columns) if name}
    return {**COLUMN, **named}


def frame_field_names() -> tuple[str, ...]:
    """The state fields every frame holds under their own name (0 for particles whose model lacks
    them), over all models in the order of their codes."""
    names: list[str] = []
    for cls in _models():
        names += [name for name in cls.frame_fields if name not in names]
    return tuple(names)


def material_from_yaml(data: Any, path: str) -> MaterialModel:
    """The material of one scene material mapping (its ``model`` picks the class; key-path errors)."""
    data = presets.expand(keys.mapping(data, path), path)
    classes = model_by_name()
    model = keys.choice(data, "model", path, tuple(classes))
    own = set(classes[model].yaml_keys)
    for key in data:
        owners = [name for name, cls in classes.items() if key in cls.yaml_keys and key not in own]
        if owners:
            raise keys.SceneError(f"{path}.{key}", f"unknown key for model {model} (a key of model {' / '.join(owners)})")
    return classes[model].from_yaml(data, path)


class MaterialTable:
    """The materials of a scene in table order; row i is material_id i. ``cell_size``: the grid's dx
    (a model may need it for its parameters)."""

    def __init__(self, materials: Sequence[MaterialModel], cell_size: float | None = None) -> None:
        if len(materials) == 0:
            raise ValueError("MaterialTable: materials is empty")
        for index, material in enumerate(materials):
            if not isinstance(material, tuple(_models())):
                raise ValueError(f"MaterialTable: materials[{index}] is a "
                                 f"{type(material).__name__}, not a material")
        self.materials = list(materials)
        self.cell_size = cell_size

    def __len__(self) -> int:
        return len(self.materials)

    def table(self, device: torch.device | str | None = None) -> torch.Tensor:
        """(M, 8) float32 tensor of packed rows, on ``device``."""
        return torch.tensor([m.pack(self.cell_size) for m in self.materials], dtype=torch.float32, device=device)

    @property
    def max_wave_speed(self) -> float:
        """Largest P-wave speed over all materials (for the CFL time step)."""
        return max(m.wave_speed for m in self.materials)

    @property
    def state_width(self) -> int:
        """S, the columns of the state block: the most state fields among the materials' models."""
        return max(len(m.state_fields) for m in self.materials)

    def models(self) -> list[tuple[type[MaterialModel], list[int]]]:
        """The models of the table, each with its material rows, in the order of their codes."""
        rows: dict[type[MaterialModel], list[int]] = {}
        for index, material in enumerate(self.materials):
            rows.setdefault(type(material), []).append(index)
        return sorted(rows.items(), key=lambda item: item[0].code)

    def initial_state(self, material_id: torch.Tensor, rest_volume: torch.Tensor, seed: int) -> torch.Tensor:
        """(N, S) float32 state block on material_id's device: each particle's model's initial state
        (``MaterialModel.initial_state``; a particle's index is its row), 0 in the columns its model
        does not own."""
        ids = material_id.detach().cpu().numpy()
        volume = rest_volume.detach().cpu().numpy()
        state = np.zeros((len(ids), self.state_width), dtype=np.float64)
        for index, material in enumerate(self.materials):
            rows = np.nonzero(ids == index)[0]
            if len(rows):
                state[rows, :len(material.state_fields)] = material.initial_state(rows, volume[rows], seed)
        return torch.from_numpy(state.astype(np.float32)).to(material_id.device)

    def partition_thresholds(self, damage_dilation: float, device: torch.device | str | None = None
                             ) -> torch.Tensor:
        """(M,) float32: state field 0 from which the fragment partition treats a particle of each
        material as damaged (inf: never)."""
        return torch.tensor([m.partition_threshold(damage_dilation) for m in self.materials],
                            dtype=torch.float32, device=device)

    def piece_thresholds(self, device: torch.device | str | None = None) -> torch.Tensor:
        """(M,) float32: state field 0 from which a particle of each material is a piece of its own
        (inf: never)."""
        return torch.tensor([m.piece_threshold for m in self.materials], dtype=torch.float32, device=device)

    def split_directions(self, state: torch.Tensor, material_id: torch.Tensor) -> torch.Tensor | None:
        """(N, 3) split direction of every particle for the fragment partition (0: none), from the
        state fields its model names (``MaterialModel.split_direction``); None if no model of the
        table gives one. A view of the state block where the models agree on the columns."""
        firsts = {cls.state_fields.index(cls.split_direction) for cls, _ in self.models() if cls.split_direction}
        if not firsts:
            return None
        first = min(firsts)
        others_clear = all(len(cls.state_fields) <= first for cls, _ in self.models() if not cls.split_direction)
        if len(firsts) == 1 and others_clear:
            return state[:, first:first + 3]
        directions = torch.zeros(len(state), 3, dtype=state.dtype, device=state.device)
        for cls, rows in self.models():
            if cls.split_direction:
                start = cls.state_fields.index(cls.split_direction)
                mine = torch.isin(material_id, torch.tensor(rows, dtype=material_id.dtype, device=material_id.device))
                directions[mine] = state[mine, start:start + 3]
        return directions

    def frame_fields(self, state: torch.Tensor, material_id: torch.Tensor) -> dict[str, torch.Tensor]:
        """The arrays ``frame_field_names()`` names, (N,) each: the field of every particle whose model
        has it, 0 elsewhere."""
        out = {name: torch.zeros(len(state), dtype=state.dtype, device=state.device) for name in frame_field_names()}
        for cls, rows in self.models():
            if not cls.frame_fields:
                continue
            mine = torch.isin(material_id, torch.tensor(rows, dtype=material_id.dtype, device=material_id.device))
            for name in cls.frame_fields:
                column = state[:, cls.state_fields.index(name)]
                out[name] = torch.where(mine, column, out[name])
        return out


TableLike = Union[torch.Tensor, MaterialTable, Iterable[MaterialModel]]


def _table_tensor(materials: TableLike, like: torch.Tensor) -> torch.Tensor:
    """The material table as a tensor with ``like``'s device and dtype."""
    if isinstance(materials, torch.Tensor):
        table = materials
    else:
        table_obj = materials if isinstance(materials, MaterialTable) else MaterialTable(list(materials))
        table = table_obj.table(like.device)
    if table.ndim != 2 or table.shape[1] != len(TABLE_COLUMNS):
        raise ValueError(f"material_table must have shape (M, {len(TABLE_COLUMNS)}), "
                         f"got {tuple(table.shape)}")
    return table.to(device=like.device, dtype=like.dtype)


def _rows_per_particle(table: torch.Tensor, material_id: torch.Tensor) -> torch.Tensor:
    """Gather the table row of every particle, (N, 8); ValueError on out-of-range ids."""
    if material_id.numel() > 0:
        low, high = int(material_id.min()), int(material_id.max())
        if low < 0 or high >= table.shape[0]:
            raise ValueError(f"material_id: ids must be in [0, {table.shape[0]}), "
                             f"got range [{low}, {high}]")
    return table[material_id.long()]


def _state_block(state: torch.Tensor, n: int) -> torch.Tensor:
    """``state`` as an (N, S) block (an (N,) tensor is one field)."""
    block = state[:, None] if state.ndim == 1 else state
    if block.ndim != 2 or block.shape[0] != n or block.shape[1] < 1:
        raise ValueError(f"state must have shape ({n}, S) with S >= 1, got {tuple(state.shape)}")
    return block


def constitutive_update_reference(material_table_or_materials: TableLike, material_id: torch.Tensor,
                                  F_trial: torch.Tensor, state: torch.Tensor
                                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Torch twin of ``_C.constitutive_update``: (F_E, state', τ, dissipated) for mixed materials.

    ``state``: the (N, S) block, or (N,) for one field (``state'`` has its shape). Computes in F_trial's dtype (pass float64 for a reference of the
    float32 kernels). Rows with an unknown model code, and non-finite inputs, give NaN (F_E, τ and
    state field 0), like the compiled kernels.
    """
    table = _table_tensor(material_table_or_materials, F_trial)
    rows = _rows_per_particle(table, material_id)
    shape = state.shape
    state = _state_block(state, len(F_trial)).to(F_trial.dtype)
    model = rows[:, COLUMN["model"]]
    F_E = F_trial.clone()
    state_new = state.clone()
    tau = torch.full_like(F_trial, math.nan)
    dissipated = torch.zeros(len(F_trial), dtype=F_trial.dtype, device=F_trial.device)
    known = torch.zeros_like(model, dtype=torch.bool)
    for cls in _models():
        mask = model == cls.code
        known |= mask
        if bool(mask.any()):
            F_E[mask], updated, tau[mask], dissipated[mask] = cls.update_rows(
                F_trial[mask], _padded(state[mask], len(cls.state_fields)), rows[mask])
            state_new[mask] = updated[:, :state.shape[1]]
    # Like the kernels: unknown models and non-finite inputs give NaN, never a finite projection.
    unknown = ~known | ~torch.isfinite(F_trial).flatten(1).all(1) | ~torch.isfinite(state[:, 0])
    tau[unknown] = math.nan
    F_E[unknown] = math.nan
    state_new[unknown, 0] = math.nan
    dissipated[unknown] = 0.0
    return F_E, state_new.reshape(shape), tau, dissipated


def elastic_energy_reference(material_table_or_materials: TableLike, material_id: torch.Tensor,
                             F_E: torch.Tensor, state: torch.Tensor | None = None) -> torch.Tensor:
    """Torch twin of ``_C.elastic_energy``: ψ(F_E) per unit rest volume, (N,), at the particles'
    state (the (N, S) block; None: all 0)."""
    table = _table_tensor(material_table_or_materials, F_E)
    rows = _rows_per_particle(table, material_id)
    block = (torch.zeros(len(F_E), 1, dtype=F_E.dtype, device=F_E.device) if state is None
             else _state_block(state, len(F_E)).to(F_E.dtype))
    model = rows[:, COLUMN["model"]]
    psi = torch.full((len(F_E),), math.nan, dtype=F_E.dtype, device=F_E.device)
    for cls in _models():
        mask = model == cls.code
        if bool(mask.any()):
            psi[mask] = cls.energy_rows(F_E[mask], _padded(block[mask], len(cls.state_fields)), rows[mask])
    return psi


def _padded(state: torch.Tensor, width: int) -> torch.Tensor:
    """``state`` with at least ``width`` columns (zeros added), as the kernels see a short row."""
    if state.shape[1] >= width:
        return state
    return torch.cat([state, state.new_zeros(len(state), width - state.shape[1])], 1)


def constitutive_update(F_trial: torch.Tensor, state: torch.Tensor, material_table: torch.Tensor,
                        material_id: torch.Tensor, backend: str = "auto"
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(F_E, state', τ, dissipated) per particle, compiled kernel or torch reference
    (``_backend.use_compiled``); ``state`` the (N, S) block."""
    if _backend.use_compiled(F_trial.device, backend):
        return _backend.compiled_module().constitutive_update(F_trial, state, material_table, material_id)
    F_E, state_new, tau, dissipated = constitutive_update_reference(material_table, material_id, F_trial, state)
    return F_E, state_new.to(state.dtype).reshape(state.shape), tau, dissipated


def elastic_energy(F_E: torch.Tensor, material_table: torch.Tensor, material_id: torch.Tensor,
                   backend: str = "auto", state: torch.Tensor | None = None) -> torch.Tensor:
    """ψ(F_E) per unit rest volume at the particles' state (the (N, S) block; None: all 0), compiled
    kernel or torch reference."""
    if _backend.use_compiled(F_E.device, backend):
        block = (torch.zeros(len(F_E), 1, dtype=torch.float32, device=F_E.device) if state is None
                 else _state_block(state, len(F_E)))
        return _backend.compiled_module().elastic_energy(F_E, block, material_table, material_id)
    return elastic_energy_reference(material_table, material_id, F_E, state)
