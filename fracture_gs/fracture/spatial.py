"""Fixed-radius neighbour queries and connected components on a uniform hash grid.

Compiled kernels (``csrc/spatial``: C++/OpenMP and CUDA, deterministic) with torch twins in
:mod:`fracture_gs.fracture.reference`; ``backend`` is ``auto`` | ``cpp`` | ``reference``.
Cost grows with the number of points and their neighbours within the radius, never with N².
"""
from __future__ import annotations

from typing import NamedTuple

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.fracture import reference

MAX_K = 32  # the kernels' kMaxNeighbours (csrc/spatial/hash_grid.h)


def _points(tensor: torch.Tensor, name: str) -> torch.Tensor:
    if tensor.dim() != 2 or tensor.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {tuple(tensor.shape)}")
    return tensor.to(torch.float32).contiguous()


def _check_radius(radius: float) -> float:
    radius = float(radius)
    if not radius > 0.0 or radius == float("inf"):
        raise ValueError(f"radius must be positive and finite, got {radius}")
    return radius


def _int32(tensor: torch.Tensor | None) -> torch.Tensor | None:
    return None if tensor is None else tensor.to(torch.int32).contiguous()


def knn_within(points: torch.Tensor, queries: torch.Tensor, radius: float, k: int, *,
               point_group: torch.Tensor | None = None, query_group: torch.Tensor | None = None,
               query_self: torch.Tensor | None = None,
               backend: str = "auto") -> tuple[torch.Tensor, torch.Tensor]:
    """The k nearest ``points`` within ``radius`` of every query.

    Returns ``index`` (Q, k) int64 (rows into ``points``, -1 where fewer were found) and
    ``distance`` (Q, k) (inf where missing), each row sorted by (distance, index). With groups
    (both or neither), only points of the query's group count; ``query_self`` (Q,) names the
    query's own row in ``points`` (or -1), which is skipped. 1 <= k <= MAX_K.
    """
    points, queries = _points(points, "points"), _points(queries, "queries")
    radius = _check_radius(radius)
    if not 1 <= k <= MAX_K:
        raise ValueError(f"k must be in 1..{MAX_K}, got {k}")
    if (point_group is None) != (query_group is None):
        raise ValueError("give both point_group and query_group, or neither")
    args = (points, _int32(point_group), queries, _int32(query_group), _int32(query_self))
    if use_compiled(points.device, backend):
        return tuple(compiled_module().spatial_knn_within(*args, radius, int(k)))
    return reference.knn_within(*args, radius, int(k))


def k_nearest(points: torch.Tensor, queries: torch.Tensor, k: int, start_radius: float,
              backend: str = "auto") -> torch.Tensor:
    """(Q, k) int64: the k nearest ``points`` of every query (exact, ties by index), for points
    that may lie far away — e.g. surface samples seen from deep inside a body, the worst case of
    a k-d tree. :func:`knn_within` runs with ``start_radius``, then with twice the radius for the
    queries that found fewer than k, until the radius spans the points' bounding box.
    1 <= k <= min(MAX_K, number of points)."""
    points, queries = _points(points, "points"), _points(queries, "queries")
    if not 1 <= k <= min(MAX_K, points.shape[0]):
        raise ValueError(f"k must be in 1..min({MAX_K}, {points.shape[0]} points), got {k}")
    radius = _check_radius(start_radius)
    lower = torch.minimum(points.min(0).values, queries.min(0).values)
    upper = torch.maximum(points.max(0).values, queries.max(0).values)
    span = float(torch.linalg.norm(upper - lower)) * 1.01 + 1e-6
    result = torch.full((queries.shape[0], k), -1, dtype=torch.int64, device=queries.device)
    pending = torch.arange(queries.shape[0], device=queries.device)
    while pending.numel() > 0:
        radius = min(radius, span)            # at the span every point is within reach
        index, _ = knn_within(points, queries.index_select(0, pending), radius, k, backend=backend)
        found = index[:, k - 1] >= 0
        result[pending[found]] = index[found]
        pending = pending[~found]
        radius *= 2.0
    return result


def component_roots(points: torch.Tensor, radius: float, group: torch.Tensor | None = None,
                    backend: str = "auto") -> torch.Tensor:
    """(N,) int64: for every point, the smallest index in its connected component of the graph
    that links points at distance <= ``radius`` (and, with ``group``, of the same group)."""
    points = _points(points, "points")
    radius = _check_radius(radius)
    if use_compiled(points.device, backend):
        return compiled_module().spatial_component_roots(points, _int32(group), radius)
    return reference.component_roots(points, _int32(group), radius)


def small_component_mask(points: torch.Tensor, radius: float, min_size: int,
                         group: torch.Tensor | None = None, backend: str = "auto",
                         known_core: torch.Tensor | None = None) -> torch.Tensor:
    """(N,) bool: points whose connected component (points linked at distance <= ``radius``,
    and of the same ``group``) has fewer than ``min_size`` points.

    The compiled kernel never labels large bodies: a point with ``min_size - 1`` neighbours is
    in a large component (its count stops there), and only the other points are united with
    their neighbours; the twin labels every component (:func:`component_roots`).
    ``known_core`` (N,) bool is an optional hint: points the caller knows to have at least
    ``min_size - 1`` such neighbours (e.g. :func:`retained_neighbours` of a rest-neighbour
    table), whose count the kernel then skips. The result does not change, as long as the hint
    names no other point."""
    points = _points(points, "points")
    radius = _check_radius(radius)
    if min_size < 1:
        raise ValueError(f"min_size must be >= 1, got {min_size}")
    if known_core is not None:
        if known_core.shape != (points.shape[0],) or known_core.dtype != torch.bool:
            raise ValueError(f"known_core must be a bool tensor of shape ({points.shape[0]},), got "
                             f"{known_core.dtype} {tuple(known_core.shape)}")
        known_core = known_core.to(points.device).contiguous()
    if use_compiled(points.device, backend):
        return compiled_module().spatial_small_component_mask(points, _int32(group), radius,
                                                              int(min_size), known_core)
    return reference.small_component_mask(points, _int32(group), radius, int(min_size))


def retained_neighbours(points: torch.Tensor, rows: torch.Tensor, table: torch.Tensor,
                        radius: float, backend: str = "auto") -> torch.Tensor:
    """(Q,) int32: for each query point ``rows[q]``, how many of the points listed in
    ``table[q]`` (Q, k) int32 indices into ``points``, -1 for none — e.g. its neighbours at
    rest — lie within ``radius`` of it now. A lower bound of its neighbour count; divided by
    the table row's length, the share of the neighbourhood that has stayed together."""
    points = _points(points, "points")
    radius = _check_radius(radius)
    rows = rows.to(device=points.device, dtype=torch.int64).contiguous()
    if rows.dim() != 1 or table.dim() != 2 or table.shape[0] != rows.shape[0]:
        raise ValueError(f"rows must have shape (Q,) and table (Q, k), got {tuple(rows.shape)} and "
                         f"{tuple(table.shape)}")
    table = table.to(device=points.device, dtype=torch.int32).contiguous()
    if use_compiled(points.device, backend):
        return compiled_module().spatial_retained_neighbours(points, rows, table, radius)
    return reference.retained_neighbours(points, rows, table, radius)


class FractureNeighbourhood(NamedTuple):
    """What :func:`fracture_neighbourhood` finds for one object's points."""

    hidden: torch.Tensor      # (N,) bool: in a fragment of fewer than min_size points
    exposed: torch.Tensor     # (N,) bool: fractured, no own Gaussian, and kept fewer than
    #                           ``exposure`` of its rest neighbours
    queries: torch.Tensor     # (Q,) int64: fractured, not hidden, with own / exposed (or all)
    neighbours: torch.Tensor  # (Q, k) int64: k nearest intact, visible points, -1 padding


def fracture_neighbourhood(points: torch.Tensor, rest_table: torch.Tensor,
                           rest_count: torch.Tensor, radius: float, min_size: int,
                           exposure: float, fractured: torch.Tensor, has_own: torch.Tensor,
                           k: int, all_interior: bool = False,
                           backend: str = "auto") -> FractureNeighbourhood:
    """FPGO's neighbourhood pass over one object's points (docs/formulas.md §13 steps 2 and 4 and the
    exposure test of :mod:`fracture_gs.fracture.fpgo`) in one call: the compiled op builds one
    hash grid of all the points (components) and one of the intact ones (k nearest).

    ``rest_table`` (N, K) int32 lists each point's neighbours at rest (indices into ``points``,
    -1 padding), ``rest_count`` (N,) int32 how many. A fractured point without an own Gaussian
    (``has_own``) is *exposed* when fewer than ``exposure`` × rest_count of them are within
    ``radius`` now (only those points are tested); a point is *hidden* when its component
    (points linked at <= ``radius``) has fewer than ``min_size`` points. The queries are the
    fractured points that are not hidden and have an own Gaussian (``has_own``) or are exposed
    (every one with ``all_interior``); each gets its ``k`` nearest points within ``radius`` that
    are neither fractured nor hidden, sorted by (distance, index).
    """
    points = _points(points, "points")
    radius = _check_radius(radius)
    n = points.shape[0]
    if rest_table.dim() != 2 or rest_table.shape[0] != n or rest_count.shape != (n,):
        raise ValueError(f"rest_table must have shape ({n}, K) and rest_count ({n},), got "
                         f"{tuple(rest_table.shape)} and {tuple(rest_count.shape)}")
    if min_size < 1:
        raise ValueError(f"min_size must be >= 1, got {min_size}")
    if not 1 <= k <= MAX_K:
        raise ValueError(f"k must be in 1..{MAX_K}, got {k}")
    for name, mask in (("fractured", fractured), ("has_own", has_own)):
        if mask.shape != (n,) or mask.dtype != torch.bool:
            raise ValueError(f"{name} must be a bool tensor of shape ({n},)")
    args = (points, rest_table.to(points.device, torch.int32).contiguous(),
            rest_count.to(points.device, torch.int32).contiguous(), radius, int(min_size),
            float(exposure), fractured.to(points.device).contiguous(),
            has_own.to(points.device).contiguous(), int(k), bool(all_interior))
    if use_compiled(points.device, backend):
        return FractureNeighbourhood(*compiled_module().spatial_fracture_neighbourhood(*args))
    return FractureNeighbourhood(*reference.fracture_neighbourhood(*args))


def connected_components(x: torch.Tensor, radius: float, group: torch.Tensor | None = None,
                         backend: str = "auto") -> torch.Tensor:
    """Fragment labels: (N,) int64 in 0..C-1, components of the graph that links points closer
    than ``radius`` (and, with ``group``, of the same group), numbered in the order of their
    smallest point index. Deterministic on every device and thread count."""
    roots = component_roots(x, radius, group, backend)
    return torch.unique(roots, return_inverse=True)[1]
