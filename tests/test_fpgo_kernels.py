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
from fracture_gs.fracture.spatial import component_roots, connected_components, knn_within

needs_cpp = pytest.mark.extension("spatial_knn_within", "spatial_component_roots",
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
