"""``model: elastic``: Hencky StVK elasticity, no plasticity, never fractured (unbreakable parts).
The kernels' law: ``csrc/common/materials/elastic.h``."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from fracture_gs import keys
from fracture_gs.materials.hencky import ELASTIC_KEYS, energy_density_reference, kirchhoff_stress_reference
from fracture_gs.materials.model import MaterialModel


@dataclass(frozen=True)
class ElasticMaterial(MaterialModel):
    """St. Venant-Kirchhoff on the Hencky strain, no plasticity (unbreakable parts). Its state field
    is carried and never changes."""

    name: ClassVar[str] = "elastic"
    code: ClassVar[int] = 0
    yaml_keys: ClassVar[tuple[str, ...]] = ("part", "model") + ELASTIC_KEYS
    state_fields: ClassVar[tuple[str, ...]] = ("alpha",)

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

    def return_map(self, F_trial: torch.Tensor, alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """No plasticity: (F_E, α) = (F_trial, α) (copies)."""
        return F_trial.clone(), alpha.clone()

    @staticmethod
    def update_rows(F_trial: torch.Tensor, state: torch.Tensor, rows: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Torch twin of the kernels' update for particles of this model: F and the state unchanged."""
        tau = kirchhoff_stress_reference(F_trial, rows[:, 1], rows[:, 2])
        return F_trial.clone(), state.clone(), tau, torch.zeros(len(F_trial), dtype=F_trial.dtype, device=F_trial.device)

    @staticmethod
    def energy_rows(F_E: torch.Tensor, state: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """Torch twin of the kernels' energy density ψ for particles of this model."""
        return energy_density_reference(F_E, rows[:, 1], rows[:, 2])
