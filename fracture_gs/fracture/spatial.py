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


def component_roots(points: torch.Tensor, radius: float, group: torch.Tensor | None = None,
                    backend: str = "auto") -> torch.Tensor:
    """(N,) int64: for every point, the smallest index in its connected component of the graph
    that links points at distance <= ``radius`` (and, with ``group``, of the same group)."""
    points = _points(points, "points")
    radius = _check_radius(radius)
    if use_compiled(points.device, backend):
        return compiled_module().spatial_component_roots(points, _int32(group), radius)
    return reference.component_roots(points, _int32(group), radius)


def connected_components(x: torch.Tensor, radius: float, group: torch.Tensor | None = None,
                         backend: str = "auto") -> torch.Tensor:
    """Fragment labels: (N,) int64 in 0..C-1, components of the graph that links points closer
    than ``radius`` (and, with ``group``, of the same group), numbered in the order of their
    smallest point index. Deterministic on every device and thread count."""
    roots = component_roots(x, radius, group, backend)
    return torch.unique(roots, return_inverse=True)[1]
