"""The kernels' material table, the twins of the compiled material ops, and the model registry.

The compiled kernels (``csrc/common/constitutive.h``) read a float32 table, one row of 8 numbers
per material (``TABLE_COLUMNS``): model code, μ, λ, K, three parameters of the model (NACC: β, ξ,
M; brittle: strength, crack band 2 E G_f / h, residual) and the fracture threshold on the state.
:class:`MaterialTable` builds it; :func:`constitutive_update_reference` and
:func:`elastic_energy_reference` are the vectorised torch twins of ``_C.constitutive_update`` and
``_C.elastic_energy`` (mixed materials handled with one mask per model).
"""
from __future__ import annotations

import math
from typing import Any, Iterable, Sequence, Union

import torch

from fracture_gs import _backend, keys
from fracture_gs.materials.brittle import MODEL_BRITTLE, BrittleMaterial
from fracture_gs.materials.elastic import MODEL_ELASTIC, ElasticMaterial
from fracture_gs.materials.nacc import MODEL_NACC, NACCMaterial
from fracture_gs.materials import presets

Material = Union[ElasticMaterial, NACCMaterial, BrittleMaterial]
# The models by YAML name, in the order of their codes.
MATERIAL_CLASSES: dict[str, type] = {cls.name: cls for cls in (ElasticMaterial, NACCMaterial, BrittleMaterial)}
TABLE_COLUMNS = ("model", "mu", "lambda", "bulk", "parameter_1", "parameter_2", "parameter_3", "fracture_threshold")
# Column of every name, the models' own parameter names included (NACC beta, xi, M; brittle strength,
# crack_band, residual).
COLUMN = {name: index for index, name in enumerate(TABLE_COLUMNS)}
for _cls in MATERIAL_CLASSES.values():
    COLUMN.update({name: 4 + i for i, name in enumerate(_cls.parameter_columns)})

__all__ = ["COLUMN", "MATERIAL_CLASSES", "MODEL_BRITTLE", "MODEL_ELASTIC", "MODEL_NACC", "Material",
           "MaterialTable", "TABLE_COLUMNS", "constitutive_update", "constitutive_update_reference",
           "elastic_energy", "elastic_energy_reference", "material_from_yaml"]


def material_from_yaml(data: Any, path: str) -> Material:
    """The material of one scene material mapping (its ``model`` picks the class; key-path errors)."""
    data = presets.expand(keys.mapping(data, path), path)
    model = keys.choice(data, "model", path, tuple(MATERIAL_CLASSES))
    own = set(MATERIAL_CLASSES[model].yaml_keys)
    for key in data:
        owners = [name for name, cls in MATERIAL_CLASSES.items() if key in cls.yaml_keys and key not in own]
        if owners:
            raise keys.SceneError(f"{path}.{key}", f"unknown key for model {model} (a key of model {' / '.join(owners)})")
    return MATERIAL_CLASSES[model].from_yaml(data, path)


class MaterialTable:
    """The materials of a scene in table order; row i is material_id i. ``cell_size``: the grid's dx
    (the brittle crack band needs it)."""

    def __init__(self, materials: Sequence[Material], cell_size: float | None = None) -> None:
        if len(materials) == 0:
            raise ValueError("MaterialTable: materials is empty")
        for index, material in enumerate(materials):
            if not isinstance(material, tuple(MATERIAL_CLASSES.values())):
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

    def initial_alpha(self, material_id: torch.Tensor) -> torch.Tensor:
        """Initial state of every particle (NACC: α0, brittle: damage 0), float32 on material_id's device."""
        state0 = torch.tensor([m.initial_state for m in self.materials], dtype=torch.float32,
                              device=material_id.device)
        return state0[material_id.long()]

    def partition_thresholds(self, damage_dilation: float, device: torch.device | str | None = None
                             ) -> torch.Tensor:
        """(M,) float32: the state from which the fragment partition treats a particle of each material
        as damaged (inf: never)."""
        return torch.tensor([m.partition_threshold(damage_dilation) for m in self.materials],
                            dtype=torch.float32, device=device)

    def is_brittle(self, device: torch.device | str | None = None) -> torch.Tensor:
        """(M,) bool: which materials are brittle (their state is a damage)."""
        return torch.tensor([isinstance(m, BrittleMaterial) for m in self.materials], device=device)


TableLike = Union[torch.Tensor, MaterialTable, Iterable[Material]]


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


def constitutive_update_reference(material_table_or_materials: TableLike, material_id: torch.Tensor,
                                  F_trial: torch.Tensor, alpha: torch.Tensor, strength: torch.Tensor | None = None
                                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Torch twin of ``_C.constitutive_update``: (F_E, state', τ) for mixed materials.

    ``strength``: per-particle tensile strength of brittle particles (None: the table's). Computes
    in F_trial's dtype (pass float64 for a reference of the float32 kernels). Rows with an unknown
    model code give NaN, like the compiled kernels.
    """
    table = _table_tensor(material_table_or_materials, F_trial)
    rows = _rows_per_particle(table, material_id)
    alpha = alpha.to(F_trial.dtype)
    strength_rows = rows[:, COLUMN["strength"]] if strength is None else strength.to(F_trial.dtype)
    model = rows[:, COLUMN["model"]]
    F_E = F_trial.clone()
    alpha_new = alpha.clone()
    tau = torch.full_like(F_trial, math.nan)
    known = torch.zeros_like(model, dtype=torch.bool)
    for cls in MATERIAL_CLASSES.values():
        mask = model == cls.model_code
        known |= mask
        if bool(mask.any()):
            F_E[mask], alpha_new[mask], tau[mask] = cls.update_rows(F_trial[mask], alpha[mask], rows[mask],
                                                                    strength_rows[mask])
    # Like the kernels: unknown models and non-finite inputs give NaN, never a finite projection.
    unknown = ~known | ~torch.isfinite(F_trial).flatten(1).all(1) | ~torch.isfinite(alpha)
    tau[unknown] = math.nan
    F_E[unknown] = math.nan
    alpha_new[unknown] = math.nan
    return F_E, alpha_new, tau


def elastic_energy_reference(material_table_or_materials: TableLike, material_id: torch.Tensor,
                             F_E: torch.Tensor, alpha: torch.Tensor | None = None) -> torch.Tensor:
    """Torch twin of ``_C.elastic_energy``: ψ(F_E) per unit rest volume, (N,); ``alpha`` is the state
    (the brittle damage degrades the tensile part; None: 0)."""
    table = _table_tensor(material_table_or_materials, F_E)
    rows = _rows_per_particle(table, material_id)
    state = torch.zeros(len(F_E), dtype=F_E.dtype, device=F_E.device) if alpha is None else alpha.to(F_E.dtype)
    model = rows[:, COLUMN["model"]]
    psi = torch.full((len(F_E),), math.nan, dtype=F_E.dtype, device=F_E.device)
    for cls in MATERIAL_CLASSES.values():
        mask = model == cls.model_code
        if bool(mask.any()):
            psi[mask] = cls.energy_rows(F_E[mask], state[mask], rows[mask])
    return psi


def constitutive_update(F_trial: torch.Tensor, alpha: torch.Tensor, material_table: torch.Tensor,
                        material_id: torch.Tensor, backend: str = "auto", strength: torch.Tensor | None = None
                        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(F_E, state', τ) per particle, compiled kernel or torch reference (``_backend.use_compiled``)."""
    if _backend.use_compiled(F_trial.device, backend):
        return _backend.compiled_module().constitutive_update(F_trial, alpha, material_table, material_id,
                                                              strength)
    F_E, alpha_new, tau = constitutive_update_reference(material_table, material_id, F_trial, alpha, strength)
    return F_E, alpha_new.to(alpha.dtype), tau


def elastic_energy(F_E: torch.Tensor, material_table: torch.Tensor, material_id: torch.Tensor,
                   backend: str = "auto", alpha: torch.Tensor | None = None) -> torch.Tensor:
    """ψ(F_E) per unit rest volume (``alpha``: the particle state, None: 0), compiled kernel or torch
    reference."""
    if _backend.use_compiled(F_E.device, backend):
        state = torch.zeros(len(F_E), dtype=torch.float32, device=F_E.device) if alpha is None else alpha
        return _backend.compiled_module().elastic_energy(F_E, state, material_table, material_id)
    return elastic_energy_reference(material_table, material_id, F_E, alpha)
