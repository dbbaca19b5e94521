"""Fracture-aware rendering: FPGO (paper §3.2.2, docs/formulas.md §13) and the spatial ops it runs on.

``connected_components(x, radius)`` (fragment labels) and ``knn_within`` are general-purpose
ops on a uniform hash grid; ``lens_ellipsoids`` is the MVEE of App. A.4; ``apply_fpgo`` turns a
frame's Gaussians into the ones to draw.
"""
from fracture_gs.fracture.fpgo import FPGOSettings, FPGOStats, FractureParticles, apply_fpgo
from fracture_gs.fracture.ops import LensEllipsoids, deform_gaussians, lens_ellipsoids
from fracture_gs.fracture.spatial import (component_roots, connected_components, k_nearest,
                                          knn_within, small_component_mask)

__all__ = ["FPGOSettings", "FPGOStats", "FractureParticles", "LensEllipsoids", "apply_fpgo",
           "component_roots", "connected_components", "deform_gaussians", "k_nearest",
           "knn_within", "lens_ellipsoids", "small_component_mask"]
