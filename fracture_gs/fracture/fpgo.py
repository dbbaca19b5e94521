"""FPGO — Fracture Particles Gaussian Optimization (paper §3.2.2, App. A.4–A.6; docs/formulas.md §13).

Applied to the Gaussians of one frame (the particles' own Gaussians, already following their
particles), it returns the Gaussians to draw:

1. the fractured set is the simulation's latched ``fractured`` flag;
2. fragments (connected components of the d_c-neighbour graph of each object, d_c =
   ``dc_factor`` × the object's rest particle spacing) with fewer than ``min_fragment``
   particles are not drawn at all (App. A.6);
3. fractured particles without a trained Gaussian (interior particles) get one: isotropic, scale
   = spacing / 2, SH and opacity interpolated once in the rest configuration (inverse distance,
   ``interpolation_k`` nearest surface Gaussians of the object) — by default only those on a
   fracture surface (``FPGOSettings.interior``, "exposed"; paper App. A.6 gives Gaussians to the
   internal particles a fracture exposes): fewer than ``exposure`` of their rest neighbours (the
   ``REST_NEIGHBOURS`` nearest within d_c at rest) are still within d_c. The NACC flag marks a
   whole damaged volume, most of it buried under intact material; its buried particles get
   nothing, as without fracture. ``interior="all"`` gives every fractured one a Gaussian
   (``render.py --interior all``);
4. every fractured particle i that has a trained Gaussian or gets one in step 3 looks up its
   ``k_neighbours`` nearest intact particles j of its object within d_c (current positions,
   hash grid); the spheres (C, k_sigma·σ) of g_i and g_j,
   σ the Gaussian's current size det(Σ)^(1/6), give one lens ellipsoid per overlapping pair
   (:func:`fracture_gs.fracture.ops.lens_ellipsoids`), with g_i's opacity, SH and view rotation,
   in exclusive group i (``FPGOSettings.exclusive``: per pixel only the nearest lens of g_i
   blends, paper §3.2.2); they replace g_i (and any
   other Gaussian particle i drives). A fractured particle without an overlapping intact
   neighbour keeps its Gaussian.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import torch

from fracture_gs.fracture.ops import LensEllipsoids, lens_ellipsoids
from fracture_gs.fracture.spatial import fracture_neighbourhood, knn_within

InteriorDeform = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


EXCLUSIVE_RULES = ("group", "all", "none")
INTERIOR_RULES = ("exposed", "all")
REST_NEIGHBOURS = 20   # rest neighbours per particle in the exposure test and the core hint


@dataclass(frozen=True)
class FPGOSettings:
    """FPGO parameters (docs/formulas.md §13 defaults; ``min_fragment`` is ours: the paper gives none)."""

    dc_factor: float = 1.5       # d_c = dc_factor × rest particle spacing
    k_neighbours: int = 2        # intact neighbours per fractured particle (g_m, g_n)
    k_sigma: float = 2.0         # sphere radius = k_sigma × Gaussian scale
    min_fragment: int = 10       # fragments with fewer particles are not drawn
    interpolation_k: int = 4     # surface Gaussians an interior particle's appearance comes from
    exclusive: str = "group"     # "group": per pixel only the nearest lens of each replaced g_i
    #                              blends (paper §3.2.2); "all": only the nearest lens of all
    #                              (the global rule of docs/formulas.md §11); "none": lenses blend like any other
    interior: str = "exposed"    # fractured interior particles FPGO draws: "exposed" (on a
    #                              fracture surface, paper App. A.6) or "all" (docs/deviations.md, Rendering)
    exposure: float = 0.8        # "exposed": fewer than this share of the rest neighbours kept

    def __post_init__(self) -> None:
        if isinstance(self.exclusive, bool):  # the earlier bool setting: True = the lenses' rule
            object.__setattr__(self, "exclusive", "group" if self.exclusive else "none")
        if self.exclusive not in EXCLUSIVE_RULES:
            raise ValueError(f"exclusive must be one of {', '.join(EXCLUSIVE_RULES)}, "
                             f"got {self.exclusive!r}")
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
        if self.interior not in INTERIOR_RULES:
            raise ValueError(f"interior must be one of {', '.join(INTERIOR_RULES)}, "
                             f"got {self.interior!r}")
        if not 0.0 < self.exposure <= 1.0:
            raise ValueError(f"exposure must be in (0, 1], got {self.exposure}")


@dataclass
class FractureParticles:
    """Constant per-particle data FPGO needs (built once per simulation, on the render device).

    ``own_gaussian[p]`` is the row of particle p's trained (or flat-colour) Gaussian in the
    frame's Gaussians, -1 for particles without one; for those, ``interior_row[p]`` indexes
    ``interior_opacity`` / ``interior_sh`` (the interpolated appearance), else -1.
    ``rest_neighbours[o]`` (rows of object o, ``REST_NEIGHBOURS``) int32 lists each particle's
    nearest neighbours within d_c at rest (indices into ``rows_by_object[o]``, -1 padding),
    ``rest_neighbour_count[o]`` how many it lists (:func:`rest_neighbour_tables`).
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
    centre_gaussian: torch.Tensor   # (N,) row of the own Gaussian the particle drives, else -1
    rest_neighbours: list[torch.Tensor]       # per object (Q_o, K) int32, indices into its rows
    rest_neighbour_count: list[torch.Tensor]  # per object (Q_o,) int32
    object_slices: list[slice | None] = field(default_factory=list)  # rows as a slice, if one


@dataclass
class FPGOStats:
    """What one FPGO pass did (for timing.csv and tests)."""

    fractured: int = 0            # fractured particles (latched flag)
    hidden_particles: int = 0     # particles in fragments below min_fragment
    buried_particles: int = 0     # fractured interior particles not on a fracture surface
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


def rest_neighbour_tables(rest_x: torch.Tensor, rows_by_object: list[torch.Tensor],
                          radii: list[float], backend: str = "auto"
                          ) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    """Per object: the ``REST_NEIGHBOURS`` nearest particles of the same object within its d_c
    at rest (``radii[o]``) of each of its particles, as (Q_o, K) int32 indices into the object's
    rows (-1 padding), and how many each row lists (Q_o,) int32."""
    tables, counts = [], []
    for rows, radius in zip(rows_by_object, radii):
        points = rest_x.index_select(0, rows)
        local, _ = knn_within(points, points, radius, REST_NEIGHBOURS,
                              query_self=torch.arange(rows.numel(), device=rows.device),
                              backend=backend)
        tables.append(local.to(torch.int32).contiguous())
        counts.append((local >= 0).sum(1).to(torch.int32))
    return tables, counts


def contiguous_span(rows: torch.Tensor) -> slice | None:
    """``rows`` as a slice when they are one ascending run (an object's particles stored
    together), else None."""
    if rows.numel() == 0:
        return None
    start, stop = int(rows[0]), int(rows[-1]) + 1
    return slice(start, stop) if stop - start == rows.numel() and bool(
        torch.equal(rows, torch.arange(start, stop, device=rows.device))) else None


def _rows_of(tensor: torch.Tensor, rows: torch.Tensor, span: slice | None) -> torch.Tensor:
    return tensor[span] if span is not None else tensor.index_select(0, rows)


class Neighbourhoods(NamedTuple):
    """Per-frame neighbourhood facts of all particles (global rows)."""

    hidden: torch.Tensor   # (N,) bool: in a fragment below min_fragment
    exposed: torch.Tensor  # (N,) bool: fractured interior particles on a fracture surface
    query: torch.Tensor    # (N,) bool: fractured particles FPGO gives lenses / a Gaussian
    pair_i: torch.Tensor   # (P,) int64: a query particle ...
    pair_j: torch.Tensor   # (P,) int64: ... and one of its k nearest intact neighbours


def neighbourhoods(x: torch.Tensor, fractured: torch.Tensor, particles: FractureParticles,
                   settings: FPGOSettings, active_objects: torch.Tensor,
                   backend: str = "auto") -> Neighbourhoods:
    """docs/formulas.md §13 steps 2 and 4 with the exposure test, per object flagged in ``active_objects``
    (O,) bool, one op each (:func:`fracture_gs.fracture.spatial.fracture_neighbourhood`):
    the small fragments, the exposed particles, the fractured particles FPGO draws (all of them
    but the hidden ones with ``interior="all"``; else those with a trained Gaussian and the
    exposed ones) and their ``k_neighbours`` nearest intact, visible neighbours within d_c."""
    n = x.shape[0]
    hidden = torch.zeros(n, dtype=torch.bool, device=x.device)
    exposed = torch.zeros(n, dtype=torch.bool, device=x.device)
    query = torch.zeros(n, dtype=torch.bool, device=x.device)
    has_own = particles.own_gaussian >= 0
    pair_i, pair_j = [], []
    for o, rows in enumerate(particles.rows_by_object):
        if not bool(active_objects[o]) or rows.numel() == 0:
            continue
        span = particles.object_slices[o] if particles.object_slices else None
        found = fracture_neighbourhood(
            _rows_of(x, rows, span), particles.rest_neighbours[o],
            particles.rest_neighbour_count[o],
            settings.dc_factor * float(particles.object_spacing[o]),
            settings.min_fragment, settings.exposure, _rows_of(fractured, rows, span),
            _rows_of(has_own, rows, span), settings.k_neighbours,
            all_interior=settings.interior == "all", backend=backend)
        hidden[span if span is not None else rows] = found.hidden
        exposed[span if span is not None else rows] = found.exposed
        queries = rows.index_select(0, found.queries)
        query[queries] = True
        linked = found.neighbours >= 0
        pair_i.append(queries[:, None].expand_as(found.neighbours)[linked])
        pair_j.append(rows[found.neighbours[linked]])
    empty = torch.empty(0, dtype=torch.long, device=x.device)
    return Neighbourhoods(hidden, exposed, query, torch.cat(pair_i) if pair_i else empty,
                          torch.cat(pair_j) if pair_j else empty)


def small_fragment_mask(x: torch.Tensor, particles: FractureParticles, settings: FPGOSettings,
                        active_objects: torch.Tensor, backend: str = "auto") -> torch.Tensor:
    """(N,) bool: particles in a fragment (per object, d_c graph) below ``min_fragment``.
    Only objects flagged in ``active_objects`` (O,) bool are searched."""
    nothing = torch.zeros(x.shape[0], dtype=torch.bool, device=x.device)
    return neighbourhoods(x, nothing, particles, settings, active_objects, backend).hidden


def particle_spheres(rows: torch.Tensor, x: torch.Tensor, F_E: torch.Tensor,
                     means: torch.Tensor, particles: FractureParticles,
                     k_sigma: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Sphere (centre, radius) of the Gaussian of each particle in ``rows``: the mean of the
    Gaussian it drives (the particle's position when it drives none) and k_sigma × the Gaussian's
    current size, rest size × |det F_E|^(1/3) (= det(Σ_t)^(1/6) for its own Gaussian)."""
    gaussian = particles.centre_gaussian[rows]
    centre = torch.where((gaussian >= 0)[:, None], means[gaussian.clamp_min(0)], x[rows])
    radius = k_sigma * particles.rest_sigma[rows] * cube_root_abs_det(F_E[rows])
    return centre, radius


def apply_fpgo(columns: dict[str, torch.Tensor], x: torch.Tensor, F_E: torch.Tensor,
               fractured: torch.Tensor, particles: FractureParticles, settings: FPGOSettings,
               deform_interior: InteriorDeform,
               backend: str = "auto") -> tuple[dict[str, torch.Tensor], FPGOStats]:
    """The Gaussians to draw for one frame (columns as ``columns``) and what FPGO did.

    ``columns`` are the frame's base Gaussians, a dict of FrameGaussians' columns
    (:data:`fracture_gs.render.frame_gaussians.GAUSSIAN_COLUMNS`; row ``own_gaussian[p]`` is
    particle p's own);
    ``deform_interior(rows)`` returns (means, covariances, view_rotations) of the interpolated
    Gaussians of the particles ``rows`` (isotropic spacing/2 at rest, following the particle).
    """
    started = time.perf_counter()
    detail: dict[str, float] = {}
    stats = FPGOStats(fractured=int(fractured.sum()))
    if stats.fractured == 0:
        stats.milliseconds = (time.perf_counter() - started) * 1e3
        return columns, stats
    active = (torch.bincount(particles.object_id[fractured],
                             minlength=len(particles.rows_by_object)) > 0).cpu()

    # small fragments (step 5), the exposure test, and the k nearest intact neighbours of the
    # fractured particles FPGO draws (step 2), one op per object
    tick = time.perf_counter()
    found = neighbourhoods(x, fractured, particles, settings, active, backend)
    hidden, pair_i, pair_j = found.hidden, found.pair_i, found.pair_j
    stats.hidden_particles = int(hidden.sum())
    if settings.interior == "exposed":
        stats.buried_particles = int((fractured & ~hidden & (particles.own_gaussian < 0)
                                      & ~found.exposed).sum())
    detail["neighbours"] = (time.perf_counter() - tick) * 1e3

    # fractured interior particles FPGO draws get their interpolated Gaussian (step 4)
    tick = time.perf_counter()
    interior = torch.nonzero(found.query & (particles.own_gaussian < 0)).flatten()
    interior_deformed = dict(zip(("means", "covariances", "view_rotations"),
                                 deform_interior(interior)))
    detail["interior"] = (time.perf_counter() - tick) * 1e3

    tick = time.perf_counter()
    centre_i, radius_i = particle_spheres(pair_i, x, F_E, columns["means"], particles,
                                          settings.k_sigma)
    centre_j, radius_j = particle_spheres(pair_j, x, F_E, columns["means"], particles,
                                          settings.k_sigma)
    lens = lens_ellipsoids(centre_i, radius_i, centre_j, radius_j, settings.k_sigma,
                           backend=backend)
    valid = torch.nonzero(lens.valid).flatten()
    replaced = torch.zeros_like(fractured)
    replaced[pair_i[valid]] = True
    stats.replaced_particles = int(replaced.sum())
    stats.lens_gaussians = int(valid.numel())
    detail["mvee"] = (time.perf_counter() - tick) * 1e3

    tick = time.perf_counter()
    out, stats.interior_gaussians = _assemble(columns, interior, interior_deformed, lens, valid,
                                              pair_i, hidden, replaced, particles,
                                              settings.exclusive != "none")
    detail["assemble"] = (time.perf_counter() - tick) * 1e3
    stats.detail_ms = detail
    stats.milliseconds = (time.perf_counter() - started) * 1e3
    return out, stats


def _gather_cat(parts: list[tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """``torch.cat([source.index_select(0, index) for source, index in parts])`` with one copy."""
    first = parts[0][0]
    total = sum(int(index.numel()) for _, index in parts)
    out = torch.empty((total,) + tuple(first.shape[1:]), dtype=first.dtype, device=first.device)
    start = 0
    for source, index in parts:
        stop = start + int(index.numel())
        torch.index_select(source, 0, index, out=out[start:stop])
        start = stop
    return out


def _assemble(columns: dict[str, torch.Tensor], interior: torch.Tensor,
              interior_deformed: dict[str, torch.Tensor], lens: LensEllipsoids,
              valid: torch.Tensor, pair_i: torch.Tensor, hidden: torch.Tensor,
              replaced: torch.Tensor, particles: FractureParticles,
              exclusive: bool) -> tuple[dict[str, torch.Tensor], int]:
    """The frame's Gaussians — base ones of particles neither hidden nor replaced, interpolated
    ones of unreplaced fractured interior particles, and the lenses, which inherit opacity, SH
    and view rotation from g_i (particle i's own Gaussian, or its interpolated one) and, when
    ``exclusive``, get exclusive group id i — and the number of interpolated ones."""
    device = interior.device
    keep_base = torch.nonzero(~(hidden | replaced)[columns["particle"]]).flatten()
    keep_interior = torch.nonzero(~replaced[interior]).flatten()
    kept = interior.index_select(0, keep_interior)
    slot = torch.full_like(particles.own_gaussian, -1)  # particle -> row of interior
    slot[interior] = torch.arange(interior.numel(), device=device)
    owners = pair_i.index_select(0, valid)
    own = particles.own_gaussian.index_select(0, owners)
    lens_own = torch.nonzero(own >= 0).flatten()       # lenses whose g_i is a base Gaussian
    lens_inner = torch.nonzero(own < 0).flatten()      # ... an interpolated one
    own_rows = own.index_select(0, lens_own)
    inner_owners = owners.index_select(0, lens_inner)
    lens_order = torch.cat([valid.index_select(0, lens_own), valid.index_select(0, lens_inner)])
    particle_order = torch.cat([lens_own, lens_inner])
    object_id = particles.object_id.to(columns["object_id"].dtype)
    interior_row = particles.interior_row
    sources = {
        "means": (interior_deformed["means"], keep_interior, lens.centre, None),
        "covariances": (interior_deformed["covariances"], keep_interior, lens.covariance, None),
        "opacities": (particles.interior_opacity, interior_row[kept],
                      particles.interior_opacity, interior_row[inner_owners]),
        "sh": (particles.interior_sh, interior_row[kept], particles.interior_sh,
               interior_row[inner_owners]),
        "view_rotations": (interior_deformed["view_rotations"], keep_interior,
                           interior_deformed["view_rotations"], slot[inner_owners]),
    }
    out: dict[str, torch.Tensor] = {}
    for name, (inner, inner_index, lens_inner_source, lens_inner_index) in sources.items():
        if lens_inner_index is None:   # geometry of the lenses
            lens_parts = [(lens_inner_source, lens_order)]
        else:                          # appearance inherited from g_i
            lens_parts = [(columns[name], own_rows), (lens_inner_source, lens_inner_index)]
        out[name] = _gather_cat([(columns[name], keep_base), (inner, inner_index), *lens_parts])
    out["particle"] = _gather_cat([(columns["particle"], keep_base), (interior, keep_interior),
                                   (owners, particle_order)])
    out["object_id"] = _gather_cat([(columns["object_id"], keep_base), (object_id, kept),
                                    (object_id, owners.index_select(0, particle_order))])
    count_lens = int(valid.numel())
    lens_group = owners.index_select(0, particle_order) if exclusive else \
        torch.full((count_lens,), -1, dtype=torch.int64, device=device)
    out["exclusive"] = torch.cat([
        columns["exclusive"].index_select(0, keep_base),
        torch.full((keep_interior.numel(),), -1, dtype=torch.int64, device=device),
        lens_group.to(torch.int64)])
    out["is_fpgo"] = torch.cat([columns["is_fpgo"].index_select(0, keep_base),
                                torch.ones(keep_interior.numel() + count_lens, dtype=torch.bool,
                                           device=device)])
    return out, int(keep_interior.numel())
