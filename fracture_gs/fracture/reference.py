"""Readable, vectorised PyTorch twins of the compiled spatial and fracture kernels.

Each function mirrors one op of ``csrc/spatial`` or ``csrc/fracture`` with the same inputs and
outputs (see :mod:`fracture_gs.fracture.ops`); the tests compare the two. They run on any
device without the extension, so they also serve as the (slower) fallback.

The neighbour search sorts points by their exact cell (no hashing needed in torch) and looks
up the 27 cells around each query with ``searchsorted``: candidate pairs grow with the number
of points per cell, never with N².
"""
from __future__ import annotations

import torch

_OFFSETS = torch.tensor([[dx, dy, dz] for dz in (-1, 0, 1) for dy in (-1, 0, 1)
                         for dx in (-1, 0, 1)])


def _cells(points: torch.Tensor, origin: torch.Tensor, radius: float) -> torch.Tensor:
    return torch.floor((points - origin) * (1.0 / radius)).long()


def _cell_keys(cells: torch.Tensor, shape: torch.Tensor) -> torch.Tensor:
    return (cells[..., 0] * shape[1] + cells[..., 1]) * shape[2] + cells[..., 2]


def pairs_within(points: torch.Tensor, queries: torch.Tensor,
                 radius: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """All (query, point) pairs with distance <= radius: (query index, point index, distance²).

    Float32 distances are computed as in the kernels: dx² + dy² + dz² of the differences.
    """
    device = points.device
    empty = torch.empty(0, dtype=torch.long, device=device)
    if points.shape[0] == 0 or queries.shape[0] == 0:
        return empty, empty, torch.empty(0, dtype=points.dtype, device=device)
    origin = points.min(0).values
    point_cells = _cells(points, origin, radius)
    query_cells = _cells(queries, origin, radius)
    # shift so that every looked-up cell has non-negative coordinates
    low = torch.minimum(point_cells.min(0).values, query_cells.min(0).values) - 1
    high = torch.maximum(point_cells.max(0).values, query_cells.max(0).values) + 1
    shape = high - low + 1
    point_keys = _cell_keys(point_cells - low, shape)
    sorted_keys, order = torch.sort(point_keys, stable=True)
    query_index, point_index = [], []
    for offset in _OFFSETS.to(device):
        keys = _cell_keys(query_cells + offset - low, shape)
        start = torch.searchsorted(sorted_keys, keys, side="left")
        count = torch.searchsorted(sorted_keys, keys, side="right") - start
        queries_of_pair = torch.repeat_interleave(torch.arange(queries.shape[0], device=device), count)
        first = torch.repeat_interleave(start, count)
        rank = torch.arange(first.shape[0], device=device) - \
            torch.repeat_interleave(torch.cumsum(count, 0) - count, count)
        query_index.append(queries_of_pair)
        point_index.append(order[first + rank])
    qi, pj = torch.cat(query_index), torch.cat(point_index)
    diff = points[pj] - queries[qi]
    d2 = diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1] + diff[:, 2] * diff[:, 2]
    keep = d2 <= radius * radius
    return qi[keep], pj[keep], d2[keep]


def knn_within(points: torch.Tensor, point_group: torch.Tensor | None, queries: torch.Tensor,
               query_group: torch.Tensor | None, query_self: torch.Tensor | None, radius: float,
               k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Twin of ``spatial_knn_within``: (index (Q,k) int64, distance (Q,k)), -1 / inf padded,
    sorted by (distance, index); same group only, never the query's ``self`` point."""
    qi, pj, d2 = pairs_within(points, queries, radius)
    keep = torch.ones_like(qi, dtype=torch.bool)
    if query_self is not None:
        keep &= pj != query_self.long()[qi]
    if point_group is not None:
        keep &= point_group[pj] == query_group[qi]
    qi, pj, d2 = qi[keep], pj[keep], d2[keep]
    # order by (query, d², point index): three stable sorts, least significant key first
    order = torch.arange(qi.shape[0], device=qi.device)
    for key in (pj, d2, qi):
        order = order[torch.sort(key[order], stable=True).indices]
    qi, pj, d2 = qi[order], pj[order], d2[order]
    first = torch.searchsorted(qi, qi, side="left")
    rank = torch.arange(qi.shape[0], device=qi.device) - first
    take = rank < k
    index = torch.full((queries.shape[0], k), -1, dtype=torch.long, device=points.device)
    distance = torch.full((queries.shape[0], k), float("inf"), dtype=points.dtype,
                          device=points.device)
    index[qi[take], rank[take]] = pj[take]
    # the square root in float64, rounded once: the correctly rounded float32 root, as the
    # kernels' std::sqrt / sqrtf give it (torch's float32 sqrt is 1 ulp off on some CPUs)
    distance[qi[take], rank[take]] = torch.sqrt(d2[take].double()).to(distance.dtype)
    return index, distance


def component_roots(points: torch.Tensor, group: torch.Tensor | None,
                    radius: float) -> torch.Tensor:
    """Twin of ``spatial_component_roots``: the smallest point index of each point's component
    of the graph "distance <= radius (and same group)"; min-label propagation with pointer
    jumping."""
    qi, pj, _ = pairs_within(points, points, radius)
    keep = pj > qi
    if group is not None:
        keep &= group[pj] == group[qi]
    a, b = qi[keep], pj[keep]
    labels = torch.arange(points.shape[0], device=points.device)
    while True:
        hooked = labels.clone()
        hooked.scatter_reduce_(0, a, labels[b], reduce="amin")
        hooked.scatter_reduce_(0, b, labels[a], reduce="amin")
        hooked = hooked[hooked]          # pointer jumping: labels stay in the component
        if torch.equal(hooked, labels):
            return labels
        labels = hooked


def small_component_mask(points: torch.Tensor, group: torch.Tensor | None, radius: float,
                         min_size: int) -> torch.Tensor:
    """Twin of ``spatial_small_component_mask``: points whose component has < min_size points."""
    roots = component_roots(points, group, radius)
    sizes = torch.bincount(roots, minlength=points.shape[0])
    return sizes[roots] < min_size


def retained_neighbours(points: torch.Tensor, rows: torch.Tensor, table: torch.Tensor,
                        radius: float) -> torch.Tensor:
    """Twin of ``spatial_retained_neighbours``: (Q,) int32 count of the table row's points
    (-1: none) within ``radius`` of point ``rows[q]`` (float32 dx² + dy² + dz², as the
    kernel)."""
    listed = table.long()
    diff = points[listed.clamp_min(0)] - points[rows][:, None, :]
    d2 = diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1] + diff[..., 2] * diff[..., 2]
    radius2 = torch.tensor(radius, dtype=torch.float32) ** 2
    return ((listed >= 0) & (d2 <= radius2.to(points.device))).sum(1).to(torch.int32)


def fracture_neighbourhood(points: torch.Tensor, rest_table: torch.Tensor,
                           rest_count: torch.Tensor, radius: float, min_size: int,
                           exposure: float, fractured: torch.Tensor, has_own: torch.Tensor,
                           k: int, all_interior: bool
                           ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Twin of ``spatial_fracture_neighbourhood`` from the other twins: (hidden, exposed,
    queries, neighbours)."""
    n = points.shape[0]
    kept = retained_neighbours(points, torch.arange(n, device=points.device), rest_table, radius)
    exposed = fractured & ~has_own & (kept.double() < rest_count.double() * exposure)
    hidden = small_component_mask(points, None, radius, min_size) if min_size > 1 else \
        torch.zeros(n, dtype=torch.bool, device=points.device)
    drawn = torch.ones_like(exposed) if all_interior else has_own | exposed
    queries = torch.nonzero(fractured & ~hidden & drawn).flatten()
    candidates = ~fractured & ~hidden
    group = candidates.to(torch.int32)
    query_group = torch.ones(queries.shape[0], dtype=torch.int32, device=points.device)
    neighbours, _ = knn_within(points, group, points[queries], query_group,
                               queries.to(torch.int32), radius, k)
    return hidden, exposed, queries, neighbours


def polar_rotation(F: torch.Tensor) -> torch.Tensor:
    """Rotation of the polar decomposition of F (…,3,3) with det +1: U Vᵀ of the SVD with the
    smallest singular direction flipped when det(U Vᵀ) < 0 (the signed SVD of the kernels)."""
    U, _, Vh = torch.linalg.svd(F.double())
    flip = torch.linalg.det(U @ Vh) < 0
    U = U.clone()
    U[..., :, 2] = torch.where(flip[..., None], -U[..., :, 2], U[..., :, 2])
    return (U @ Vh).to(F.dtype)


def deform_gaussians(x: torch.Tensor, F: torch.Tensor, driver: torch.Tensor,
                     rest_offset: torch.Tensor, rest_covariance: torch.Tensor,
                     object_rotation: torch.Tensor, gaussian_object: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Twin of ``fracture_deform_gaussians``: means x_p + F·offset, covariances F Σ0 Fᵀ, view
    rotations R_F·R_obj (R_F the polar rotation of F)."""
    Fg = F[driver]
    means = x[driver] + torch.einsum("mij,mj->mi", Fg, rest_offset)
    Fd = Fg.double()
    covariances = (Fd @ rest_covariance.double() @ Fd.transpose(1, 2)).to(x.dtype)
    view_rotations = polar_rotation(Fg) @ object_rotation[gaussian_object.long()]
    return means, covariances, view_rotations


def lens_ellipsoids(centre_i: torch.Tensor, radius_i: torch.Tensor, centre_j: torch.Tensor,
                    radius_j: torch.Tensor, k_sigma: float
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Twin of ``fracture_lens_ellipsoids`` (formulas in ``csrc/common/mvee.h``, docs/formulas.md §13):
    (centre, scales, rotation [u v w], covariance, valid) of the overlap of each sphere pair."""
    delta = centre_j - centre_i
    d = torch.sqrt(delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1] + delta[:, 2] * delta[:, 2])
    positive = (radius_i > 0) & (radius_j > 0)
    valid = positive & (d < radius_i + radius_j)
    contained = valid & (d <= (radius_i - radius_j).abs())
    lens = valid & ~contained
    safe_d = torch.where(lens, d, torch.ones_like(d))
    u = delta / safe_d[:, None]
    u = torch.where(lens[:, None], u, torch.tensor([1.0, 0.0, 0.0], device=u.device, dtype=u.dtype))
    # v: cross product of u with the least aligned coordinate axis (as in the kernel)
    a = u.abs()
    axis = torch.where((a[:, 0] <= a[:, 1]) & (a[:, 0] <= a[:, 2]), 0,
                       torch.where(a[:, 1] <= a[:, 2], 1, 2))
    e = torch.nn.functional.one_hot(axis, 3).to(u.dtype)
    v = torch.linalg.cross(u, e)
    v = v / v.norm(dim=1, keepdim=True)
    w = torch.linalg.cross(u, v)
    rotation = torch.stack([u, v, w], dim=2)
    h = 0.5 * safe_d + (radius_i - radius_j) * (radius_i + radius_j) / (2.0 * safe_d)
    semi_axis = 0.5 * (radius_i + radius_j - d)
    semi_across = torch.sqrt(torch.clamp(radius_i * radius_i - h * h, min=0.0))
    smaller_is_i = radius_i <= radius_j
    small_radius = torch.where(smaller_is_i, radius_i, radius_j)
    scale_axis = torch.where(contained, small_radius, semi_axis) / k_sigma
    scale_across = torch.where(contained, small_radius, semi_across) / k_sigma
    scale_axis = torch.where(valid, scale_axis, torch.zeros_like(scale_axis))
    scale_across = torch.where(valid, scale_across, torch.zeros_like(scale_across))
    eye = torch.eye(3, dtype=u.dtype, device=u.device).expand(u.shape[0], 3, 3)
    rotation = torch.where(lens[:, None, None], rotation, eye)
    t = radius_i / (radius_i + radius_j)
    centre = torch.where(lens[:, None], centre_i + t[:, None] * delta,
                         torch.where((contained & ~smaller_is_i)[:, None], centre_j, centre_i))
    scales = torch.stack([scale_axis, scale_across, scale_across], dim=1)
    covariance = (scale_across ** 2)[:, None, None] * eye + \
        (scale_axis ** 2 - scale_across ** 2)[:, None, None] * (u[:, :, None] * u[:, None, :])
    return centre, scales, rotation, covariance, valid
