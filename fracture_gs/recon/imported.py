"""Starting from a Gaussian model trained elsewhere (``train.py --from-ply``).

* Without masks the SDF comes from the Gaussians' opacity field inside a user-given box:
  the density ``D(x) = Σ_i o_i exp(-½ (x - μ_i)ᵀ (Σ_i + (h/2)² I)⁻¹ (x - μ_i))`` on the grid
  nodes (each kernel widened by half a voxel h, so that thin shells stay closed on the grid),
  the region ``D > 0.5`` closed morphologically and with its enclosed cavities filled (a 3DGS
  object is a shell of Gaussians), and a signed distance to that solid (Euclidean distance transforms, lightly
  smoothed so that marching cubes sees no voxel steps).
* Every surface particle is bound to its nearest Gaussian (``gaussian_index``); Gaussians that
  no particle is bound to are not drawn in simulations (:func:`unbound_warning` says so).
"""
from __future__ import annotations

import re

import numpy as np
import torch
from scipy import ndimage
from scipy.spatial import cKDTree

from fracture_gs.gaussians import GaussianModel, PlyFormatError, read_ply
from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.grid import VoxelGrid, sample_dense

DENSITY_LEVEL = 0.5
MAX_REACH_VOXELS = 4          # a Gaussian's density is evaluated within 3 sigma, at most this
SIGMA_REACH = 3.0


def opacity_density(model: GaussianModel, grid: VoxelGrid) -> torch.Tensor:
    """Density of the Gaussians at the grid nodes (nx, ny, nz), each Gaussian truncated at
    3 sigma (and at ``MAX_REACH_VOXELS`` voxels)."""
    with torch.no_grad():
        means = model.means.detach().double().cpu()
        covariances = model.covariances().detach().double().cpu()
        opacity = model.opacities.detach().double().cpu()
        lower = torch.tensor(grid.lower) - SIGMA_REACH * model.scales.max().item()
        upper = torch.tensor(grid.upper) + SIGMA_REACH * model.scales.max().item()
        near = ((means >= lower) & (means <= upper)).all(dim=1) & (opacity > 1e-3)
        means, covariances, opacity = means[near], covariances[near], opacity[near]
        # blur every kernel by half a voxel, so that a surface shell of Gaussians thinner
        # than a voxel still yields a closed band of nodes above the level
        footprint = (0.5 * grid.voxel) ** 2 * torch.eye(3, dtype=torch.float64)
        precision = torch.linalg.inv(covariances + footprint)
        sigma = model.scales.detach().double().cpu()[near].max(dim=1).values
        reach = torch.clamp(torch.ceil(SIGMA_REACH * sigma / grid.voxel), 1,
                            MAX_REACH_VOXELS).long()
        shape = torch.tensor(grid.shape)
        origin = torch.tensor(grid.origin, dtype=torch.float64)
        density = torch.zeros(grid.num_nodes, dtype=torch.float64)
        base = torch.round((means - origin) / grid.voxel).long()
        for radius in range(1, MAX_REACH_VOXELS + 1):
            members = torch.nonzero(reach == radius)[:, 0]
            if members.numel() == 0:
                continue
            span = torch.arange(-radius, radius + 1)
            offsets = torch.stack(torch.meshgrid(span, span, span, indexing="ij"), -1).reshape(-1, 3)
            for offset in offsets:
                node = base[members] + offset
                valid = ((node >= 0) & (node < shape)).all(dim=1)
                node, who = node[valid], members[valid]
                delta = origin + node.double() * grid.voxel - means[who]
                quadratic = torch.einsum("pi,pij,pj->p", delta, precision[who], delta)
                flat = (node[:, 0] * grid.shape[1] + node[:, 1]) * grid.shape[2] + node[:, 2]
                density.index_add_(0, flat, opacity[who] * torch.exp(-0.5 * quadratic))
    return density.reshape(grid.shape).float()


def opacity_field_sdf(model: GaussianModel, lower: np.ndarray, upper: np.ndarray,
                      resolution: int, source: str) -> tuple[VoxelGrid, torch.Tensor]:
    """Grid and SDF of the solid bounded by the Gaussians' opacity field in [lower, upper]."""
    grid = VoxelGrid.around(lower, upper, resolution)
    density = opacity_density(model, grid).numpy()
    occupied = density > DENSITY_LEVEL
    if not occupied.any():
        raise ReconstructionError(f"{source}: the Gaussians' opacity field never exceeds "
                                  f"{DENSITY_LEVEL} inside --bbox {list(lower)} {list(upper)}; "
                                  f"check the box (model coordinates) or give masks")
    closed = ndimage.binary_closing(occupied, iterations=1, border_value=0)
    solid = ndimage.binary_fill_holes(closed | occupied)
    outside = ndimage.distance_transform_edt(~solid)
    inside = ndimage.distance_transform_edt(solid)
    signed = np.where(solid, 0.5 - inside, outside - 0.5) * grid.voxel
    signed = torch.from_numpy(ndimage.gaussian_filter(signed, sigma=0.75).astype(np.float32))
    # The solid's boundary is the outside of the band of Gaussians; their centres lie on the
    # surface, so the level is moved to pass through them (median over the opaque ones).
    means = model.means.detach().float().cpu()
    opaque = (model.opacities.detach().cpu() > 0.5) & ((means >= torch.tensor(grid.lower).float())
                                                       & (means <= torch.tensor(grid.upper).float())
                                                       ).all(dim=1)
    if opaque.any():
        signed = signed - sample_dense(signed, grid, means[opaque]).median()
    return grid, signed


def read_imported(path: str) -> GaussianModel:
    """The Gaussians of the ``--from-ply`` file ``path``; PlyFormatError naming the file when it
    cannot be read or holds no Gaussian (a model with nothing to bind the particles to)."""
    model = read_ply(path)
    if model.num_gaussians == 0:
        raise PlyFormatError(f"{path}: the PLY holds no Gaussians (0 vertices); give the "
                             "point_cloud.ply of a trained 3DGS model")
    return model


def bind_to_nearest(particles: np.ndarray, gaussian_means: np.ndarray) -> np.ndarray:
    """Index (int64) of the nearest Gaussian of every particle."""
    _, nearest = cKDTree(gaussian_means).query(particles)
    return nearest.astype(np.int64)


def unbound_warning(gaussian_index: np.ndarray, num_gaussians: int) -> str | None:
    """The warning for imported Gaussians that no surface particle carries, or None.

    ``gaussian_index`` holds the Gaussian of every surface particle (:func:`bind_to_nearest`).
    A simulation moves and draws only the Gaussians that particles carry, so the others vanish
    from every rendered frame; the message gives their count and why they were left over."""
    bound = int(np.unique(gaussian_index).size)
    unbound = num_gaussians - bound
    if unbound <= 0:
        return None
    particles = int(gaussian_index.size)
    if particles < num_gaussians:
        reason = (f"there are only {particles} surface particles for {num_gaussians} Gaussians "
                  f"and each particle carries its nearest Gaussian; raise --n-surface to about "
                  f"{num_gaussians} to carry more of them")
    else:
        reason = ("they are the nearest Gaussian of no surface particle (Gaussians away from "
                  "the reconstructed surface, inside the object or floating around it)")
    return (f"--from-ply: {unbound} of {num_gaussians} imported Gaussians are bound to no particle "
            f"and will not be drawn in simulations: {reason}")


def iteration_of(path: str) -> int:
    """N of a ``.../iteration_N/point_cloud.ply`` path, else 0."""
    match = re.search(r"iteration_(\d+)", path.replace("\\", "/"))
    return int(match.group(1)) if match else 0
