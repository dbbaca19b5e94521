"""Quality measures of a reconstruction against ground truth (used by the acceptance script
and the tests): Chamfer distance, particle spacing statistics, part agreement.

Chamfer distance, as reported everywhere in this project:
``CD(A, B) = ½ (mean_{a ∈ S_A} d(a, B) + mean_{b ∈ S_B} d(b, A))`` where ``S_A`` and ``S_B``
are ``samples`` (200,000) points drawn uniformly by area on each mesh's surface and
``d(p, M)`` is the distance from p to the nearest of ``10 x samples`` points drawn the same
way on M (a dense stand-in for M's surface: the sampling floor this leaves is about half the
dense spacing, ~0.04 % of the diagonal for the generated objects). It is quoted as a
percentage of the ground-truth bounding-box diagonal.
"""
from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from fracture_gs.data.parts import PartSpec, assign_part_ids

CHAMFER_SAMPLES = 200_000
DENSE_FACTOR = 10


def surface_samples(mesh: trimesh.Trimesh, count: int, seed: int = 0) -> np.ndarray:
    """``count`` points uniformly distributed by area on ``mesh`` (reproducible)."""
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points)


def chamfer_distance(mesh: trimesh.Trimesh, reference: trimesh.Trimesh,
                     samples: int = CHAMFER_SAMPLES, seed: int = 0) -> dict[str, float]:
    """Symmetric Chamfer distance (module docstring) and its two one-sided halves:
    ``accuracy`` (mesh → reference) and ``completeness`` (reference → mesh)."""
    ours = surface_samples(mesh, samples, seed)
    theirs = surface_samples(reference, samples, seed + 1)
    ours_dense = surface_samples(mesh, DENSE_FACTOR * samples, seed + 2)
    theirs_dense = surface_samples(reference, DENSE_FACTOR * samples, seed + 3)
    accuracy = float(cKDTree(theirs_dense).query(ours)[0].mean())
    completeness = float(cKDTree(ours_dense).query(theirs)[0].mean())
    diagonal = float(np.linalg.norm(reference.bounds[1] - reference.bounds[0]))
    chamfer = 0.5 * (accuracy + completeness)
    return {"chamfer": chamfer, "accuracy": accuracy, "completeness": completeness,
            "diagonal": diagonal, "chamfer_percent": 100.0 * chamfer / diagonal}


def nearest_neighbour_spacing(points: np.ndarray) -> np.ndarray:
    """Distance of every point to its nearest other point."""
    distances, _ = cKDTree(points).query(points, k=2)
    return distances[:, 1]


def spacing_variation(points: np.ndarray) -> float:
    """Coefficient of variation (std / mean) of the nearest-neighbour spacing."""
    spacing = nearest_neighbour_spacing(points)
    return float(spacing.std() / spacing.mean())


def part_agreement(points: np.ndarray, part_id: np.ndarray, reference: trimesh.Trimesh,
                   spec: PartSpec) -> float:
    """Fraction of particles whose ``part_id`` equals the part (by ``spec``) of the nearest
    point of the ground-truth surface."""
    samples = surface_samples(reference, CHAMFER_SAMPLES, seed=7)
    reference_parts = assign_part_ids(samples, spec)
    _, nearest = cKDTree(samples).query(points)
    return float(np.mean(reference_parts[nearest] == part_id))
