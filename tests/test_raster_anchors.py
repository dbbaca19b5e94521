"""Outside anchors for the rasterizer: pixel values computed by hand from the 3DGS rules.

The other raster tests compare the C++ kernels with the torch twin; if both shared a wrong
rule they would agree. Here every expected number comes from the formulas of docs/formulas.md §11 / 3DGS
(Kerbl et al. 2023) written out in the test, never from ``fracture_gs.render.reference``:

* a camera-space point (x, y, z) lands on (fx x/z + cx, fy y/z + cy); pixel (i, j) has its
  centre at (i + 0.5, j + 0.5);
* 2D covariance J Σ Jᵀ with J = [[fx/z, 0, -fx x/z²], [0, fy/z, -fy y/z²]], plus 0.3 px² on the
  diagonal; radius = ceil(3 √λ_max);
* α = min(0.99, o · exp(-½ dᵀ Σ₂⁻¹ d)); entries with α < 1/255 are skipped; front to back,
  a pixel stops before the entry that would take T below 1e-4;
* rgb = Σ wₖ cₖ + T_final · background, alpha = 1 - T_final, depth = Σ wₖ zₖ (camera z),
  wₖ = αₖ Tₖ;
* colour = max(0, Σ Yₖ(d) shₖ + 0.5) with the real SH basis of 3DGS, d the unit vector from the
  camera centre to the mean.

Both backends run every anchor: the torch reference always, the C++ kernels when built.
"""
from __future__ import annotations

import math

import pytest
import torch

from fracture_gs.render import Camera, rasterize

BACKENDS = [pytest.param("cpp", marks=pytest.mark.extension("raster_forward")), "reference"]
FOCAL = 20.0
SIZE = 24           # 24 x 24 pixels: two 16-pixel tiles per axis
TOLERANCE = 2e-6    # float32 kernels, values of order 1


def camera_with_mean_at(pixel: tuple[int, int], point: tuple[float, float, float],
                        focal: float = FOCAL) -> Camera:
    """Identity pose; principal point placed so ``point`` projects onto the centre of
    ``pixel`` (column, row)."""
    x, y, z = point
    cx = pixel[0] + 0.5 - focal * x / z
    cy = pixel[1] + 0.5 - focal * y / z
    return Camera(torch.eye(4), focal, focal, cx, cy, SIZE, SIZE, near=0.01)


def render(backend: str, camera: Camera, means: list[list[float]], opacities: list[float],
           *, scales: list[list[float]] | None = None, quats: list[list[float]] | None = None,
           colors: list[list[float]] | None = None, sh: torch.Tensor | None = None,
           background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict[str, torch.Tensor]:
    n = len(means)
    scales_t = torch.tensor(scales if scales is not None else [[0.1, 0.1, 0.1]] * n)
    quats_t = torch.tensor(quats if quats is not None else [[1.0, 0.0, 0.0, 0.0]] * n)
    kwargs = {"sh": sh} if sh is not None else {"colors": torch.tensor(colors)}
    return rasterize(torch.tensor(means), torch.tensor(opacities), camera, scales=scales_t,
                     quats=quats_t, background=torch.tensor(background), backend=backend,
                     **kwargs)


def gaussian_alpha(opacity: float, offset: tuple[float, float], cov: tuple[float, float, float]
                   ) -> float:
    """o · exp(-½ dᵀ Σ⁻¹ d) for Σ = [[a, b], [b, c]] (the 1/255 cut and 0.99 clamp are left to
    the caller)."""
    a, b, c = cov
    dx, dy = offset
    det = a * c - b * b
    power = -0.5 * (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
    return opacity * math.exp(power)


@pytest.mark.parametrize("backend", BACKENDS)
def test_one_gaussian_at_known_offsets(backend: str) -> None:
    """Isotropic σ = 0.1 at z = 2 seen with f = 20: (f σ / z)² = 1 px², 1.3 px² with the
    low-pass. The mean sits on the centre of pixel (10, 12)."""
    mean = (0.0, 0.0, 2.0)
    camera = camera_with_mean_at((10, 12), mean)
    colour, background = (0.2, 0.5, 0.9), (0.1, 0.3, 0.05)
    out = render(backend, camera, [list(mean)], [0.8], colors=[list(colour)],
                 background=background)
    variance = 1.0 + 0.3
    for offset in [(0, 0), (1, 0), (0, -1), (1, 1), (-2, 1), (3, 0), (2, -2)]:
        alpha = gaussian_alpha(0.8, offset, (variance, 0.0, variance))
        column, row = 10 + offset[0], 12 + offset[1]
        assert float(out["alpha"][row, column]) == pytest.approx(alpha, abs=TOLERANCE), offset
        expected_rgb = [alpha * c + (1 - alpha) * b for c, b in zip(colour, background)]
        assert out["rgb"][row, column].tolist() == pytest.approx(expected_rgb, abs=TOLERANCE)
        assert float(out["depth"][row, column]) == pytest.approx(alpha * 2.0, abs=TOLERANCE)
    # A pixel the Gaussian cannot reach (α far below 1/255) shows exactly the background.
    assert out["rgb"][0, 0].tolist() == list(torch.tensor(background).tolist())
    assert float(out["alpha"][0, 0]) == 0.0 and float(out["depth"][0, 0]) == 0.0
    # radius = ceil(3 √λmax) = ceil(3 √1.3) = 4
    assert out["radii"].tolist() == [math.ceil(3 * math.sqrt(variance))]


@pytest.mark.parametrize("backend", BACKENDS)
def test_pixel_centres_are_at_half_integers(backend: str) -> None:
    """The mean on the pixel corner (10, 12) (not a centre): the four pixels around it are
    equal, each at offset (±0.5, ±0.5). Integer pixel centres would put one pixel at the peak."""
    mean = (0.0, 0.0, 2.0)
    camera = camera_with_mean_at((10, 12), mean)
    camera = Camera(torch.eye(4), FOCAL, FOCAL, camera.cx - 0.5, camera.cy - 0.5, SIZE, SIZE)
    out = render(backend, camera, [list(mean)], [0.9], colors=[[1.0, 1.0, 1.0]])
    expected = gaussian_alpha(0.9, (0.5, 0.5), (1.3, 0.0, 1.3))
    block = out["alpha"][11:13, 9:11]
    assert block.flatten().tolist() == pytest.approx([expected] * 4, abs=TOLERANCE)


@pytest.mark.parametrize("backend", BACKENDS)
def test_anisotropic_and_rotated_covariance(backend: str) -> None:
    """scales (0.2, 0.05, 0.1) rotated 90° about the camera z axis by the quaternion
    (cos 45°, 0, 0, sin 45°) (w x y z): the long axis turns from image x to image y."""
    mean = (0.0, 0.0, 2.0)
    camera = camera_with_mean_at((12, 12), mean)
    half = math.sqrt(0.5)
    out = render(backend, camera, [list(mean)], [0.7], scales=[[0.2, 0.05, 0.1]],
                 quats=[[half, 0.0, 0.0, half]], colors=[[1.0, 1.0, 1.0]])
    scale_px = FOCAL / 2.0
    cov = ((0.05 * scale_px) ** 2 + 0.3, 0.0, (0.2 * scale_px) ** 2 + 0.3)  # x: 0.55, y: 4.3
    for offset in [(1, 0), (0, 1), (0, 3), (2, 2)]:
        expected = gaussian_alpha(0.7, offset, cov)
        value = float(out["alpha"][12 + offset[1], 12 + offset[0]])
        assert value == pytest.approx(expected, abs=TOLERANCE), offset


@pytest.mark.parametrize("backend", BACKENDS)
def test_off_axis_gaussian_uses_the_perspective_jacobian(backend: str) -> None:
    """An isotropic Gaussian at x/z = 0.3: J's third column -f x/z² stretches the footprint
    along image x by (1 + (x/z)²) and correlates nothing along y."""
    mean = (0.6, 0.0, 2.0)
    camera = camera_with_mean_at((12, 12), mean)
    out = render(backend, camera, [list(mean)], [0.75], colors=[[1.0, 1.0, 1.0]])
    s2 = (FOCAL * 0.1 / 2.0) ** 2  # (f σ / z)² = 1
    cov = (s2 * (1 + 0.3 ** 2) + 0.3, 0.0, s2 + 0.3)
    for offset in [(2, 0), (0, 2), (1, 1), (-2, 1)]:
        expected = gaussian_alpha(0.75, offset, cov)
        value = float(out["alpha"][12 + offset[1], 12 + offset[0]])
        assert value == pytest.approx(expected, abs=TOLERANCE), offset
    # depth is camera z (2), not the distance from the camera (√(0.6² + 2²) ≈ 2.088)
    assert float(out["depth"][12, 12]) == pytest.approx(0.75 * 2.0, abs=TOLERANCE)


@pytest.mark.parametrize("backend", BACKENDS)
def test_alpha_is_clamped_at_0_99(backend: str) -> None:
    mean = (0.0, 0.0, 2.0)
    camera = camera_with_mean_at((10, 10), mean)
    out = render(backend, camera, [list(mean)], [1.0], colors=[[0.0, 1.0, 0.5]],
                 background=(1.0, 0.0, 0.0))
    assert float(out["alpha"][10, 10]) == pytest.approx(0.99, abs=TOLERANCE)
    assert out["rgb"][10, 10].tolist() == pytest.approx([0.01, 0.99, 0.495], abs=TOLERANCE)
    # one pixel away α = exp(-½ / 1.3) ≈ 0.68 is below the clamp
    assert float(out["alpha"][10, 11]) == pytest.approx(math.exp(-0.5 / 1.3), abs=TOLERANCE)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("ratio", [1.002, 0.998])
def test_alphas_below_1_over_255_are_skipped(backend: str, ratio: float) -> None:
    """At offset (3, 1) the Gaussian factor is g = exp(-½ · 10 / 1.3); the opacity puts α at
    1.002/255 (blended) or 0.998/255 (skipped: the pixel is exactly the background)."""
    mean = (0.0, 0.0, 2.0)
    camera = camera_with_mean_at((10, 10), mean)
    g = math.exp(-0.5 * 10 / 1.3)
    opacity = ratio / 255.0 / g
    background = (0.25, 0.5, 0.75)
    out = render(backend, camera, [list(mean)], [opacity], colors=[[1.0, 0.0, 0.0]],
                 background=background)
    value = out["rgb"][11, 13].tolist()
    if ratio > 1:
        alpha = ratio / 255.0
        assert float(out["alpha"][11, 13]) == pytest.approx(alpha, rel=1e-5)
        assert value == pytest.approx([alpha + (1 - alpha) * b if i == 0 else (1 - alpha) * b
                                       for i, b in enumerate(background)], abs=TOLERANCE)
    else:
        assert float(out["alpha"][11, 13]) == 0.0
        assert value == list(background)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("last_transmittance", [1.02e-4, 0.98e-4])
def test_front_to_back_until_transmittance_below_1e_4(backend: str,
                                                      last_transmittance: float) -> None:
    """Three Gaussians on one pixel, given out of depth order, each with the same α there,
    chosen so that T after the third would be 1.02e-4 (it is blended) or 0.98e-4 (the pixel stops
    before it). The third (farthest) one is pure red, so red = its weight or exactly 0."""
    alpha = 1.0 - last_transmittance ** (1.0 / 3.0)
    depths = [3.0, 2.0, 4.0]                       # input order; blending order 2, 3, 4
    colours = {2.0: [0.0, 1.0, 0.0], 3.0: [0.0, 0.0, 1.0], 4.0: [1.0, 0.0, 0.0]}
    camera = camera_with_mean_at((10, 10), (0.0, 0.0, 2.0))
    out = render(backend, camera, [[0.0, 0.0, z] for z in depths], [alpha] * 3,
                 scales=[[0.05 * z] * 3 for z in depths],
                 colors=[colours[z] for z in depths], background=(0.0, 0.0, 0.0))
    blended = 3 if last_transmittance >= 1e-4 else 2
    weights = [alpha * (1.0 - alpha) ** k for k in range(blended)]
    expected_rgb = [sum(w * colours[z][ch] for w, z in zip(weights, (2.0, 3.0, 4.0)))
                    for ch in range(3)]
    assert out["rgb"][10, 10].tolist() == pytest.approx(expected_rgb, abs=TOLERANCE)
    if blended == 2:
        assert float(out["rgb"][10, 10, 0]) == 0.0   # the red third Gaussian is not blended
    assert float(out["alpha"][10, 10]) == pytest.approx(1 - (1 - alpha) ** blended,
                                                        abs=TOLERANCE)
    expected_depth = sum(w * z for w, z in zip(weights, (2.0, 3.0, 4.0)))
    assert float(out["depth"][10, 10]) == pytest.approx(expected_depth, abs=5 * TOLERANCE)


@pytest.mark.parametrize("backend", BACKENDS)
def test_two_layers_blend_with_the_background(backend: str) -> None:
    """α = 0.5 at z = 2 in front of α = 0.6 at z = 3: w = 0.5 and 0.3, T_final = 0.2."""
    camera = camera_with_mean_at((8, 8), (0.0, 0.0, 2.0))
    out = render(backend, camera, [[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]], [0.6, 0.5],
                 scales=[[0.15] * 3, [0.1] * 3], colors=[[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
                 background=(0.0, 1.0, 0.0))
    assert out["rgb"][8, 8].tolist() == pytest.approx([0.5, 0.2, 0.3], abs=TOLERANCE)
    assert float(out["alpha"][8, 8]) == pytest.approx(0.8, abs=TOLERANCE)
    assert float(out["depth"][8, 8]) == pytest.approx(0.5 * 2 + 0.3 * 3, abs=TOLERANCE)


# --------------------------------------------------------------------------- spherical harmonics

SQRT_PI = math.sqrt(math.pi)


def sh_basis_by_hand(x: float, y: float, z: float) -> list[float]:
    """The 16 real SH basis functions in 3DGS's order and signs, constants from their closed
    forms (l = 0: 1/(2√π); l = 1: √3/(2√π); l = 2: √15/(2√π), √5/(4√π), √15/(4√π);
    l = 3: √(35/2)/(4√π), √105/(2√π), √(21/2)/(4√π), √7/(4√π), √105/(4√π))."""
    c0 = 1 / (2 * SQRT_PI)
    c1 = math.sqrt(3) / (2 * SQRT_PI)
    c2a, c2b, c2c = math.sqrt(15) / (2 * SQRT_PI), math.sqrt(5) / (4 * SQRT_PI), \
        math.sqrt(15) / (4 * SQRT_PI)
    c3a, c3b = math.sqrt(35 / 2) / (4 * SQRT_PI), math.sqrt(105) / (2 * SQRT_PI)
    c3c, c3d = math.sqrt(21 / 2) / (4 * SQRT_PI), math.sqrt(7) / (4 * SQRT_PI)
    c3e = math.sqrt(105) / (4 * SQRT_PI)
    xx, yy, zz = x * x, y * y, z * z
    return [c0,
            -c1 * y, c1 * z, -c1 * x,
            c2a * x * y, -c2a * y * z, c2b * (2 * zz - xx - yy), -c2a * x * z, c2c * (xx - yy),
            -c3a * y * (3 * xx - yy), c3b * x * y * z, -c3c * y * (4 * zz - xx - yy),
            c3d * z * (2 * zz - 3 * xx - 3 * yy), -c3c * x * (4 * zz - xx - yy),
            c3e * z * (xx - yy), -c3a * x * (xx - 3 * yy)]


def test_hand_constants_are_the_published_ones() -> None:
    """The closed forms above equal the decimal constants printed in 3DGS's sh_utils."""
    basis = sh_basis_by_hand(1.0, 0.0, 0.0)
    assert basis[0] == pytest.approx(0.28209479177387814, rel=1e-15)
    assert -basis[3] == pytest.approx(0.4886025119029199, rel=1e-15)
    assert basis[8] == pytest.approx(0.5462742152960396, rel=1e-15)
    assert -basis[15] == pytest.approx(0.5900435899266435, rel=1e-15)
    assert sh_basis_by_hand(0.0, 0.0, 1.0)[6] == pytest.approx(2 * 0.31539156525252005, rel=1e-15)


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_colours_of_degree_0_to_3_at_a_known_direction(backend: str) -> None:
    """Sixteen Gaussians in a row, all seen from the origin along their own direction; Gaussian
    k has only coefficient k set (0.4 in red, -0.4 in green): its colour is 0.5 ± 0.4 Yₖ(d).
    Opacity 0.5 and a black background make the centre pixel rgb = 0.5 · colour."""
    degree_terms = 16
    colours_seen = []
    expected = []
    for k in range(degree_terms):
        mean = (0.05 * (k - 7.5), -0.3, 1.2)       # distinct, non-axial directions
        norm = math.sqrt(sum(c * c for c in mean))
        direction = tuple(c / norm for c in mean)
        sh = torch.zeros(1, degree_terms, 3)
        sh[0, k, 0], sh[0, k, 1] = 0.4, -0.4
        camera = camera_with_mean_at((12, 12), mean)
        out = render(backend, camera, [list(mean)], [0.5], scales=[[0.02] * 3], sh=sh)
        basis = sh_basis_by_hand(*direction)[k]
        colours_seen.append(out["rgb"][12, 12].tolist())
        expected.append([0.5 * max(0.0, 0.5 + 0.4 * basis), 0.5 * max(0.0, 0.5 - 0.4 * basis),
                         0.5 * 0.5])
    for k, (seen, want) in enumerate(zip(colours_seen, expected)):
        assert seen == pytest.approx(want, abs=TOLERANCE), f"coefficient {k}"


@pytest.mark.parametrize("backend", BACKENDS)
def test_sh_colour_is_clamped_at_zero(backend: str) -> None:
    """A DC coefficient of -2 gives 0.5 - 2 · 0.2821 < 0: the colour clamps to 0, so the pixel
    is (1 - α) · background."""
    sh = torch.zeros(1, 1, 3)
    sh[0, 0] = torch.tensor([-2.0, 0.0, 1.0])
    mean = (0.0, 0.0, 2.0)
    out = render(backend, camera_with_mean_at((5, 5), mean), [list(mean)], [0.5], sh=sh,
                 background=(0.2, 0.2, 0.2))
    dc = 1 / (2 * SQRT_PI)
    assert out["rgb"][5, 5].tolist() == pytest.approx(
        [0.1, 0.5 * 0.5 + 0.1, 0.5 * (0.5 + dc) + 0.1], abs=TOLERANCE)
