"""Compiled spatial / fracture kernels against their torch twins (and against scipy)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.csgraph
import torch
from scipy.spatial import cKDTree

from fracture_gs.fracture import reference
from fracture_gs.fracture.ops import deform_gaussians, lens_ellipsoids
from fracture_gs.fracture.spatial import (component_roots, connected_components,
                                          fracture_neighbourhood, k_nearest, knn_within,
                                          retained_neighbours, small_component_mask)
from kernel_devices import KERNEL_DEVICES

needs_cpp = pytest.mark.extension("spatial_knn_within", "spatial_component_roots",
                                   "spatial_small_component_mask", "spatial_retained_neighbours",
                                   "spatial_fracture_neighbourhood",
                                   "fracture_deform_gaussians", "fracture_lens_ellipsoids")
BACKENDS = ["reference", pytest.param("cpp", marks=needs_cpp)]


def clustered_points(count: int, seed: int) -> torch.Tensor:
    """Points in a few separated blobs plus scattered ones (many components)."""
    generator = torch.Generator().manual_seed(seed)
    centres = torch.rand(6, 3, generator=generator) * 2.0
    blobs = centres[torch.randint(0, 6, (count // 2,), generator=generator)] + \
        0.08 * torch.randn(count // 2, 3, generator=generator)
    scattered = torch.rand(count - count // 2, 3, generator=generator) * 2.0
    return torch.cat([blobs, scattered])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("k", [1, 2, 5])
def test_knn_within_matches_brute_force(backend, k):
    points = clustered_points(1500, seed=1)
    queries = torch.cat([points[:300], torch.rand(100, 3) * 2.0])
    radius = 0.12
    query_self = torch.cat([torch.arange(300), torch.full((100,), -1)])
    index, distance = knn_within(points, queries, radius, k, query_self=query_self, backend=backend)
    tree = cKDTree(points.double().numpy())
    for q in range(queries.shape[0]):
        found = sorted((float(np.linalg.norm(points[j].double().numpy() - queries[q].double().numpy())), j)
                       for j in tree.query_ball_point(queries[q].double().numpy(), radius + 1e-6)
                       if j != int(query_self[q]))
        found = [(d, j) for d, j in found if d <= radius - 1e-5][:k]  # away from the boundary
        for n, (d, j) in enumerate(found):
            assert int(index[q, n]) == j
            assert float(distance[q, n]) == pytest.approx(d, abs=1e-5)
    assert ((index >= 0) | torch.isinf(distance)).all()


@needs_cpp
@pytest.mark.parametrize("k", [2, 3])
def test_knn_within_kernel_equals_twin_with_groups(k):
    points = clustered_points(4000, seed=2)
    group = (torch.arange(points.shape[0]) % 3).to(torch.int32)
    queries = points[::7] + 0.01
    query_group = group[::7]
    args = dict(point_group=group, query_group=query_group)
    index_c, distance_c = knn_within(points, queries, 0.1, k, backend="cpp", **args)
    index_r, distance_r = knn_within(points, queries, 0.1, k, backend="reference", **args)
    assert torch.equal(index_c, index_r)
    assert torch.allclose(distance_c, distance_r, atol=1e-7)
    hit = index_c >= 0
    assert (group[index_c[hit]] == query_group[:, None].expand_as(index_c)[hit]).all()


@needs_cpp
@pytest.mark.parametrize("k", [1, 2, 7])
def test_knn_within_on_a_lattice_keeps_every_tie(k):
    """On an integer lattice many candidates lie at the same distance and on cell faces (cell =
    radius = 1.5): the kernel's search, which skips grid rows beyond the k-th neighbour found,
    must still pick the same (distance, index) winners as the twin, which sees every pair."""
    axis = torch.arange(12.0)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    queries = torch.cat([points[::5], points[::7] + 0.5, points[::11] + torch.tensor([0.25, 0.5, 0.75])])
    for radius in (1.5, 1.0, 2.0):
        index_c, distance_c = knn_within(points, queries, radius, k, backend="cpp")
        index_r, distance_r = knn_within(points, queries, radius, k, backend="reference")
        assert torch.equal(index_c, index_r)
        assert torch.equal(distance_c, distance_r)


@pytest.mark.parametrize("backend", BACKENDS)
def test_k_nearest_is_exact_from_deep_inside_a_shell(backend):
    # surface samples of a sphere, queried from inside (radius doubling from 0.05 up to the span)
    generator = torch.Generator().manual_seed(7)
    shell = torch.nn.functional.normalize(torch.randn(800, 3, generator=generator), dim=1)
    queries = 0.95 * torch.rand(300, 1, generator=generator) * \
        torch.nn.functional.normalize(torch.randn(300, 3, generator=generator), dim=1)
    queries[0] = 0.0                                   # the centre: every point equally far
    index = k_nearest(shell, queries, 4, 0.05, backend=backend)
    distance = torch.linalg.norm(shell[index] - queries[:, None], dim=2).double().numpy()
    expected, _ = cKDTree(shell.double().numpy()).query(queries.double().numpy(), k=4)
    assert np.allclose(distance, expected, atol=1e-6)
    assert (index >= 0).all() and (np.diff(distance, axis=1) >= -1e-6).all()
    with pytest.raises(ValueError, match="k must be"):
        k_nearest(shell[:3], queries, 4, 0.05, backend=backend)


def scipy_components(points: torch.Tensor, radius: float) -> np.ndarray:
    pairs = cKDTree(points.double().numpy()).query_pairs(radius, output_type="ndarray")
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                                    shape=(points.shape[0],) * 2)
    return scipy.sparse.csgraph.connected_components(graph, directed=False)[1]


@pytest.mark.parametrize("backend", BACKENDS)
def test_connected_components_match_scipy(backend):
    points = clustered_points(3000, seed=3)
    radius = 0.07
    labels = connected_components(points, radius, backend=backend)
    expected = scipy_components(points, radius)
    # same partition: a bijection between the two labelings
    pairs = np.unique(np.stack([labels.numpy(), expected]), axis=1)
    assert pairs.shape[1] == len(np.unique(expected)) == int(labels.max()) + 1
    # numbered by smallest member, in order
    roots = component_roots(points, radius, backend=backend)
    assert (roots <= torch.arange(points.shape[0])).all()
    first_member = torch.zeros(int(labels.max()) + 1, dtype=torch.long).scatter_reduce(
        0, labels, torch.arange(points.shape[0]), reduce="amin", include_self=False)
    assert (first_member[1:] > first_member[:-1]).all()


@needs_cpp
def test_component_kernel_equals_twin_with_groups_and_is_deterministic():
    points = clustered_points(5000, seed=4)
    group = (points[:, 0] > 1.0).to(torch.int32)   # a plane cuts blobs into two groups
    roots_c = component_roots(points, 0.06, group, backend="cpp")
    roots_r = component_roots(points, 0.06, group, backend="reference")
    assert torch.equal(roots_c, roots_r)
    for _ in range(3):
        assert torch.equal(component_roots(points, 0.06, group, backend="cpp"), roots_c)
    assert (group[roots_c] == group).all()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("min_size", [1, 2, 8, 10, 12, 270])
def test_small_component_mask_matches_scipy_component_sizes(backend, min_size):
    points = clustered_points(3000, seed=5)
    radius = 0.11   # components of 1..13 scattered points and six blobs of 249..293
    labels = scipy_components(points, radius)
    sizes = np.bincount(labels)[labels]
    assert min_size == 1 or ((sizes < min_size).any() and (sizes >= min_size).any())
    mask = small_component_mask(points, radius, min_size, backend=backend)
    assert np.array_equal(mask.numpy(), sizes < min_size)


@pytest.mark.parametrize("backend", BACKENDS)
def test_small_component_mask_follows_sparse_chains(backend):
    # chains have 2 neighbours per point (never "core" for min_size 10): sizes must come from the
    # whole chain, and a short tail hanging off a dense blob belongs to the blob
    radius = 0.1
    step = 0.09 * torch.tensor([1.0, 0.0, 0.0])
    long_chain = torch.arange(12.0)[:, None] * step                       # 12 points: drawn
    short_chain = torch.arange(9.0)[:, None] * step + torch.tensor([0.0, 1.0, 0.0])  # 9: hidden
    blob = torch.tensor([0.0, 0.0, 1.0]) + 0.02 * torch.rand(30, 3, generator=torch.Generator().manual_seed(1))
    tail = blob[:1] + torch.arange(1.0, 4.0)[:, None] * step              # 3 points off the blob
    points = torch.cat([long_chain, short_chain, blob, tail])
    mask = small_component_mask(points, radius, 10, backend=backend)
    expected = torch.zeros(points.shape[0], dtype=torch.bool)
    expected[12:21] = True
    assert torch.equal(mask, expected)
    group = torch.zeros(points.shape[0], dtype=torch.int32)
    group[6:12] = 1                                   # cut the long chain into 6 + 6: both hidden
    expected[:12] = True
    assert torch.equal(small_component_mask(points, radius, 10, group, backend=backend), expected)


@needs_cpp
def test_small_component_kernel_equals_twin_with_groups():
    points = clustered_points(5000, seed=6)
    group = (points[:, 1] > 1.0).to(torch.int32)
    for min_size in (3, 10, 60):
        assert torch.equal(small_component_mask(points, 0.06, min_size, group, backend="cpp"),
                           small_component_mask(points, 0.06, min_size, group, backend="reference"))


def neighbour_counts(points: torch.Tensor, radius: float) -> np.ndarray:
    """Neighbours within radius of every point (itself excluded), float64."""
    tree = cKDTree(points.double().numpy())
    return np.array([len(n) - 1 for n in tree.query_ball_point(points.double().numpy(), radius)])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("min_size", [2, 10, 12])
def test_known_core_hint_leaves_the_small_fragment_mask_unchanged(backend, min_size):
    points = clustered_points(3000, seed=5)
    radius = 0.11
    sizes = np.bincount(scipy_components(points, radius))[scipy_components(points, radius)]
    # a hint naming a random 70 % of the true core points (>= min_size - 1 neighbours; counts
    # away from the float boundary would not differ, the blobs' points have dozens)
    core = neighbour_counts(points, radius - 1e-4) >= min_size - 1
    hint = torch.from_numpy(core) & (torch.rand(points.shape[0], generator=torch.Generator().manual_seed(3)) < 0.7)
    assert hint.any() and (~hint & torch.from_numpy(core)).any()
    mask = small_component_mask(points, radius, min_size, backend=backend, known_core=hint)
    assert np.array_equal(mask.numpy(), sizes < min_size)
    with pytest.raises(ValueError, match="known_core"):
        small_component_mask(points, radius, min_size, backend=backend, known_core=hint[:-1])


def rest_table(points: torch.Tensor, radius: float, k: int = 16) -> torch.Tensor:
    index, _ = knn_within(points, points, radius, k, query_self=torch.arange(points.shape[0]),
                          backend="reference")
    return index.to(torch.int32)


@needs_cpp
@pytest.mark.parametrize("device", KERNEL_DEVICES)
def test_retained_neighbours_kernel_equals_twin_and_counts(device):
    rest = clustered_points(3000, seed=7)
    radius = 0.1
    table = rest_table(rest, radius, k=12)
    generator = torch.Generator().manual_seed(8)
    moved = rest + 0.04 * torch.randn(rest.shape, generator=generator)   # neighbourhoods open
    rows = torch.randint(0, rest.shape[0], (2000,), generator=generator)
    kept = retained_neighbours(moved.to(device), rows.to(device), table[rows].to(device), radius,
                               backend="cpp").cpu()
    twin = retained_neighbours(moved, rows, table[rows], radius, backend="reference")
    assert kept.dtype == torch.int32 and torch.equal(kept, twin)
    listed = table[rows].long()
    distance = (moved[listed.clamp_min(0)] - moved[rows][:, None]).double().norm(dim=2)
    clear = ((distance - radius).abs() > 1e-5) | (listed < 0)
    expected = ((listed >= 0) & (distance <= radius)).sum(1)
    assert torch.equal(kept[clear.all(1)].long(), expected[clear.all(1)])
    assert 0 < int(kept.sum()) < int((listed >= 0).sum())      # some kept, some lost
    assert torch.equal(retained_neighbours(rest, rows, table[rows], radius, backend="cpp"),
                       (table[rows] >= 0).sum(1).to(torch.int32))   # at rest: every one kept


def cracked_block() -> dict[str, torch.Tensor]:
    """A jittered 20 x 12 x 12 lattice (spacing 1) cut at x = 9.5: the right part moved 2.5
    along x, a crumb of 4 points thrown off; fractured: the band |x - 9.5| < 3 and the crumb;
    own Gaussians on the outer layer."""
    axes = [torch.arange(20.0), torch.arange(12.0), torch.arange(12.0)]
    rest = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    rest = rest + 0.1 * torch.rand(rest.shape, generator=torch.Generator().manual_seed(4))
    lattice = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    moved = rest.clone()
    moved[lattice[:, 0] > 9.5, 0] += 2.5
    crumb = (lattice[:, 0] == 0) & (lattice[:, 1] == 0) & (lattice[:, 2] < 4)
    moved[crumb] += torch.tensor([-6.0, 0.0, 0.0])
    fractured = ((lattice[:, 0] - 9.5).abs() < 3) | crumb
    outer = ((lattice == 0) | (lattice == torch.tensor([19.0, 11.0, 11.0]))).any(1)
    return {"rest": rest, "x": moved, "fractured": fractured, "has_own": outer,
            "lattice": lattice, "crumb": crumb}


def block_rest_table(block: dict[str, torch.Tensor],
                     radius: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The block's rest-neighbour table (20 per point) and each row's count."""
    table = rest_table(block["rest"], radius, k=20)
    return table, (table >= 0).sum(1).to(torch.int32)


@needs_cpp
@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("all_interior", [False, True])
def test_fracture_neighbourhood_kernel_equals_twin(device, all_interior):
    block = cracked_block()
    radius = 1.5
    table, count = block_rest_table(block, radius)
    args = (table, count, radius, 10, 0.8, block["fractured"], block["has_own"], 2)
    on_device = [a.to(device) if isinstance(a, torch.Tensor) else a for a in args]
    kernel = fracture_neighbourhood(block["x"].to(device), *on_device, all_interior=all_interior,
                                    backend="cpp")
    twin = fracture_neighbourhood(block["x"], *args, all_interior=all_interior,
                                  backend="reference")
    for name, got, want in zip(kernel._fields, kernel, twin):
        assert torch.equal(got.cpu(), want), name
    hidden, exposed, queries, neighbours = twin
    lattice = block["lattice"]
    assert torch.equal(hidden, block["crumb"])                  # the crumb of 4 points
    face = (lattice[:, 0] == 9) | (lattice[:, 0] == 10)         # the two faces of the cut
    deep = ~block["has_own"] & ((lattice[:, 0] - 9.5).abs() > 2)  # inside, away from the cut
    # the faces lose the neighbours across the cut (5 of the 16..20 at rest on this jittered
    # lattice; a few face points whose rest neighbourhood the jitter thinned keep just over 80 %)
    tested = face & block["fractured"] & ~block["has_own"]      # exposure is only asked there
    assert exposed[tested].float().mean() > 0.95 and not exposed[deep].any()
    assert not exposed[block["has_own"] | ~block["fractured"]].any()
    drawn = block["fractured"] & ~hidden
    if not all_interior:
        drawn &= block["has_own"] | exposed
    assert torch.equal(queries, torch.nonzero(drawn).flatten())
    found = neighbours >= 0
    partners = neighbours[found]
    assert not block["fractured"][partners].any() and not hidden[partners].any()
    gaps = (block["x"][partners] - block["x"][queries[:, None].expand_as(neighbours)[found]]).norm(dim=1)
    assert (gaps <= radius + 1e-5).all()


@needs_cpp
def test_fracture_neighbourhood_where_every_point_keeps_its_neighbours():
    # min_size 5: every point of the block keeps at least 4 of its rest neighbours (the fewest
    # keep 5), so the hint names all of them and the op skips the small-fragment search; with the
    # crumb thrown off (a line of 4 points, 1-2 neighbours each) it must run it
    block = cracked_block()
    radius = 1.5
    table, count = block_rest_table(block, radius)
    intact_crumb = block["x"].clone()
    intact_crumb[block["crumb"]] = block["rest"][block["crumb"]]   # the crumb not thrown off
    for x, hidden_expected in ((intact_crumb, torch.zeros_like(block["crumb"])),
                               (block["x"], block["crumb"])):
        args = (table, count, radius, 5, 0.8, block["fractured"], block["has_own"], 2)
        kernel = fracture_neighbourhood(x, *args, backend="cpp")
        twin = fracture_neighbourhood(x, *args, backend="reference")
        for name, got, want in zip(kernel._fields, kernel, twin):
            assert torch.equal(got, want), name
        assert torch.equal(kernel.hidden, hidden_expected)


@needs_cpp
def test_rest_table_entries_that_index_no_point_are_errors():
    block = cracked_block()
    radius = 1.5
    table, count = block_rest_table(block, radius)
    n = block["x"].shape[0]
    rows = torch.arange(n)
    for bad in (n, -2):
        broken = table.clone()
        broken[7, 0] = bad       # the first entry of a row is always read
        with pytest.raises(RuntimeError, match="table entries must be -1 or index points"):
            retained_neighbours(block["x"], rows, broken, radius, backend="cpp")
        with pytest.raises(RuntimeError, match="table entries must be -1 or index points"):
            fracture_neighbourhood(block["x"], broken, count, radius, 10, 0.8, block["fractured"],
                                   block["has_own"], 2, backend="cpp")


def random_deformations(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    F = torch.eye(3) + 0.3 * torch.randn(count, 3, 3, generator=generator)
    F[::17, :, 0] *= -1.0   # some inverted elements
    return F


@needs_cpp
def test_deform_kernel_equals_twin():
    generator = torch.Generator().manual_seed(5)
    n, m = 300, 500
    x = torch.rand(n, 3, generator=generator)
    F = random_deformations(n, seed=6)
    driver = torch.randint(0, n, (m,), generator=generator)
    offset = 0.01 * torch.randn(m, 3, generator=generator)
    A = torch.randn(m, 3, 3, generator=generator)
    cov0 = 1e-4 * (A @ A.transpose(1, 2) + 0.1 * torch.eye(3))
    rotations = reference.polar_rotation(torch.randn(2, 3, 3, generator=generator))
    objects = torch.randint(0, 2, (m,), generator=generator)
    compiled = deform_gaussians(x, F, driver, offset, cov0, rotations, objects, backend="cpp")
    twin = deform_gaussians(x, F, driver, offset, cov0, rotations, objects, backend="reference")
    assert torch.allclose(compiled.means, twin.means, atol=1e-6)
    assert torch.allclose(compiled.covariances, twin.covariances, rtol=1e-5, atol=1e-10)
    assert torch.allclose(compiled.view_rotations, twin.view_rotations, atol=2e-5)
    rot = compiled.view_rotations.double()
    assert torch.allclose(rot @ rot.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(m, 3, 3),
                          atol=1e-5)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(m, dtype=torch.float64), atol=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_deformation_is_the_polar_rotation_and_the_pushed_covariance(backend):
    # F = Q S (rotation times symmetric stretch): the Gaussian turns by Q, Σ_t = F Σ0 Fᵀ
    angle = 0.7
    Q = torch.tensor([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0],
                      [0.0, 0.0, 1.0]], dtype=torch.float32)
    S = torch.tensor([[1.2, 0.1, 0.0], [0.1, 0.9, 0.0], [0.0, 0.0, 1.05]])
    F = (Q @ S)[None]
    cov0 = torch.diag(torch.tensor([1e-4, 4e-4, 9e-4]))[None]
    out = deform_gaussians(torch.tensor([[0.5, 0.5, 0.5]]), F, torch.tensor([0]),
                           torch.tensor([[0.01, 0.0, 0.0]]), cov0, torch.eye(3)[None],
                           torch.tensor([0]), backend=backend)
    assert torch.allclose(out.view_rotations[0], Q, atol=1e-6)
    assert torch.allclose(out.covariances[0], F[0] @ cov0[0] @ F[0].T, rtol=1e-5)
    assert torch.allclose(out.means[0], torch.tensor([0.5, 0.5, 0.5]) + 0.01 * F[0][:, 0], atol=1e-7)


@needs_cpp
def test_lens_kernel_equals_twin_on_every_regime():
    generator = torch.Generator().manual_seed(7)
    p = 4000
    ci = torch.rand(p, 3, generator=generator)
    cj = ci + 0.2 * torch.randn(p, 3, generator=generator)
    cj[::50] = ci[::50]                                  # coincident centres
    ri = 0.01 + 0.2 * torch.rand(p, generator=generator)
    rj = 0.01 + 0.2 * torch.rand(p, generator=generator)
    rj[::13] = ri[::13]                                  # equal radii
    compiled = lens_ellipsoids(ci, ri, cj, rj, 2.0, backend="cpp")
    twin = lens_ellipsoids(ci, ri, cj, rj, 2.0, backend="reference")
    assert torch.equal(compiled.valid, twin.valid)
    assert 0.2 < compiled.valid.float().mean() < 0.9   # the sample covers all regimes
    for name in ("centre", "scales", "rotation", "covariance"):
        assert torch.allclose(getattr(compiled, name), getattr(twin, name), atol=2e-6), name
