"""The material models of the MPM solver, one class per model, and their registry.

Every model shares St. Venant-Kirchhoff elasticity on the Hencky strain
(:mod:`fracture_gs.materials.hencky`) and the interface of :class:`MaterialModel`
(:mod:`fracture_gs.materials.model`): its YAML keys and their validation (``from_yaml`` /
``to_yaml``), its row of the kernels' material table (``pack``), its per-particle state, the torch
twin of its law (``update_rows``, ``energy_rows``) and its thresholds. Its law for the compiled
kernels is one header in ``csrc/common/materials/``.

``MODELS`` lists the models (each class's docstring says what it is for; docs/materials.md
describes them for users).

:mod:`fracture_gs.materials.table` builds the table and the state block and dispatches the twins;
:mod:`fracture_gs.materials.presets` reads the named presets of ``configs/materials/``
(``preset: porcelain``).
"""
from fracture_gs.materials.hencky import (MIN_SINGULAR_VALUE, compose, energy_density_reference, hencky_strain,
                                          kirchhoff_stress_reference, lame_parameters, proper_svd)
from fracture_gs.materials.model import MaterialModel, SubstepView
from fracture_gs.materials.elastic import ElasticMaterial
from fracture_gs.materials.nacc import (P0_FLOOR, YIELD_TOLERANCE, NACCMaterial, ReturnMapResult,
                                        friction_angle_to_M, nacc_return_map_strain, nacc_update_reference)
from fracture_gs.materials.brittle import BrittleMaterial
from fracture_gs.materials.von_mises import VonMisesMaterial

# The models in the order of their codes (csrc/common/material_registry.h lists the same). Adding a
# model: its class (a MaterialModel), its header, and one line here and there.
MODELS: tuple[type[MaterialModel], ...] = (
    ElasticMaterial,
    NACCMaterial,
    BrittleMaterial,
    VonMisesMaterial,
)

from fracture_gs.materials.table import (COLUMN, TABLE_COLUMNS, MaterialTable,  # noqa: E402 (reads MODELS)
                                         constitutive_update, constitutive_update_reference, elastic_energy,
                                         elastic_energy_reference, frame_field_names, material_from_yaml,
                                         model_by_code, model_by_name, model_columns)

Material = MaterialModel

__all__ = ["COLUMN", "MIN_SINGULAR_VALUE", "MODELS", "Material", "MaterialModel", "MaterialTable", "P0_FLOOR",
           "ReturnMapResult", "SubstepView", "TABLE_COLUMNS", "YIELD_TOLERANCE", "compose", "constitutive_update",
           "constitutive_update_reference", "elastic_energy", "elastic_energy_reference", "energy_density_reference",
           "frame_field_names", "friction_angle_to_M", "hencky_strain", "kirchhoff_stress_reference",
           "lame_parameters", "material_from_yaml", "model_by_code", "model_by_name", "model_columns",
           "nacc_return_map_strain", "nacc_update_reference", "proper_svd"] + [cls.__name__ for cls in MODELS]
