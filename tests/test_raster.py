"""The C++ Gaussian rasterizer against its dense PyTorch twin (docs/formulas.md §11)."""
from __future__ import annotations


import pytest
import torch

from fracture_gs.render import Camera, rasterize, rasterize_reference
from kernel_devices import KERNEL_DEVICES
from raster_scenes import make_camera, random_scene, split

needs_cpp = pytest.mark.extension("raster_forward")  # tests/conftest.py: skipped without _C, failed in CI
BACKENDS = [pytest.param("cpp", marks=needs_cpp), "reference"]

WIDTH, HEIGHT = 37, 29  # not multiples of 16


def _config(seed: int) -> dict:
    return {"sh_degree": [None, 0, 1, 2, 3][seed % 5], "full_covariance": seed % 2 == 1,
            "exclusive": [False, True, "groups"][(seed // 2) % 3], "view_rotations": seed % 3 == 0}


def _on(scene: dict, device: str) -> dict:
    return {k: v.to(device) for k, v in scene.items()}


def _compiled(scene: dict, camera: Camera, device: str = "cpu") -> dict:
    """The compiled rasterizer on ``device``; outputs on the CPU."""
    means, opacities, kwargs = split(_on(scene, device))
    return {k: v.cpu() for k, v in rasterize(means, opacities, camera, backend="cpp", **kwargs).items()}


def _render_both(scene: dict, camera: Camera, reference_dtype: torch.dtype = torch.float64, device: str = "cpu"):
    cpp = _compiled(scene, camera, device)
    ref_scene = {k: (v.to(reference_dtype) if v.is_floating_point() else v) for k, v in scene.items()}
    means_r, opacities_r, kwargs_r = split(ref_scene)
    ref = rasterize_reference(means_r, opacities_r, camera, **kwargs_r)
    return cpp, ref


@needs_cpp
@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("seed", range(24))
def test_forward_matches_reference(seed: int, device: str) -> None:
    config = _config(seed)
    scene = random_scene(seed, 80, **config)
    camera = make_camera(WIDTH, HEIGHT, seed)
    cpp, ref = _render_both(scene, camera, device=device)
    if device != "cpu":  # the CPU kernel's image is the reference of the CUDA one
        cpu = _compiled(scene, camera)
        for key in ("rgb", "alpha", "depth"):
            assert (cpp[key] - cpu[key]).abs().max().item() <= 1e-4, key
        assert torch.equal(cpp["radii"], cpu["radii"])
    assert ref["alpha"].max() > 0.5  # the scene is actually visible
    for key in ("rgb", "alpha", "depth"):
        err = (cpp[key].double() - ref[key]).abs().max().item()
        assert err <= 1e-4, f"{key}: max abs error {err} ({config})"
    assert torch.equal(cpp["radii"], ref["radii"])
    visible = ref["radii"] > 0
    assert (cpp["means2d"][visible].double() - ref["means2d"][visible]).abs().max() < 1e-3


def _loss_weights(height: int, width: int, seed: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(seed)
    return (torch.randn(height, width, 3, generator=gen, dtype=torch.float64),
            torch.randn(height, width, generator=gen, dtype=torch.float64),
            torch.randn(height, width, generator=gen, dtype=torch.float64))


def _gradients(render, scene: dict, camera: Camera, weights) -> dict[str, torch.Tensor]:
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items() if v.is_floating_point()}
    full = {**scene, **leaves}
    means, opacities, kwargs = split(full)
    out = render(means, opacities, camera, **kwargs)
    loss = ((out["rgb"].double() * weights[0]).sum() + (out["alpha"].double() * weights[1]).sum()
            + (out["depth"].double() * weights[2]).sum())
    loss.backward()
    # An input the image does not depend on (view rotations of degree-0 SH) has no grad.
    grads = {k: (torch.zeros_like(v) if v.grad is None else v.grad).double()
             for k, v in leaves.items()}
    grads["means2d"] = out["means2d"].grad.double()
    return grads


def _compiled_gradients(scene: dict, camera: Camera, weights, device: str) -> dict[str, torch.Tensor]:
    """Gradients of the compiled rasterizer on ``device`` (on the CPU, float64)."""
    on_device = _gradients(lambda *a, **k: rasterize(*a, backend="cpp", **k), _on(scene, device), camera,
                           tuple(w.to(device) for w in weights))
    return {k: v.cpu() for k, v in on_device.items()}


@needs_cpp
@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("seed", range(10))
def test_gradients_match_reference(seed: int, device: str) -> None:
    config = _config(seed)
    scene = random_scene(100 + seed, 40, **config)
    camera = make_camera(WIDTH, HEIGHT, seed)
    weights = _loss_weights(HEIGHT, WIDTH, seed)
    cpp = _compiled_gradients(scene, camera, weights, device)
    ref_scene = {k: (v.double() if v.is_floating_point() else v) for k, v in scene.items()}
    ref = _gradients(rasterize_reference, ref_scene, camera, weights)
    assert set(cpp) == set(ref)
    if device != "cpu":  # the CPU kernel's gradients are the reference of the CUDA ones
        cpu = _compiled_gradients(scene, camera, weights, "cpu")
        for name, g_cpu in cpu.items():
            scale = max(g_cpu.abs().max().item(), 1e-12)
            assert (cpp[name] - g_cpu).abs().max().item() <= 1e-3 * scale, name
    for name, g_ref in ref.items():
        g_cpp = cpp[name]
        scale = g_ref.abs().max().item()
        if scale == 0:
            assert g_cpp.abs().max() < 1e-6, name
            continue
        significant = g_ref.abs() > 1e-2 * scale
        rel = ((g_cpp - g_ref).abs() / g_ref.abs())[significant]
        assert rel.max() <= 1e-3, f"{name}: max relative error {rel.max():.2e} ({config})"
        assert (g_cpp - g_ref).abs().max() <= 1e-3 * scale, name


def test_reference_gradcheck() -> None:
    scene = random_scene(7, 3, sh_degree=2, view_rotations=True, dtype=torch.float64)
    scene["opacities"] = torch.tensor([0.7, 0.5, 0.9], dtype=torch.float64)
    camera = make_camera(7, 6, 3)
    names = ["means", "opacities", "scales", "quats", "sh", "view_rotations", "background"]

    def render(*tensors):
        kwargs = dict(zip(names, tensors))
        out = rasterize_reference(kwargs.pop("means"), kwargs.pop("opacities"), camera, **kwargs)
        return out["rgb"], out["alpha"], out["depth"]

    inputs = [scene[n].clone().requires_grad_(True) for n in names]
    assert render(*inputs)[1].max() > 0.3
    assert torch.autograd.gradcheck(render, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)

    covariance_scene = random_scene(8, 3, sh_degree=None, full_covariance=True, dtype=torch.float64)

    def render_covariance(means, covariances, colors):
        out = rasterize_reference(means, covariance_scene["opacities"], camera,
                                  covariances=covariances, colors=colors)
        return out["rgb"], out["depth"]

    inputs = [covariance_scene[n].clone().requires_grad_(True) for n in ("means", "covariances", "colors")]
    assert torch.autograd.gradcheck(render_covariance, inputs, eps=1e-6, atol=1e-6, rtol=1e-4,
                                    fast_mode=True)


def _edge_case_scene() -> tuple[dict, Camera]:
    """Gaussians behind / on the near plane, off-screen, huge, degenerate, transparent."""
    camera = Camera(torch.eye(4), fx=20.0, fy=20.0, cx=9.5, cy=8.0, width=19, height=17, near=0.1)
    means = torch.tensor([
        [0.0, 0.0, -1.0],    # behind the camera
        [0.0, 0.0, 0.1],     # exactly on the near plane
        [0.01, 0.0, 0.1001],  # just in front of the near plane
        [0.6, 0.2, 1.0],     # partly off-screen (right edge)
        [5.0, 5.0, 1.0],     # far off-screen
        [0.0, 0.0, 2.0],     # huge: bigger than the image
        [0.1, -0.1, 1.5],    # degenerate: one zero scale
        [-0.1, 0.1, 1.2],    # zero opacity
        [0.0, 0.1, 3.0],     # all-zero scale
        [0.05, 0.05, 1.0],   # ordinary
    ])
    scales = torch.tensor([[0.1] * 3, [0.1] * 3, [0.05] * 3, [0.2] * 3, [0.3] * 3, [50.0] * 3,
                           [0.2, 0.0, 0.1], [0.1] * 3, [0.0] * 3, [0.05] * 3])
    quats = torch.randn(10, 4, generator=torch.Generator().manual_seed(0))
    opacities = torch.tensor([0.9, 0.9, 0.9, 0.9, 0.9, 0.5, 0.9, 0.0, 0.9, 0.9])
    colors = torch.rand(10, 3, generator=torch.Generator().manual_seed(1))
    return {"means": means, "opacities": opacities, "scales": scales, "quats": quats,
            "colors": colors}, camera


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("case", ["edge", "empty", "one_pixel", "odd_size"])
def test_no_nan_or_inf(backend: str, case: str) -> None:
    scene, camera = _edge_case_scene()
    if case == "empty":
        scene = {k: v[:0] for k, v in scene.items()}
    elif case == "one_pixel":
        camera = Camera(torch.eye(4), 20.0, 20.0, 0.5, 0.5, 1, 1, near=0.1)
    elif case == "odd_size":
        camera = Camera(torch.eye(4), 20.0, 20.0, 16.0, 3.0, 33, 7, near=0.1)
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    means, opacities, kwargs = split(leaves)
    out = rasterize(means, opacities, camera, backend=backend, **kwargs)
    for key in ("rgb", "alpha", "depth"):
        assert torch.isfinite(out[key]).all(), key
    (out["rgb"].sum() + out["alpha"].sum() + out["depth"].sum()).backward()
    for name, leaf in leaves.items():
        assert leaf.grad is None or torch.isfinite(leaf.grad).all(), name
    if case == "edge":
        assert out["radii"][:2].eq(0).all()  # culled at / behind the near plane
        assert out["radii"][7] == 0  # zero opacity
        assert out["radii"][5] > 20  # huge
        assert out["alpha"].max() > 0.5


@needs_cpp
@pytest.mark.parametrize("case", ["edge", "one_pixel", "odd_size"])
def test_edge_cases_match_reference(case: str) -> None:
    scene, camera = _edge_case_scene()
    if case == "one_pixel":
        camera = Camera(torch.eye(4), 20.0, 20.0, 0.5, 0.5, 1, 1, near=0.1)
    elif case == "odd_size":
        camera = Camera(torch.eye(4), 20.0, 20.0, 16.0, 3.0, 33, 7, near=0.1)
    # float32 reference: a mean exactly on the near plane must round the same way
    cpp, ref = _render_both(scene, camera, torch.float32)
    for key in ("rgb", "alpha", "depth"):
        assert (cpp[key] - ref[key]).abs().max() <= 1e-4, key
    assert torch.equal(cpp["radii"], ref["radii"])


@pytest.mark.parametrize("backend", BACKENDS)
def test_exclusive_keeps_only_the_nearest(backend: str) -> None:
    camera = Camera(torch.eye(4), 30.0, 30.0, 10.0, 10.0, 20, 20)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.02, 0.0, 2.5], [0.0, 0.03, 3.0], [0.0, 0.0, 1.5]])
    scales = torch.full((4, 3), 0.3)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(4, 1)
    opacities = torch.tensor([0.6, 0.7, 0.8, 0.3])
    colors = torch.eye(3).repeat(2, 1)[:4]
    exclusive = torch.tensor([True, True, True, False])
    both = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=colors,
                     exclusive=exclusive, backend=backend)
    keep = torch.tensor([0, 3])  # the nearest exclusive one and the non-exclusive one
    nearest = rasterize(means[keep], opacities[keep], camera, scales=scales[keep],
                        quats=quats[keep], colors=colors[keep], backend=backend)
    assert torch.allclose(both["rgb"], nearest["rgb"], atol=1e-6)
    plain = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=colors,
                      backend=backend)
    assert (plain["alpha"] - both["alpha"]).max() > 0.1  # exclusivity really removed something
    # Gradients respect it: the skipped exclusive Gaussians get none.
    leaf = colors.clone().requires_grad_(True)
    out = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=leaf,
                    exclusive=exclusive, backend=backend)
    out["rgb"].sum().backward()
    assert leaf.grad[1:3].abs().max() == 0 and leaf.grad[0].abs().min() > 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_group_exclusive_keeps_the_nearest_of_each_group(backend: str) -> None:
    """Group rule (paper §3.2.2): of each group only the nearest member shades a pixel, other
    groups and non-exclusive Gaussians blend as usual."""
    camera = Camera(torch.eye(4), 30.0, 30.0, 10.0, 10.0, 20, 20)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.02, 0.0, 2.5], [0.0, 0.03, 3.0], [0.0, 0.0, 1.5],
                          [0.01, 0.01, 2.2], [0.0, -0.02, 3.5]])
    scales = torch.full((6, 3), 0.3)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(6, 1)
    opacities = torch.tensor([0.6, 0.7, 0.8, 0.3, 0.5, 0.4])
    colors = torch.rand(6, 3, generator=torch.Generator().manual_seed(2))
    groups = torch.tensor([4, 4, 9, -1, 9, 4])  # 4: 0 (nearest), 1, 5; 9: 4 (nearest), 2
    grouped = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=colors,
                        exclusive=groups, backend=backend)
    keep = torch.tensor([0, 3, 4])
    nearest = rasterize(means[keep], opacities[keep], camera, scales=scales[keep],
                        quats=quats[keep], colors=colors[keep], backend=backend)
    assert torch.allclose(grouped["rgb"], nearest["rgb"], atol=1e-6)
    assert torch.allclose(grouped["alpha"], nearest["alpha"], atol=1e-6)
    # the global rule would keep one of groups 4 and 9 together, i.e. fewer
    flags = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=colors,
                      exclusive=groups >= 0, backend=backend)
    assert (grouped["alpha"] - flags["alpha"]).max() > 0.1
    # where the nearest member of a group is transparent (alpha < 1/255), the next one shades
    far = means.clone()
    far[0, 0] = 3.0  # group 4's nearest member leaves the image centre
    moved = rasterize(far, opacities, camera, scales=scales, quats=quats, colors=colors,
                      exclusive=groups, backend=backend)
    centre = moved["rgb"][10, 10]
    expected = rasterize(far[[1, 3, 4]], opacities[[1, 3, 4]], camera, scales=scales[:3],
                         quats=quats[:3], colors=colors[[1, 3, 4]], backend=backend)["rgb"][10, 10]
    assert torch.allclose(centre, expected, atol=1e-6)
    # gradients: the skipped members get none
    leaf = colors.clone().requires_grad_(True)
    out = rasterize(means, opacities, camera, scales=scales, quats=quats, colors=leaf,
                    exclusive=groups, backend=backend)
    out["rgb"].sum().backward()
    assert leaf.grad[[1, 2, 5]].abs().max() == 0 and leaf.grad[[0, 3, 4]].abs().min() > 0


def test_group_ring_links_each_group() -> None:
    from fracture_gs.render.exclusive import group_ring

    ring = group_ring(torch.tensor([3, -1, 0, 3, 3, 7, 0, -1, 9]))
    assert ring.dtype == torch.int32
    assert ring.tolist() == [3, -1, 6, 4, 0, 5, 2, -1, 8]
    assert group_ring(torch.full((4,), -1)).tolist() == [-1] * 4
    assert group_ring(torch.zeros(0, dtype=torch.int64)).numel() == 0


@needs_cpp
def test_backward_is_deterministic() -> None:
    scene = random_scene(3, 200, sh_degree=3)
    camera = make_camera(64, 48, 3)
    weights = _loss_weights(48, 64, 3)
    render = lambda *a, **k: rasterize(*a, backend="cpp", **k)  # noqa: E731
    first = _gradients(render, scene, camera, weights)
    second = _gradients(render, scene, camera, weights)
    for name in first:
        assert torch.equal(first[name], second[name]), name


def _bad_call(case: str) -> None:
    """rasterize with one argument wrong (``case``), everything else valid."""
    camera = make_camera(8, 8)
    args = dict(means=torch.zeros(3, 3), opacities=torch.zeros(3), camera=camera,
                covariances=torch.eye(3).repeat(3, 1, 1), colors=torch.ones(3, 3))
    change = {
        "camera": dict(camera="not a camera"),
        "means shape": dict(means=torch.zeros(3, 2)),
        "means list": dict(means=[[0.0, 0.0, 0.0]]),
        "means dtype": dict(means=torch.zeros(3, 3, dtype=torch.int64)),
        "opacities type": dict(opacities=[0.5, 0.5, 0.5]),
        "opacities device": dict(opacities=torch.zeros(3, device="meta")),
        "scales without quats": dict(scales=torch.ones(3, 3), covariances=None),
        "both shapes": dict(scales=torch.ones(3, 3), quats=torch.ones(3, 4)),
        "no colour": dict(colors=None),
        "view rotations without sh": dict(view_rotations=torch.eye(3).repeat(3, 1, 1)),
    }[case]
    args.update(change)
    rasterize(args.pop("means"), args.pop("opacities"), args.pop("camera"), **args)


@pytest.mark.parametrize("case, needle", [
    ("camera", "camera must be a fracture_gs.render.Camera, got str"),
    ("means shape", r"means must have shape \(N, 3\), got \(3, 2\)"),
    ("means list", r"means must have shape \(N, 3\), got list"),
    ("means dtype", "means must be floating point"),
    ("opacities type", "opacities must be a torch.Tensor, got list"),
    ("opacities device", "opacities is on meta, means are on cpu"),
    ("scales without quats", "scales and quats must be given together"),
    ("both shapes", "exactly one of scales\\+quats or covariances"),
    ("no colour", "exactly one of sh or colors"),
    ("view rotations without sh", "view_rotations only apply to sh colours"),
])
def test_bad_input_names_the_argument(case: str, needle: str) -> None:
    with pytest.raises(ValueError, match="rasterize: .*" + needle):
        _bad_call(case)


def test_bad_input_raises() -> None:
    camera = make_camera(8, 8)
    means = torch.zeros(3, 3)
    with pytest.raises(ValueError, match="opacities"):
        rasterize(means, torch.zeros(4), camera, scales=torch.ones(3, 3), quats=torch.ones(3, 4),
                  colors=torch.ones(3, 3))
    with pytest.raises(ValueError, match="covariances"):
        rasterize(means, torch.zeros(3), camera, colors=torch.ones(3, 3))
    with pytest.raises(ValueError, match="sh"):
        rasterize(means, torch.zeros(3), camera, covariances=torch.eye(3).repeat(3, 1, 1),
                  sh=torch.zeros(3, 5, 3))
    for dtype in (torch.uint8, torch.float32):  # uint8 0/1 would read as groups 0 and 1
        with pytest.raises(ValueError, match="exclusive"):
            rasterize(means, torch.zeros(3), camera, covariances=torch.eye(3).repeat(3, 1, 1),
                      colors=torch.ones(3, 3), exclusive=torch.zeros(3, dtype=dtype))


@needs_cpp
@pytest.mark.parametrize("exclusive", [False, True, "groups"])
def test_saturated_pixels_match_reference(exclusive: bool | str) -> None:
    """A dense, nearly opaque scene: most pixels stop blending early (transmittance threshold),
    at different entries for neighbouring pixels; forward and gradients still match."""
    scene = random_scene(7, 300, sh_degree=2, exclusive=exclusive)
    scene["opacities"] = 0.9 + 0.09 * torch.rand(300, generator=torch.Generator().manual_seed(7))
    camera = make_camera(WIDTH, HEIGHT, 7)
    cpp, ref = _render_both(scene, camera)
    saturated = (1.0 - ref["alpha"]) < 1e-3
    # the early stop is actually exercised (exclusive Gaussians blend at most one per pixel)
    assert saturated.float().mean() > (0.05 if exclusive is True else 0.3)
    for key in ("rgb", "alpha", "depth"):
        assert (cpp[key].double() - ref[key]).abs().max().item() <= 1e-4, key
    weights = _loss_weights(HEIGHT, WIDTH, 7)
    grads_cpp = _gradients(lambda *a, **k: rasterize(*a, backend="cpp", **k), scene, camera, weights)
    ref_scene = {k: (v.double() if v.is_floating_point() else v) for k, v in scene.items()}
    grads_ref = _gradients(rasterize_reference, ref_scene, camera, weights)
    for name, g_ref in grads_ref.items():
        scale = g_ref.abs().max().item()
        assert (grads_cpp[name] - g_ref).abs().max() <= 1e-3 * max(scale, 1e-6), name
