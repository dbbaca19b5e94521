"""What every material model class provides (the registry of models: :mod:`fracture_gs.materials`).

A model is one class (its YAML keys and their validation, its table row, its per-particle state,
the torch twin of its law and energy) and one C++ header in ``csrc/common/materials/`` (its law,
shared by the CPU and CUDA kernels). The class's ``name``, ``code``, ``parameter_columns`` and
``state_fields`` are those of the header (``tests/test_material_registry.py`` checks it against
the compiled extension's ``material_models()``).

The particle state is one float32 block ``(N, S)``, S the largest ``len(state_fields)`` among the
scene's models: a particle's model owns the first ``len(state_fields)`` columns of its row, the
rest stay 0. Field 0 is the one the fracture threshold applies to (the ``fractured`` flag), the
fragment partition's threshold, and the frames' ``alpha``. The solver moves the block as a whole
(re-sorting, checkpoints, the kernels) and reads fields only through the hooks below.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from fracture_gs.materials.hencky import HenckyElasticity

# Columns of a material-table row (csrc/common/material_law.h, MatField): model code, Lamé μ and λ,
# bulk modulus K, the model's parameters, the fracture threshold on state field 0.
BASE_COLUMNS = ("model", "mu", "lambda", "bulk")
PARAMETER_SLOTS = 3
THRESHOLD_COLUMN = "fracture_threshold"
TABLE_WIDTH = len(BASE_COLUMNS) + PARAMETER_SLOTS + 1
FIRST_PARAMETER = len(BASE_COLUMNS)


@dataclass
class SubstepView:
    """What a model's :meth:`MaterialModel.after_substep` may look at and change, in the solver's
    current particle order: ``state_old`` / ``state`` (the block before and after the substep;
    ``state`` may be changed in place), ``F_E`` and ``C`` after the substep, its length ``dt``,
    ``mine`` (bool (N,): the particles of this model), ``cache``, a dict the model may keep
    between substeps (the solver empties it when it re-sorts the particles), and ``backend``, the
    solver's choice of compiled kernels or torch twins (``_backend.use_compiled``)."""

    state_old: torch.Tensor
    state: torch.Tensor
    F_E: torch.Tensor
    C: torch.Tensor
    dt: float
    mine: torch.Tensor
    cache: dict[str, Any]
    backend: str = "auto"


@dataclass(frozen=True)
class MaterialModel(HenckyElasticity):
    """Base of the material classes: Hencky elasticity plus the model's description and hooks."""

    name: ClassVar[str]                       # the YAML ``model`` value
    code: ClassVar[int]                       # the table's model column (the C++ kCode)
    yaml_keys: ClassVar[tuple[str, ...]]      # the keys of its scene mapping
    parameter_columns: ClassVar[tuple[str, ...]] = ("", "", "")   # its parameter columns ("" unused)
    state_fields: ClassVar[tuple[str, ...]] = ("alpha",)          # its per-particle state
    frame_fields: ClassVar[tuple[str, ...]] = ()   # state fields every frame holds under their name
    split_direction: ClassVar[str | None] = None   # first of 3 state fields holding a split direction
    dissipates: ClassVar[bool] = False             # its update may dissipate energy (update_rows' last output)

    # ------------------------------------------------------------------ the table row
    def parameters(self, cell_size: float | None) -> tuple[float, ...]:
        """Values of ``parameter_columns`` (0 for unused ones); ``cell_size``: the grid's dx."""
        return (0.0,) * PARAMETER_SLOTS

    @property
    def fracture_threshold(self) -> float:
        """State field 0 from which a particle counts as fractured (the flag latches; inf: never)."""
        return math.inf

    def pack(self, cell_size: float | None = None) -> list[float]:
        """One row of the material table (``fracture_gs.materials.table.TABLE_COLUMNS``)."""
        values = list(self.parameters(cell_size))
        if len(values) != PARAMETER_SLOTS:
            raise ValueError(f"{type(self).__name__}.parameters gives {len(values)} values, not {PARAMETER_SLOTS}")
        return self.elastic_row(self.code) + values + [self.fracture_threshold]

    # ------------------------------------------------------------------ the state
    def initial_state(self, index: np.ndarray, rest_volume: np.ndarray, seed: int) -> np.ndarray:
        """(n, len(state_fields)) float64: the state the particles with these indices (their rows in
        the scene) and rest volumes start with; ``seed`` is the scene's."""
        return np.zeros((len(index), len(self.state_fields)), dtype=np.float64)

    def partition_threshold(self, damage_dilation: float) -> float:
        """State field 0 from which the fragment partition treats a particle as damaged (inf: never);
        ``damage_dilation``: the scene's ``contact.damage_dilation``."""
        return math.inf

    @property
    def piece_threshold(self) -> float:
        """State field 0 from which a particle is a piece of its own when pieces are counted
        (inf: never)."""
        return math.inf

    @classmethod
    def after_substep(cls, view: SubstepView) -> None:
        """Called after every substep when the scene has particles of this model (nothing by default)."""

    # ------------------------------------------------------------------ the torch twins
    @staticmethod
    def update_rows(F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: (F_trial (n,3,3), state (n,S),
        table rows (n,8)) -> (F_E, new state (n,S), τ, energy per unit rest volume the update took (n,))."""
        raise NotImplementedError

    @staticmethod
    def energy_rows(F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density ψ for particles of this model, (n,)."""
        raise NotImplementedError


def parameter(rows: torch.Tensor, cls: type[MaterialModel], name: str) -> torch.Tensor:
    """Column ``name`` of ``cls``'s parameters in table rows (n, 8)."""
    return rows[:, FIRST_PARAMETER + cls.parameter_columns.index(name)]


def field(state: torch.Tensor, cls: type[MaterialModel], name: str) -> torch.Tensor:
    """State field ``name`` of ``cls`` in a state block (n, S) (a view)."""
    return state[:, cls.state_fields.index(name)]
