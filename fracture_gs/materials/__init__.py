"""Constitutive models of the MPM solver, one class per model, and their PyTorch twins.

Every model shares St. Venant-Kirchhoff elasticity on the Hencky strain
(:mod:`fracture_gs.materials.hencky`):

* :class:`ElasticMaterial` (``model: elastic``) - no plasticity, unbreakable parts;
* :class:`NACCMaterial` (``model: nacc``) - non-associated Cam-clay plasticity (Wolper et al. 2019):
  dough, clay, sand, crumbling soil;
* :class:`BrittleMaterial` (``model: brittle``) - Rankine damage with crack-band softening and
  Weibull strength: porcelain, glass, ceramic, stone.

A material class is the one home of its model: its YAML keys and their validation
(``from_yaml`` / ``to_yaml``), its row of the kernels' material table (``pack``), its torch twin
(``update_rows``, ``energy_rows``) and its thresholds. The compiled kernels are
``csrc/common/constitutive.h`` and ``csrc/common/hencky_eig.h``; :mod:`fracture_gs.materials.table`
builds the table and dispatches the twins. :mod:`fracture_gs.materials.presets` reads the named
presets of ``configs/materials/`` (``preset: porcelain``).
"""
from fracture_gs.materials.brittle import BrittleMaterial, particle_strengths
from fracture_gs.materials.elastic import ElasticMaterial
from fracture_gs.materials.hencky import (MIN_SINGULAR_VALUE, compose, energy_density_reference, hencky_strain,
                                          kirchhoff_stress_reference, lame_parameters, proper_svd)
from fracture_gs.materials.nacc import (P0_FLOOR, YIELD_TOLERANCE, NACCMaterial, ReturnMapResult,
                                        friction_angle_to_M, nacc_return_map_strain, nacc_update_reference)
from fracture_gs.materials.table import (COLUMN, MATERIAL_CLASSES, MODEL_BRITTLE, MODEL_ELASTIC, MODEL_NACC,
                                         TABLE_COLUMNS, Material, MaterialTable, constitutive_update,
                                         constitutive_update_reference, elastic_energy, elastic_energy_reference,
                                         material_from_yaml)

__all__ = ["BrittleMaterial", "COLUMN", "ElasticMaterial", "MATERIAL_CLASSES", "MIN_SINGULAR_VALUE",
           "MODEL_BRITTLE", "MODEL_ELASTIC", "MODEL_NACC", "Material", "MaterialTable", "NACCMaterial", "P0_FLOOR",
           "ReturnMapResult", "TABLE_COLUMNS", "YIELD_TOLERANCE", "compose", "constitutive_update",
           "constitutive_update_reference", "elastic_energy", "elastic_energy_reference", "energy_density_reference",
           "friction_angle_to_M", "hencky_strain", "kirchhoff_stress_reference", "lame_parameters",
           "material_from_yaml", "nacc_return_map_strain", "nacc_update_reference", "particle_strengths",
           "proper_svd"]
