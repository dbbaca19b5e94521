"""FPGO lens ellipsoids (docs/formulas.md §13 step 4, paper App. A.4) on hand-computed sphere pairs.

Every case runs on the compiled kernel and on its torch twin.
"""
from __future__ import annotations

import math

import pytest
import torch

from fracture_gs.fracture.ops import lens_ellipsoids

BACKENDS = ["reference",
            pytest.param("cpp", marks=pytest.mark.extension("fracture_lens_ellipsoids"))]


def lens(ci, ri, cj, rj, backend, k_sigma=2.0):
    out = lens_ellipsoids(torch.tensor([ci], dtype=torch.float32), torch.tensor([ri]),
                          torch.tensor([cj], dtype=torch.float32), torch.tensor([rj]), k_sigma,
                          backend=backend)
    return {name: value[0] for name, value in out._asdict().items()}


def check_frame(result, u):
    """R is a proper rotation whose first column is u, and Σ = R diag(s²) Rᵀ."""
    rotation, scales = result["rotation"].double(), result["scales"].double()
    assert torch.allclose(rotation.T @ rotation, torch.eye(3, dtype=torch.float64), atol=1e-6)
    assert torch.linalg.det(rotation).item() == pytest.approx(1.0, abs=1e-6)
    assert torch.allclose(rotation[:, 0], torch.tensor(u, dtype=torch.float64), atol=1e-6)
    expected = rotation @ torch.diag(scales ** 2) @ rotation.T
    assert torch.allclose(result["covariance"].double(), expected, atol=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_equal_spheres_lens_touches_tips_and_circle(backend):
    # r = 1, d = 1 along x: lens from x = 0 to x = 1, circle of radius sqrt(3)/2 at x = 1/2
    result = lens((0, 0, 0), 1.0, (1, 0, 0), 1.0, backend)
    assert bool(result["valid"])
    assert torch.allclose(result["centre"], torch.tensor([0.5, 0.0, 0.0]), atol=1e-7)
    semi = result["scales"] * 2.0  # k_sigma = 2
    assert semi[0].item() == pytest.approx(0.5, abs=1e-6)           # (r_i + r_j - d) / 2
    assert semi[1].item() == pytest.approx(math.sqrt(0.75), abs=1e-6)
    assert semi[2].item() == pytest.approx(math.sqrt(0.75), abs=1e-6)
    check_frame(result, (1.0, 0.0, 0.0))
    # the ellipsoid passes through both lens tips and the whole intersection circle
    inverse = torch.linalg.inv(result["covariance"].double() * 4.0)  # semi-axes, not scales
    centre = result["centre"].double()
    on_lens = [torch.tensor(p, dtype=torch.float64) for p in
               ((0, 0, 0), (1, 0, 0), (0.5, math.sqrt(0.75), 0), (0.5, 0, -math.sqrt(0.75)),
                (0.5, math.sqrt(0.375), math.sqrt(0.375)))]
    for point in on_lens:
        offset = point - centre
        assert (offset @ inverse @ offset).item() == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("backend", BACKENDS)
def test_unequal_spheres_follow_the_formulas(backend):
    # r_i = 2, r_j = 1, d = 2 along u = (0, 0.6, 0.8); h = (d² + r_i² - r_j²) / 2d = 1.75
    ci = (1.0, 1.0, 1.0)
    u = (0.0, 0.6, 0.8)
    cj = tuple(c + 2.0 * a for c, a in zip(ci, u))
    result = lens(ci, 2.0, cj, 1.0, backend, k_sigma=3.0)
    assert bool(result["valid"])
    expected_centre = torch.tensor([c + (2.0 / 3.0) * 2.0 * a for c, a in zip(ci, u)])
    assert torch.allclose(result["centre"], expected_centre, atol=1e-6)
    semi = result["scales"] * 3.0
    assert semi[0].item() == pytest.approx(0.5, abs=1e-6)
    assert semi[1].item() == pytest.approx(math.sqrt(4.0 - 1.75 ** 2), abs=1e-6)
    assert semi[2].item() == pytest.approx(semi[1].item(), abs=1e-7)
    check_frame(result, u)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("distance", [3.0, 3.0 + 1e-6, 10.0])  # tangent, just apart, far apart
def test_tangent_and_disjoint_spheres_give_nothing(backend, distance):
    result = lens((0, 0, 0), 2.0, (0, distance, 0), 1.0, backend)
    assert not bool(result["valid"])
    assert torch.all(result["scales"] == 0)
    assert torch.all(result["covariance"] == 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_contained_sphere_is_its_own_ellipsoid(backend):
    # the overlap of a sphere inside another is the smaller sphere
    small_j = lens((0, 0, 0), 2.0, (0, 0, 1.0), 0.5, backend)
    assert bool(small_j["valid"])
    assert torch.allclose(small_j["centre"], torch.tensor([0.0, 0.0, 1.0]))
    assert torch.allclose(small_j["scales"], torch.full((3,), 0.25))
    assert torch.allclose(small_j["covariance"], 0.0625 * torch.eye(3))
    small_i = lens((0, 0, 0), 0.5, (0, 0, 1.0), 2.0, backend)
    assert torch.allclose(small_i["centre"], torch.zeros(3))
    assert torch.allclose(small_i["scales"], torch.full((3,), 0.25))
    # internally tangent (d = |r_i - r_j|) counts as contained
    touching = lens((0, 0, 0), 2.0, (1.5, 0, 0), 0.5, backend)
    assert torch.allclose(touching["centre"], torch.tensor([1.5, 0.0, 0.0]))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("ci,ri,cj,rj", [
    ((0.3, 0.2, 0.1), 1.0, (0.3, 0.2, 0.1), 1.0),     # d = 0, r_i = r_j
    ((0.3, 0.2, 0.1), 1.0, (0.3, 0.2, 0.1), 0.4),     # d = 0, r_i != r_j
    ((0.0, 0.0, 0.0), 1.0, (1e-7, 0.0, 0.0), 1.0),    # d -> 0, r_i = r_j
    ((0.0, 0.0, 0.0), 1.0, (0.0, 0.0, 1e-30), 1.0),   # d underflows
    ((0.0, 0.0, 0.0), 0.0, (0.5, 0.0, 0.0), 1.0),     # zero radius
])
def test_degenerate_pairs_have_no_nan(backend, ci, ri, cj, rj):
    result = lens(ci, ri, cj, rj, backend)
    for name in ("centre", "scales", "rotation", "covariance"):
        assert torch.isfinite(result[name]).all(), name
    if ri > 0:
        assert bool(result["valid"])
        assert torch.linalg.det(result["rotation"].double()).item() == pytest.approx(1.0, abs=1e-6)
        assert result["scales"].max().item() <= max(ri, rj) / 2.0 + 1e-6
