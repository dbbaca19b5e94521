"""FPGO — Fracture Particles Gaussian Optimization (paper §3.2.2, App. A.4–A.6; SPEC §6.3).

Applied to the Gaussians of one frame (the particles' own Gaussians, already following their
particles), it returns the Gaussians to draw:

1. the fractured set is the simulation's latched ``fractured`` flag;
2. fragments (connected components of the d_c-neighbour graph of each object, d_c =
   ``dc_factor`` × the object's rest particle spacing) with fewer than ``min_fragment``
   particles are not drawn at all (App. A.6);
3. fractured particles without a trained Gaussian (interior particles) get one: isotropic, scale
   = spacing / 2, SH and opacity interpolated once in the rest configuration (inverse distance,
   ``interpolation_k`` nearest surface Gaussians of the object);
4. every fractured particle i looks up its ``k_neighbours`` nearest intact particles j of its
   object within d_c (current positions, hash grid); the spheres (C, k_sigma·σ) of g_i and g_j,
   σ the Gaussian's current size det(Σ)^(1/6), give one lens ellipsoid per overlapping pair
   (:func:`fracture_gs.fracture.ops.lens_ellipsoids`), with g_i's opacity, SH and view rotation,
   marked ``exclusive``; they replace g_i (and any other Gaussian particle i drives). A
   fractured particle without an overlapping intact neighbour keeps its Gaussian.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import torch

from fracture_gs.fracture.ops import lens_ellipsoids
from fracture_gs.fracture.spatial import connected_components, knn_within

if TYPE_CHECKING:  # pragma: no cover
    from fracture_gs.render.frame_gaussians import FrameGaussians

InteriorDeform = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


@dataclass(frozen=True)
class FPGOSettings:
    """FPGO parameters (SPEC §6.3 defaults; ``min_fragment`` is ours: the paper gives none)."""

    dc_factor: float = 1.5       # d_c = dc_factor × rest particle spacing
    k_neighbours: int = 2        # intact neighbours per fractured particle (g_m, g_n)
    k_sigma: float = 2.0         # sphere radius = k_sigma × Gaussian scale
    min_fragment: int = 10       # fragments with fewer particles are not drawn
    interpolation_k: int = 4     # surface Gaussians an interior particle's appearance comes from

    def __post_init__(self) -> None:
        if not self.dc_factor > 0:
            raise ValueError(f"dc_factor must be > 0, got {self.dc_factor}")
        if not 1 <= self.k_neighbours <= 16:
            raise ValueError(f"k_neighbours must be in 1..16, got {self.k_neighbours}")
        if not self.k_sigma > 0:
            raise ValueError(f"k_sigma must be > 0, got {self.k_sigma}")
        if self.min_fragment < 1:
            raise ValueError(f"min_fragment must be >= 1, got {self.min_fragment}")
        if self.interpolation_k < 1:
            raise ValueError(f"interpolation_k must be >= 1, got {self.interpolation_k}")


@dataclass
class FractureParticles:
    """Constant per-particle data FPGO needs (built once per simulation, on the render device).

    ``own_gaussian[p]`` is the row of particle p's trained (or flat-colour) Gaussian in the
    frame's Gaussians, -1 for particles without one; for those, ``interior_row[p]`` indexes
    ``interior_opacity`` / ``interior_sh`` (the interpolated appearance), else -1.
    """

    object_id: torch.Tensor         # (N,) int64
    own_gaussian: torch.Tensor      # (N,) int64
    interior_row: torch.Tensor      # (N,) int64
    interior_opacity: torch.Tensor  # (I,)
    interior_sh: torch.Tensor       # (I, K, 3)
    rest_sigma: torch.Tensor        # (N,) rest size of each particle's Gaussian (spacing/2 if none)
    object_spacing: torch.Tensor    # (O,) rest particle spacing per object (CPU float64)
    object_rotation: torch.Tensor   # (O,3,3) rotation of each object's scene transform
    rows_by_object: list[torch.Tensor]  # particle indices of each object


@dataclass
class FPGOStats:
    """What one FPGO pass did (for timing.csv and tests)."""

    fractured: int = 0            # fractured particles (latched flag)
    hidden_particles: int = 0     # particles in fragments below min_fragment
    interior_gaussians: int = 0   # Gaussians given to fractured interior particles
    lens_gaussians: int = 0       # MVEE Gaussians drawn
    replaced_particles: int = 0   # fractured particles whose Gaussians the lenses replaced
    milliseconds: float = 0.0
    detail_ms: dict[str, float] = field(default_factory=dict)


def cube_root_abs_det(F: torch.Tensor) -> torch.Tensor:
    """|det F|^(1/3) of (N,3,3) matrices (vectorised cofactor expansion)."""
    det = (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
           - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
           + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))
    return det.abs().pow(1.0 / 3.0)


def small_fragment_mask(x: torch.Tensor, particles: FractureParticles, settings: FPGOSettings,
                        active_objects: torch.Tensor, backend: str = "auto") -> torch.Tensor:
    """(N,) bool: particles in a fragment (per object, d_c graph) below ``min_fragment``.
    Only objects flagged in ``active_objects`` (O,) bool are searched."""
    hidden = torch.zeros(x.shape[0], dtype=torch.bool, device=x.device)
    if settings.min_fragment <= 1:
        return hidden
    for o, rows in enumerate(particles.rows_by_object):
        if not bool(active_objects[o]) or rows.numel() == 0:
            continue
        radius = settings.dc_factor * float(particles.object_spacing[o])
        labels = connected_components(x[rows], radius, backend=backend)
        sizes = torch.bincount(labels)
        hidden[rows] = sizes[labels] < settings.min_fragment
    return hidden


GAUSSIAN_COLUMNS = ("means", "covariances", "opacities", "sh", "view_rotations", "exclusive",
                    "object_id", "is_fpgo", "particle")


def apply_fpgo(gaussians: "FrameGaussians", x: torch.Tensor, F_E: torch.Tensor, fractured: torch.Tensor,
               particles: FractureParticles, settings: FPGOSettings, deform_interior: InteriorDeform,
               backend: str = "auto") -> tuple[dict[str, torch.Tensor], FPGOStats]:
    """The Gaussians to draw for one frame (a dict of the ``GAUSSIAN_COLUMNS``) and what FPGO did.

    ``gaussians`` are the frame's base Gaussians (row ``own_gaussian[p]`` is particle p's own);
    ``deform_interior(rows)`` returns (means, covariances, view_rotations) of the interpolated
    Gaussians of the particles ``rows`` (isotropic spacing/2 at rest, following the particle).
    """
    started = time.perf_counter()
    detail: dict[str, float] = {}
    stats = FPGOStats(fractured=int(fractured.sum()))
    columns = {name: getattr(gaussians, name) for name in GAUSSIAN_COLUMNS}
    if stats.fractured == 0:
        stats.milliseconds = (time.perf_counter() - started) * 1e3
        return columns, stats
    device = x.device
    object_rows = particles.rows_by_object
    active = torch.zeros(len(object_rows), dtype=torch.bool)
    active[torch.unique(particles.object_id[fractured]).cpu()] = True

    tick = time.perf_counter()
    hidden = small_fragment_mask(x, particles, settings, active, backend)
    detail["fragments"] = (time.perf_counter() - tick) * 1e3
    stats.hidden_particles = int(hidden.sum())

    # the own Gaussian g_i of every particle that may need one: trained / flat rows, or the
    # interpolated Gaussian of a fractured interior particle
    tick = time.perf_counter()
    query = fractured & ~hidden
    interior = torch.nonzero(query & (particles.own_gaussian < 0)).flatten()
    interior_means, interior_cov, interior_rot = deform_interior(interior)
    interior_irow = particles.interior_row[interior]
    interior_g = {"means": interior_means, "covariances": interior_cov,
                  "opacities": particles.interior_opacity[interior_irow],
                  "sh": particles.interior_sh[interior_irow], "view_rotations": interior_rot}
    detail["interior"] = (time.perf_counter() - tick) * 1e3

    # sphere centre and radius of every particle's Gaussian at this frame
    tick = time.perf_counter()
    # (a particle that drives its own Gaussian: that Gaussian's mean; any other: the particle)
    with_own = torch.nonzero(particles.own_gaussian >= 0).flatten()
    drivers = with_own[gaussians.particle[particles.own_gaussian[with_own]] == with_own]
    centre = x.clone()
    centre[drivers] = gaussians.means[particles.own_gaussian[drivers]]
    radius = settings.k_sigma * particles.rest_sigma * cube_root_abs_det(F_E)

    # k nearest intact neighbours of every fractured particle, object by object
    pair_i, pair_j = [], []
    candidate = ~fractured & ~hidden
    for o, rows in enumerate(object_rows):
        if not bool(active[o]):
            continue
        queries = rows[query[rows]]
        points = rows[candidate[rows]]
        if queries.numel() == 0 or points.numel() == 0:
            continue
        d_c = settings.dc_factor * float(particles.object_spacing[o])
        index, _ = knn_within(x[points], x[queries], d_c, settings.k_neighbours, backend=backend)
        found = index >= 0
        pair_i.append(queries[:, None].expand_as(index)[found])
        pair_j.append(points[index[found]])
    pair_i = torch.cat(pair_i) if pair_i else torch.empty(0, dtype=torch.long, device=device)
    pair_j = torch.cat(pair_j) if pair_j else torch.empty(0, dtype=torch.long, device=device)
    detail["neighbours"] = (time.perf_counter() - tick) * 1e3

    tick = time.perf_counter()
    lens = lens_ellipsoids(centre[pair_i], radius[pair_i], centre[pair_j], radius[pair_j],
                           settings.k_sigma, backend=backend)
    pair_i = pair_i[lens.valid]
    replaced = torch.zeros_like(fractured)
    replaced[pair_i] = True
    stats.replaced_particles = int(replaced.sum())
    stats.lens_gaussians = int(pair_i.numel())
    detail["mvee"] = (time.perf_counter() - tick) * 1e3

    # appearance of g_i for each lens: its own row, or its interpolated Gaussian
    tick = time.perf_counter()
    slot = torch.full_like(particles.own_gaussian, -1)
    slot[interior] = torch.arange(interior.numel(), device=device)
    own = particles.own_gaussian[pair_i]
    from_own = own >= 0
    lens_cols = {"means": lens.centre[lens.valid], "covariances": lens.covariance[lens.valid]}
    for name in ("opacities", "sh", "view_rotations"):
        source = columns[name][own.clamp_min(0)]
        inner = interior_g[name][slot[pair_i].clamp_min(0)] if interior.numel() else source
        shape = (-1,) + (1,) * (source.dim() - 1)
        lens_cols[name] = torch.where(from_own.view(shape), source, inner)

    keep_base = ~(hidden | replaced)[gaussians.particle]
    keep_interior = ~replaced[interior]
    stats.interior_gaussians = int(keep_interior.sum())
    n_lens = pair_i.numel()
    n_int = int(keep_interior.sum())
    flags = {
        "exclusive": torch.cat([columns["exclusive"][keep_base],
                                torch.zeros(n_int, dtype=torch.bool, device=device),
                                torch.ones(n_lens, dtype=torch.bool, device=device)]),
        "object_id": torch.cat([columns["object_id"][keep_base],
                                particles.object_id[interior][keep_interior].to(columns["object_id"].dtype),
                                particles.object_id[pair_i].to(columns["object_id"].dtype)]),
        "is_fpgo": torch.cat([columns["is_fpgo"][keep_base],
                              torch.ones(n_int + n_lens, dtype=torch.bool, device=device)]),
        "particle": torch.cat([columns["particle"][keep_base], interior[keep_interior], pair_i]),
    }
    out = {name: torch.cat([columns[name][keep_base], interior_g[name][keep_interior],
                            lens_cols[name]])
           for name in ("means", "covariances", "opacities", "sh", "view_rotations")}
    out.update(flags)
    detail["assemble"] = (time.perf_counter() - tick) * 1e3
    stats.detail_ms = detail
    stats.milliseconds = (time.perf_counter() - started) * 1e3
    return out, stats
