"""Simulation particles of a reconstructed object (docs/formulas.md §15, paper App. A.2).

* Surface particles: a maximal Poisson-disk set on the mesh. Many area-weighted candidate
  points get random priorities; a candidate is kept iff no kept candidate of higher priority
  lies within the disk radius r (the greedy dart-throwing result, computed in parallel rounds
  over the candidate pairs, Luby-style). r is bisected until the set holds at least the
  requested count, and the surplus points with the closest neighbours are dropped.
* Interior particles: ``nv`` uniform random samples in every voxel of a particle lattice
  whose centre has SDF < 0 (samples that fall outside the surface are discarded).
* Rest volume: each lattice voxel's occupied volume (its inside fraction, from 4^3
  sub-samples of the SDF, times the voxel volume, at least half a sub-sample where particles
  are) is shared equally by the particles in it; a voxel without particles gives its volume
  to the nearest particle. The volumes are then
  scaled so that their sum equals the mesh volume exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from fracture_gs.recon.grid import VoxelGrid, sample_dense

CANDIDATES_PER_PARTICLE = 6
PACKING = 0.70        # N ≈ PACKING · area / r², a maximal Poisson-disk set's density
SUBSAMPLES = 4        # per axis, for the inside fraction of boundary voxels


@dataclass
class ParticleSet:
    """Particles in the model frame; surface particles come first."""

    position: np.ndarray      # (N, 3) float64
    volume: np.ndarray        # (N,) float64
    is_surface: np.ndarray    # (N,) bool
    normal: np.ndarray        # (N, 3) outward normals (zero for interior particles)
    surface_spacing: float    # Poisson-disk radius of the surface particles
    interior_voxel: float     # edge of the interior sampling voxels

    @property
    def num_surface(self) -> int:
        return int(self.is_surface.sum())

    @property
    def num_interior(self) -> int:
        return int((~self.is_surface).sum())


def maximal_poisson_disk(points: np.ndarray, radius: float, priority: np.ndarray) -> np.ndarray:
    """Indices of the greedy Poisson-disk subset of ``points`` in decreasing ``priority``: a
    point is kept iff no kept point of higher priority lies within ``radius``."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    state = np.zeros(len(points), dtype=np.int8)   # 0 undecided, 1 kept, -1 removed
    if len(pairs) == 0:
        return np.arange(len(points))
    first, second = pairs[:, 0], pairs[:, 1]
    while True:
        undecided = state == 0
        if not undecided.any():
            break
        live = undecided[first] & undecided[second]
        a, b = first[live], second[live]
        beaten = np.zeros(len(points), dtype=bool)
        a_wins = priority[a] > priority[b]
        beaten[b[a_wins]] = True
        beaten[a[~a_wins]] = True
        winners = undecided & ~beaten
        state[winners] = 1
        kept_first = winners[first] & (state[second] == 0)
        kept_second = winners[second] & (state[first] == 0)
        state[second[kept_first]] = -1
        state[first[kept_second]] = -1
    return np.nonzero(state == 1)[0]


def sample_surface_even(mesh: trimesh.Trimesh, count: int,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """``count`` evenly spread points on ``mesh`` with their face normals, and the disk
    radius used."""
    if count < 1:
        raise ValueError(f"surface particle count must be >= 1, got {count}")
    candidates_count = max(CANDIDATES_PER_PARTICLE * count, 64)
    candidates, faces = trimesh.sample.sample_surface(mesh, candidates_count,
                                                      seed=int(rng.integers(2**31)))
    normals = mesh.face_normals[faces]
    priority = rng.random(len(candidates))
    radius = float(np.sqrt(PACKING * mesh.area / count))
    kept = maximal_poisson_disk(candidates, radius, priority)
    low, high = 0.0, radius
    for _ in range(8):  # shrink r until the set is large enough, then bisect a few times
        if len(kept) >= count:
            break
        high, radius = radius, radius * 0.85
        kept = maximal_poisson_disk(candidates, radius, priority)
    low = radius
    best = kept
    for _ in range(5):
        if len(best) <= count * 1.02:
            break
        trial_radius = 0.5 * (low + high)
        trial = maximal_poisson_disk(candidates, trial_radius, priority)
        if len(trial) >= count:
            low, best = trial_radius, trial
        else:
            high = trial_radius
    radius = low
    if len(best) < count:  # too few candidates for the request: take them all
        best = np.argsort(-priority)[:count]
    elif len(best) > count:
        spacing, _ = cKDTree(candidates[best]).query(candidates[best], k=2)
        best = best[np.argsort(spacing[:, 1])[len(best) - count:]]
    return candidates[best], normals[best], radius


def particle_lattice(mesh: trimesh.Trimesh, resolution: int) -> VoxelGrid:
    """Voxel lattice for the interior samples: ``resolution`` voxels along the longest side of
    the mesh's bounding box; voxel centres are the lattice nodes."""
    lower, upper = mesh.bounds
    grid = VoxelGrid.around(lower, upper, resolution)
    return VoxelGrid(tuple(np.asarray(grid.origin) - grid.voxel), grid.voxel,
                     tuple(n + 2 for n in grid.shape))


def _inside(values: torch.Tensor | np.ndarray, shell: float):
    """Inside the solid: SDF < 0, and deeper than ``-shell`` when ``shell`` > 0 (a hollow body
    whose wall is ``shell`` thick)."""
    inside = values < 0
    return inside & (values > -shell) if shell > 0 else inside


def _inside_fraction(sdf: torch.Tensor, sdf_grid: VoxelGrid, centres: np.ndarray,
                     voxel: float, shell: float = 0.0) -> np.ndarray:
    """Fraction of each voxel (given by its centre) inside the solid (:func:`_inside`)."""
    offsets = (np.arange(SUBSAMPLES) + 0.5) / SUBSAMPLES - 0.5
    sub = np.stack(np.meshgrid(offsets, offsets, offsets, indexing="ij"), -1).reshape(-1, 3)
    fractions = np.empty(len(centres))
    chunk = 1 << 15
    for start in range(0, len(centres), chunk):
        points = (centres[start:start + chunk, None, :] + voxel * sub[None]).reshape(-1, 3)
        values = sample_dense(sdf, sdf_grid, torch.from_numpy(points).float().to(sdf.device))
        fractions[start:start + chunk] = _inside(values.reshape(-1, len(sub)), shell).float().mean(1).cpu().numpy()
    return fractions


def sample_particles(mesh: trimesh.Trimesh, sdf: torch.Tensor, sdf_grid: VoxelGrid,
                     n_surface: int, nv: int, particle_resolution: int,
                     rng: np.random.Generator, shell: float = 0.0) -> ParticleSet:
    """Surface + interior particles with rest volumes summing to the solid's volume: the mesh's,
    or with ``shell`` > 0 (model units) a hollow body's whose wall is ``shell`` thick (interior
    particles only where -shell < SDF < 0)."""
    surface, normals, spacing = sample_surface_even(mesh, n_surface, rng)
    lattice = particle_lattice(mesh, particle_resolution)
    centres = lattice.node_positions().reshape(-1, 3).double().numpy()
    centre_sdf = sample_dense(sdf, sdf_grid, torch.from_numpy(centres).float().to(sdf.device))
    centre_sdf = centre_sdf.cpu().numpy().astype(np.float64)
    half_diagonal = 0.5 * np.sqrt(3.0) * lattice.voxel
    occupied = _inside(centre_sdf, shell).astype(np.float64)
    boundary = np.abs(centre_sdf) < half_diagonal + sdf_grid.voxel
    if shell > 0:
        boundary |= np.abs(centre_sdf + shell) < half_diagonal + sdf_grid.voxel
    occupied[boundary] = _inside_fraction(sdf, sdf_grid, centres[boundary], lattice.voxel, shell)
    interior_voxels = np.nonzero(_inside(centre_sdf, shell))[0]
    if nv > 0 and len(interior_voxels):
        jitter = rng.random((len(interior_voxels), nv, 3)) - 0.5
        interior = (centres[interior_voxels, None, :] + lattice.voxel * jitter).reshape(-1, 3)
        values = sample_dense(sdf, sdf_grid, torch.from_numpy(interior).float().to(sdf.device))
        interior = interior[_inside(values.cpu().numpy(), shell)]
    else:
        interior = np.zeros((0, 3))
    position = np.concatenate([surface, interior])
    volume = distribute_volume(position, lattice, occupied * lattice.voxel ** 3)
    solid_volume = mesh.volume if shell <= 0 else float(occupied.sum()) * lattice.voxel ** 3
    volume *= solid_volume / volume.sum()
    is_surface = np.zeros(len(position), dtype=bool)
    is_surface[:len(surface)] = True
    all_normals = np.concatenate([normals, np.zeros_like(interior)])
    return ParticleSet(position, volume, is_surface, all_normals, spacing, lattice.voxel)


def distribute_volume(position: np.ndarray, lattice: VoxelGrid,
                      voxel_volume: np.ndarray) -> np.ndarray:
    """Share each voxel's volume equally among the particles in it; voxels without particles
    give theirs to the nearest particle."""
    shape = np.asarray(lattice.shape)
    index3 = np.rint((position - np.asarray(lattice.origin)) / lattice.voxel).astype(np.int64)
    index3 = np.clip(index3, 0, shape - 1)
    flat = (index3[:, 0] * shape[1] + index3[:, 1]) * shape[2] + index3[:, 2]
    per_voxel = np.bincount(flat, minlength=lattice.num_nodes)
    # a particle on the surface may sit in a voxel whose measured inside fraction is zero:
    # such a voxel still holds half a sub-sample of material, so no particle gets volume 0
    floor = 0.5 / SUBSAMPLES ** 3 * lattice.voxel ** 3
    voxel_volume = np.where(per_voxel > 0, np.maximum(voxel_volume, floor), voxel_volume)
    volume = voxel_volume[flat] / per_voxel[flat]
    orphans = np.nonzero((voxel_volume > 0) & (per_voxel == 0))[0]
    if len(orphans):
        centres = lattice.node_positions().reshape(-1, 3).double().numpy()[orphans]
        _, nearest = cKDTree(position).query(centres)
        volume += np.bincount(nearest, weights=voxel_volume[orphans], minlength=len(position))
    return volume
