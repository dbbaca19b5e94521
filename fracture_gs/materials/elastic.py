"""``model: elastic``: Hencky StVK elasticity, no plasticity, never fractured (unbreakable parts)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from fracture_gs import keys
from fracture_gs.materials.hencky import ELASTIC_KEYS, HenckyElasticity, energy_density_reference, \
    kirchhoff_stress_reference

MODEL_ELASTIC = 0


@dataclass(frozen=True)
class ElasticMaterial(HenckyElasticity):
    """St. Venant-Kirchhoff on the Hencky strain, no plasticity (unbreakable parts)."""

    name: ClassVar[str] = "elastic"
    yaml_keys: ClassVar[tuple[str, ...]] = ("part", "model") + ELASTIC_KEYS
    model_code: ClassVar[int] = MODEL_ELASTIC
    parameter_columns: ClassVar[tuple[str, ...]] = ()
    alpha0: ClassVar[float] = 0.0                 # the state is carried but never changes
    alpha_threshold: ClassVar[float] = math.inf   # never flagged as fractured

    def __post_init__(self) -> None:
        self._validate_elasticity()

    @classmethod
    def from_yaml(cls, data: Any, path: str) -> "ElasticMaterial":
        """The material of a scene's material mapping (``part`` and ``model`` are the scene's)."""
        keys.check_keys(data, path, cls.yaml_keys, required=ELASTIC_KEYS)
        return cls(**cls.elasticity_from_yaml(data, path))

    def to_yaml(self) -> dict[str, Any]:
        """The resolved keys (``model`` included)."""
        return {"model": self.name, "E": self.E, "nu": self.nu, "density": self.density}

    def partition_threshold(self, damage_dilation: float) -> float:
        """State from which the fragment partition treats a particle as damaged: never."""
        return math.inf

    def pack(self, cell_size: float | None = None) -> list[float]:
        """One row of the material table (``fracture_gs.materials.table.TABLE_COLUMNS``)."""
        return self.elastic_row(MODEL_ELASTIC) + [0.0, 0.0, 0.0, self.alpha_threshold]

    def return_map(self, F_trial: torch.Tensor, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """No plasticity: (F_E, α) = (F_trial, α) (copies)."""
        return F_trial.clone(), alpha.clone()

    @staticmethod
    def update_rows(F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor, strength: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: (F_E, state, τ)."""
        return F_trial.clone(), state.clone(), kirchhoff_stress_reference(F_trial, rows[:, 1], rows[:, 2])

    @staticmethod
    def energy_rows(F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density ψ for particles of this model."""
        return energy_density_reference(F_E, rows[:, 1], rows[:, 2])
