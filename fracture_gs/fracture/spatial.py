"""Fixed-radius neighbour queries and connected components on a uniform hash grid.

Compiled kernels (``csrc/spatial``: C++/OpenMP and CUDA, deterministic) with torch twins in
:mod:`fracture_gs.fracture.reference`; ``backend`` is ``auto`` | ``cpp`` | ``reference``.
Cost grows with the number of points and their neighbours within the radius, never with N².
"""
from __future__ import annotations

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.fracture import reference


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
    query's own row in ``points`` (or -1), which is skipped. 1 <= k <= 16.
    """
    points, queries = _points(points, "points"), _points(queries, "queries")
    radius = _check_radius(radius)
    if not 1 <= k <= 16:
        raise ValueError(f"k must be in 1..16, got {k}")
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
    1 <= k <= min(16, number of points)."""
    points, queries = _points(points, "points"), _points(queries, "queries")
    if not 1 <= k <= min(16, points.shape[0]):
        raise ValueError(f"k must be in 1..min(16, {points.shape[0]} points), got {k}")
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
                         group: torch.Tensor | None = None, backend: str = "auto") -> torch.Tensor:
    """(N,) bool: points whose connected component (points linked at distance <= ``radius``,
    and of the same ``group``) has fewer than ``min_size`` points.

    The compiled kernel never labels large bodies: a point with ``min_size - 1`` neighbours is
    in a large component (its count stops there), and only the other points are united with
    their neighbours; the twin labels every component (:func:`component_roots`)."""
    points = _points(points, "points")
    radius = _check_radius(radius)
    if min_size < 1:
        raise ValueError(f"min_size must be >= 1, got {min_size}")
    if use_compiled(points.device, backend):
        return compiled_module().spatial_small_component_mask(points, _int32(group), radius,
                                                              int(min_size))
    return reference.small_component_mask(points, _int32(group), radius, int(min_size))


def connected_components(x: torch.Tensor, radius: float, group: torch.Tensor | None = None,
                         backend: str = "auto") -> torch.Tensor:
    """Fragment labels: (N,) int64 in 0..C-1, components of the graph that links points closer
    than ``radius`` (and, with ``group``, of the same group), numbered in the order of their
    smallest point index. Deterministic on every device and thread count."""
    roots = component_roots(x, radius, group, backend)
    return torch.unique(roots, return_inverse=True)[1]
