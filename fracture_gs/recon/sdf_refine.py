"""Photometric refinement of the grid SDF by NeuS-style volume rendering (docs/training.md).

The SDF lives on the nodes of a :class:`VoxelGrid`; a point's value is the trilinear
interpolant. Only the nodes inside the visual hull plus a margin of ``band_voxels`` are
optimised (the "band"): the object lies inside its visual hull, so the nodes outside are
fixed at the margin (a truncated SDF). A ray is rendered with the unbiased NeuS opacity
(Wang et al. 2021) computed from consecutive SDF samples,

    alpha_i = max(0, (Phi_s(f_i) - Phi_s(f_{i+1})) / Phi_s(f_i)),   Phi_s(x) = sigmoid(s x),

with weights w_i = alpha_i prod_{j<i} (1 - alpha_j). The colour field is image-based (as in
multi-view stereo and Geo-NeuS) rather than learned: a sample point x is projected into the
K training views nearest to the ray's view and read there. Rays come in patches of
``patch`` x ``patch`` pixels; the photometric term is 1 - NCC between the reference patch
and the patch that each neighbour view sees at the rendered (weight-averaged) surface, the
best half of the neighbours counting (robust to occlusion and highlights) and each patch
weighted by its contrast (texture-less patches carry no depth cue). It is small only where
the rays meet the surface that the other views see; no colour has to be learned first, so
the refinement converges within the few hundred ray batches a CPU can afford. Further
terms: a binary cross-entropy between rendered opacity and the mask, an eikonal term
``(|grad f| - 1)^2`` at the ray samples and at nodes next to them, and a Laplacian
smoothness term (in voxel units).

The large changes that silhouettes cannot see (a bowl's cavity) are made before this stage
by stereo carving (:mod:`fracture_gs.recon.carving`); this stage polishes the carved SDF.
``1/s`` (the width of the opacity transition) follows a geometric schedule from
``initial_width_voxels`` (coarse voxels) to ``final_width_voxels`` (fine voxels). A
gradient-free pre-pass over the whole ray finds the interval that carries the weight, the
differentiable pass samples that interval densely. With ``coarse_fraction`` > 0 the first
part of the run is at half the resolution, after which the SDF is upsampled.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from fracture_gs.data.dataset import Dataset
from fracture_gs.recon.grid import (VoxelGrid, cell_corners, combine_with_gradient,
                                    gather, resample)
from fracture_gs.recon.rays import RigTensors, box_intersection


PRESAMPLE_SPACING = 1.5   # voxels between the samples of the gradient-free pre-pass
TEXTURE_CONTRAST = 0.02   # grey-level std of a patch that counts as fully textured


@dataclass
class RefineSettings:
    """Sizes and weights of the refinement (defaults sized for a 2-core CPU: the stereo
    carving before it does the large changes, this stage polishes at the fine level)."""

    iterations: int = 300
    rays: int = 1024                     # rays per iteration
    patch: int = 8                       # rays come in patch x patch pixel squares
    samples: int = 40                    # differentiable samples per ray
    coarse_fraction: float = 0.0         # share of iterations at half resolution
    band_voxels: float = 3.0             # optimised margin outside the hull, in voxels
    neighbours: int = 4                  # views compared with the ray's view
    sdf_lr: float = 0.05                 # in voxels per step (Adam)
    sdf_eps: float = 1e-5                # Adam epsilon: nodes with tiny gradients stay put
    mask_weight: float = 0.3
    eikonal_weight: float = 0.1
    smooth_weight: float = 0.05          # Laplacian term (voxel units)
    smooth_floor: float = 1.0            # the Laplacian weight fades linearly to this share
    initial_width_voxels: float = 1.0    # 1/s at the start, in coarse (2 fine) voxels
    final_width_voxels: float = 1.0      # 1/s at the end, in fine voxels
    seed: int = 0


@dataclass
class RefineLog:
    """Per-logged-iteration values (written to train_log.csv by the caller)."""

    rows: list[dict] = field(default_factory=list)


class GridSDF(torch.nn.Module):
    """SDF on the band nodes of a grid and the width 1/s of the NeuS opacity transition.

    Band values are stored compactly, one row per band node plus a last row that stands for
    every node outside the band: there the SDF is the band margin (a truncated SDF: the
    object lies inside its visual hull, so nothing outside the band can become surface).
    """

    def __init__(self, grid: VoxelGrid, initial_sdf: torch.Tensor, margin: float,
                 width: float) -> None:
        super().__init__()
        self.grid = grid
        self.margin = float(margin)
        flat = initial_sdf.reshape(-1).float()
        band_index = torch.nonzero(flat < margin)[:, 0]
        count = band_index.numel()
        self.register_buffer("band_index", band_index)
        lookup = torch.full((flat.numel(),), count, dtype=torch.long, device=flat.device)
        lookup[band_index] = torch.arange(count, device=flat.device)
        self.register_buffer("lookup", lookup)
        self.sdf = torch.nn.Parameter(torch.cat([flat[band_index], flat.new_full((1,), margin)]))
        self.register_buffer("width", torch.tensor(float(width)))

    def after_step(self) -> None:
        """Restore the fixed value of the nodes outside the band (after every step)."""
        with torch.no_grad():
            self.sdf[-1] = self.margin

    def rows(self, nodes: torch.Tensor) -> torch.Tensor:
        """Table rows of flat node indices (any shape)."""
        return gather(self.lookup, nodes)

    def dense_sdf(self) -> torch.Tensor:
        """(nx, ny, nz) SDF, detached (truncated at the margin outside the band)."""
        return self.sdf.detach()[self.lookup].reshape(self.grid.shape)

    def evaluate(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """SDF (P,) and its gradient (P, 3) at ``points``."""
        corners = cell_corners(self.grid, points)
        return combine_with_gradient(gather(self.sdf, self.rows(corners.index)), corners)

    def set_width(self, width: float) -> None:
        """Set 1/s, the width of the NeuS opacity transition (scheduled, not learned)."""
        self.width.fill_(width)

    @property
    def sharpness(self) -> torch.Tensor:
        return 1.0 / self.width


class NeighbourViews:
    """The training images as a colour lookup: each view's K nearest other views (by the
    angle between the directions from the object centre to the cameras) and bilinear
    colour samples of world points in those views."""

    def __init__(self, dataset: Dataset, count: int, centre: np.ndarray,
                 device: torch.device) -> None:
        views = len(dataset)
        self.height, self.width = dataset.height, dataset.width
        self.images = dataset.images.to(device).reshape(-1, 3)
        matrices = []
        for camera in dataset.cameras:
            intrinsics = torch.tensor([[camera.fx, 0.0, camera.cx], [0.0, camera.fy, camera.cy],
                                       [0.0, 0.0, 1.0]], dtype=torch.float64)
            matrices.append(intrinsics @ camera.world_to_camera.double().cpu()[:3, :4])
        self.matrices = torch.stack(matrices).float().to(device)                  # (V, 3, 4)
        directions = F.normalize(dataset.camera_centers().double()
                                 - torch.as_tensor(centre, dtype=torch.float64), dim=1)
        cosine = directions @ directions.T
        cosine.fill_diagonal_(-2.0)
        count = max(1, min(count, views - 1))
        self.neighbours = cosine.topk(count, dim=1).indices.to(device)           # (V, K)

    def colors(self, points: torch.Tensor, views: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Colours (R, K, S, 3) of ``points`` (R, S, 3) in the neighbours of ``views`` (R,),
        and whether each projection lands in front of the camera inside the image."""
        neighbour = self.neighbours[views]                                         # (R, K)
        matrix = self.matrices[neighbour]                                          # (R, K, 3, 4)
        projected = torch.einsum("rkij,rsj->rksi", matrix[..., :3], points) \
            + matrix[:, :, None, :, 3]
        depth = projected[..., 2]
        u = projected[..., 0] / depth.clamp_min(1e-6) - 0.5       # pixel-centre coordinates
        v = projected[..., 1] / depth.clamp_min(1e-6) - 0.5
        valid = (depth > 1e-6) & (u >= 0) & (u <= self.width - 1) & (v >= 0) \
            & (v <= self.height - 1)
        u = u.clamp(0, self.width - 1.001)
        v = v.clamp(0, self.height - 1.001)
        u0, v0 = u.floor(), v.floor()
        fu, fv = (u - u0)[..., None], (v - v0)[..., None]
        base = (neighbour[:, :, None] * self.height + v0.long()) * self.width + u0.long()
        c00 = gather(self.images, base)
        c01 = gather(self.images, base + 1)
        c10 = gather(self.images, base + self.width)
        c11 = gather(self.images, base + self.width + 1)
        color = (c00 * (1 - fu) + c01 * fu) * (1 - fv) + (c10 * (1 - fu) + c11 * fu) * fv
        return color, valid


def neus_alpha(sdf: torch.Tensor, sharpness: torch.Tensor) -> torch.Tensor:
    """NeuS section opacities (R, n-1) from SDF samples (R, n) along rays."""
    log_cdf = F.logsigmoid(sharpness * sdf)
    ratio = torch.exp(log_cdf[:, 1:] - log_cdf[:, :-1])
    return (1.0 - ratio).clamp(0.0, 1.0)


def composite_weights(alpha: torch.Tensor) -> torch.Tensor:
    """Front-to-back weights alpha_i prod_{j<i} (1 - alpha_j)."""
    transmittance = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]),
                                             1.0 - alpha[:, :-1] + 1e-7], dim=1), dim=1)
    return alpha * transmittance


def nearest_sdf(model: GridSDF, points: torch.Tensor) -> torch.Tensor:
    """SDF of the nearest node (clamped to the grid), for the gradient-free pre-pass."""
    grid = model.grid
    origin = torch.tensor(grid.origin, dtype=points.dtype, device=points.device)
    upper = torch.tensor([n - 1 for n in grid.shape], device=points.device)
    index = torch.minimum(torch.round((points - origin) / grid.voxel).long().clamp_min(0), upper)
    flat = (index[:, 0] * grid.shape[1] + index[:, 1]) * grid.shape[2] + index[:, 2]
    return gather(model.sdf.detach(), model.rows(flat))


def weight_interval(model: GridSDF, origins: torch.Tensor, directions: torch.Tensor,
                    near: torch.Tensor, far: torch.Tensor,
                    presamples: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Gradient-free pass: the sub-interval of [near, far] that holds the rendering weight
    of each ray (around the SDF minimum for rays that currently carry no weight)."""
    grid = model.grid
    with torch.no_grad():
        steps = torch.linspace(0.0, 1.0, presamples, device=origins.device)
        t = near[:, None] + (far - near)[:, None] * steps[None]
        points = origins[:, None, :] + t[..., None] * directions[:, None, :]
        sdf = nearest_sdf(model, points.reshape(-1, 3)).reshape(t.shape)
        weights = composite_weights(neus_alpha(sdf, model.sharpness))
        total = weights.sum(dim=1)
        cumulative = torch.cumsum(weights, dim=1)
        low = (cumulative < 1e-3 * total[:, None]).sum(dim=1)
        high = (cumulative < 0.999 * total[:, None]).sum(dim=1) + 1
        empty = total < 1e-2
        minimum = sdf.argmin(dim=1)
        spacing = ((far - near) / (presamples - 1)).clamp_min(1e-9)
        pad = torch.ceil(2.0 * grid.voxel / spacing).long().clamp_min(1)
        low = torch.where(empty, minimum - pad, low - 1).clamp(0, presamples - 1)
        high = torch.where(empty, minimum + pad, high + 1).clamp(0, presamples - 1)
        start = t.gather(1, low[:, None])[:, 0]
        end = t.gather(1, high[:, None])[:, 0]
        end = torch.maximum(end, start + 2.0 * grid.voxel)
    return start, end


def render_rays(model: GridSDF, origins: torch.Tensor, directions: torch.Tensor,
                near: torch.Tensor, far: torch.Tensor, samples: int, presamples: int,
                generator: torch.Generator | None) -> dict[str, torch.Tensor]:
    """Differentiable NeuS weights along rays: ``weights`` (R, S-1) of the sections that
    start at ``points`` (R, S, 3), ``opacity`` (R,), and the SDF ``gradient`` (R*S, 3)."""
    start, end = weight_interval(model, origins, directions, near, far, presamples)
    jitter = torch.rand(origins.shape[0], samples, device=origins.device, generator=generator)
    t = start[:, None] + (end - start)[:, None] * (torch.arange(samples, device=origins.device)
                                                   + jitter) / samples
    points = origins[:, None, :] + t[..., None] * directions[:, None, :]
    sdf, gradient = model.evaluate(points.reshape(-1, 3))
    weights = composite_weights(neus_alpha(sdf.reshape(t.shape), model.sharpness))
    return {"weights": weights, "opacity": weights.sum(dim=1), "gradient": gradient,
            "points": points}


def ray_pool(dataset: Dataset, dilation: int) -> torch.Tensor:
    """(P, 3) int64 (view, column, row) of the pixels within ``dilation`` pixels of a mask."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilation + 1, 2 * dilation + 1))
    pools = []
    for view, mask in enumerate(dataset.masks.cpu().numpy()):
        near_object = cv2.dilate((mask > 0.02).astype(np.uint8), kernel)
        rows, columns = np.nonzero(near_object)
        pools.append(np.stack([np.full_like(rows, view), columns, rows], axis=1))
    return torch.from_numpy(np.concatenate(pools).astype(np.int64))


def sample_patches(pool: torch.Tensor, rays: int, patch: int, width: int, height: int,
                   generator: torch.Generator) -> tuple[torch.Tensor, ...]:
    """(view, column, row) of ``rays`` pixels in square patches of ``patch`` x ``patch``
    pixels around random pool pixels (neighbouring rays read neighbouring grid cells, which
    keeps the gathers cache-friendly)."""
    per_patch = patch * patch
    count = max(1, rays // per_patch)
    centre = pool[torch.randint(pool.shape[0], (count,), device=pool.device,
                                generator=generator)]
    offset = torch.arange(patch, device=pool.device) - patch // 2
    dy, dx = torch.meshgrid(offset, offset, indexing="ij")
    column = (centre[:, 1, None] + dx.reshape(1, -1)).clamp(0, width - 1)
    row = (centre[:, 2, None] + dy.reshape(1, -1)).clamp(0, height - 1)
    view = centre[:, 0, None].expand(-1, per_patch)
    return view.reshape(-1), column.reshape(-1), row.reshape(-1)


def laplacian_and_eikonal(model: GridSDF, nodes: torch.Tensor
                          ) -> tuple[torch.Tensor, torch.Tensor]:
    """Discrete Laplacian in voxel units, (Σ neighbours - 6 centre) / voxel (a smooth
    surface of radius R voxels gives about 2/R; noise of one voxel gives several), and the
    central-difference gradient norm at interior nodes."""
    grid = model.grid
    ny, nz = grid.shape[1], grid.shape[2]
    strides = torch.tensor([ny * nz, nz, 1], device=nodes.device)
    neighbours = torch.cat([nodes[:, None], nodes[:, None] + strides, nodes[:, None] - strides],
                           dim=1)                                        # (N, 7)
    values = gather(model.sdf, model.rows(neighbours))
    centre, plus, minus = values[:, 0], values[:, 1:4], values[:, 4:7]
    laplacian = ((plus + minus).sum(dim=1) - 6.0 * centre) / grid.voxel
    norm = ((plus - minus) / (2 * grid.voxel)).norm(dim=1)
    return laplacian, norm


def regularised_nodes(grid: VoxelGrid, points: torch.Tensor, count: int,
                      generator: torch.Generator) -> torch.Tensor:
    """Flat indices of the nodes nearest to ``count`` random ``points``, moved off the grid's
    outer layer (so that they have 6 neighbours)."""
    pick = points[torch.randint(points.shape[0], (count,), device=points.device,
                                generator=generator)]
    origin = torch.tensor(grid.origin, dtype=pick.dtype, device=pick.device)
    upper = torch.tensor([n - 2 for n in grid.shape], device=pick.device)
    index = torch.minimum(torch.round((pick - origin) / grid.voxel).long().clamp_min(1), upper)
    return (index[:, 0] * grid.shape[1] + index[:, 1]) * grid.shape[2] + index[:, 2]


def patch_ncc_loss(weights: torch.Tensor, colors: torch.Tensor, valid: torch.Tensor,
                   reference: torch.Tensor, patch_pixels: int) -> torch.Tensor:
    """Photo-consistency of ray patches: 1 - NCC between each reference patch and the same
    patch as the neighbour views see the rendered surface, best half of the neighbours,
    weighted by the reference patch's contrast (texture-less patches carry no depth cue).

    ``weights`` (R, S-1) NeuS weights, ``colors`` (R, K, S-1, 3) and ``valid`` (R, K, S-1)
    neighbour colours at the samples, ``reference`` (R, 3) the rays' pixels; R is a whole
    number of patches of ``patch_pixels`` rays.
    """
    opacity = weights.sum(dim=1).clamp_min(1e-4)
    gray = colors.mean(dim=-1)                                              # (R, K, S)
    seen = torch.einsum("rs,rks->rk", weights, gray) / opacity[:, None]     # (R, K)
    coverage = torch.einsum("rs,rks->rk", weights, valid.float()) / opacity[:, None]
    reference_gray = reference.mean(dim=-1)
    patches = reference.shape[0] // patch_pixels
    seen = seen.reshape(patches, patch_pixels, -1)
    coverage = coverage.reshape(patches, patch_pixels, -1).mean(dim=1)      # (N, K)
    ref = reference_gray.reshape(patches, patch_pixels, 1)
    ref_centred = ref - ref.mean(dim=1, keepdim=True)
    seen_centred = seen - seen.mean(dim=1, keepdim=True)
    ref_std = (ref_centred.square().mean(dim=1) + 1e-8).sqrt()                # (N, 1)
    seen_std = (seen_centred.square().mean(dim=1) + 1e-8).sqrt()              # (N, K)
    ncc = (ref_centred * seen_centred).mean(dim=1) / (ref_std * seen_std + 1e-4)
    cost = torch.where(coverage > 0.9, 1.0 - ncc, torch.full_like(ncc, 2.0))
    keep = max(1, (cost.shape[1] + 1) // 2)
    best = cost.topk(keep, dim=1, largest=False).values.mean(dim=1)          # (N,)
    texture = (ref_std[:, 0] / TEXTURE_CONTRAST).clamp(max=1.0)
    usable = (best < 2.0).float() * texture
    return (best.clamp(max=2.0) * usable).sum() / usable.sum().clamp_min(1e-6)


def _train_level(model: GridSDF, dataset: Dataset, views: NeighbourViews, rig: RigTensors,
                 pool: torch.Tensor, settings: RefineSettings, iterations: int,
                 first_iteration: int, total_iterations: int,
                 width_schedule: Callable[[float], float], generator: torch.Generator,
                 log: RefineLog, progress: Callable[[dict], None] | None) -> None:
    device = model.sdf.device
    grid = model.grid
    optimizer = torch.optim.Adam([
        {"params": [model.sdf], "lr": settings.sdf_lr * grid.voxel, "eps": settings.sdf_eps}])
    images = dataset.images.to(device)
    masks = dataset.masks.to(device)
    lower, upper = grid.lower, grid.upper
    diagonal = float(np.linalg.norm(upper - lower))
    presamples = int(min(256, max(32, math.ceil(diagonal / (PRESAMPLE_SPACING * grid.voxel)))))
    for step in range(iterations):
        iteration = first_iteration + step
        progress_fraction = iteration / max(total_iterations, 1)
        model.set_width(width_schedule(progress_fraction))
        view, column, row = sample_patches(pool, settings.rays, settings.patch,
                                           dataset.width, dataset.height, generator)
        origins, directions = rig.rays(view, column, row)
        near, far = box_intersection(origins, directions, lower, upper)
        far = torch.maximum(far, near + grid.voxel)
        out = render_rays(model, origins, directions, near, far, settings.samples, presamples,
                          generator)
        target = images[view, row, column]
        mask = masks[view, row, column]
        with torch.no_grad():
            colors, valid = views.colors(out["points"][:, :-1], view)
        photo = patch_ncc_loss(out["weights"], colors, valid, target, settings.patch ** 2)
        opacity = out["opacity"].clamp(1e-4, 1 - 1e-4)
        mask_loss = F.binary_cross_entropy(opacity, mask)
        eikonal = (out["gradient"].norm(dim=-1) - 1.0).square().mean()
        nodes = regularised_nodes(grid, out["points"].detach().reshape(-1, 3),
                                  settings.rays * 8, generator)
        laplacian, norm = laplacian_and_eikonal(model, nodes)
        eikonal = eikonal + (norm - 1.0).square().mean()
        smooth = laplacian.square().mean()
        fade = max(settings.smooth_floor, 1.0 - progress_fraction)
        loss = (photo + settings.mask_weight * mask_loss
                + settings.eikonal_weight * eikonal + settings.smooth_weight * fade * smooth)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        model.after_step()
        row_log = {"stage": "sdf", "iteration": iteration + 1, "loss": loss.item(),
                   "photo": photo.item(), "mask": mask_loss.item(),
                   "width": float(model.width), "voxel": grid.voxel}
        if progress is not None:
            progress(row_log)
        if (iteration + 1) % 50 == 0 or iteration + 1 == total_iterations:
            log.rows.append(row_log)


@dataclass
class RefinedSDF:
    """Result of the refinement: the SDF on the fine grid."""

    grid: VoxelGrid
    sdf: torch.Tensor          # (nx, ny, nz)
    log: RefineLog
    seconds: float


def _coarse_grid(grid: VoxelGrid) -> VoxelGrid:
    shape = tuple(int(math.ceil((n - 1) / 2)) + 1 for n in grid.shape)
    return VoxelGrid(grid.origin, grid.voxel * 2, shape)


def refine_sdf(dataset: Dataset, grid: VoxelGrid, hull_sdf: torch.Tensor,
               settings: RefineSettings, device: torch.device,
               progress: Callable[[dict], None] | None = None) -> RefinedSDF:
    """Refine the visual-hull SDF ``hull_sdf`` (on ``grid``) against the images of
    ``dataset`` (which must have masks)."""
    if dataset.masks is None:
        raise ValueError("refine_sdf needs masks")
    started = time.perf_counter()
    generator = torch.Generator(device=device).manual_seed(settings.seed)
    rig = RigTensors.from_cameras(dataset.cameras, device)
    views = NeighbourViews(dataset, settings.neighbours, 0.5 * (grid.lower + grid.upper), device)
    pool = ray_pool(dataset, dilation=max(2, dataset.width // 50)).to(device)
    hull = hull_sdf.to(device)
    log = RefineLog()
    coarse_iterations = int(round(settings.iterations * settings.coarse_fraction))
    coarse = _coarse_grid(grid)
    start_width = settings.initial_width_voxels * coarse.voxel
    end_width = settings.final_width_voxels * grid.voxel

    def width_schedule(fraction: float) -> float:  # geometric from start to end
        return start_width ** (1.0 - fraction) * end_width ** fraction

    model = GridSDF(coarse, resample(hull, grid, coarse), settings.band_voxels * coarse.voxel,
                    start_width).to(device)
    if coarse_iterations > 0:
        _train_level(model, dataset, views, rig, pool, settings, coarse_iterations, 0,
                     settings.iterations, width_schedule, generator, log, progress)
    fine_margin = settings.band_voxels * grid.voxel
    fine_sdf = hull
    if coarse_iterations > 0:
        fine_sdf = torch.where(hull < fine_margin, resample(model.dense_sdf(), coarse, grid),
                               hull)
    fine = GridSDF(grid, fine_sdf, fine_margin, float(model.width)).to(device)
    if settings.iterations - coarse_iterations > 0:
        _train_level(fine, dataset, views, rig, pool, settings,
                     settings.iterations - coarse_iterations, coarse_iterations,
                     settings.iterations, width_schedule, generator, log, progress)
    return RefinedSDF(grid, fine.dense_sdf().clone(), log, time.perf_counter() - started)
