"""Differentiable Gaussian rasterizer: autograd Function over the C++/CUDA kernels.

``rasterize`` runs the compiled kernels (``fracture_gs._C.raster_forward`` / ``raster_backward``)
when available for the tensors' device and falls back to ``rasterize_reference`` otherwise
(``backend="reference"`` forces the twin). Both have the semantics documented in
``fracture_gs.render.reference``.

Densification statistics: the returned ``means2d`` (N, 2) holds the pixel means of the
Gaussians with radius > 0 (0 elsewhere). When autograd is on and any input requires grad it
is a leaf with ``requires_grad=True``; after ``loss.backward()`` its ``.grad`` is dL/d(pixel
mean) per Gaussian (the gsplat "means2d" trick); it does not change the other gradients.
"""
from __future__ import annotations

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.render.camera import Camera
from fracture_gs.render.exclusive import group_ring, is_group_ids
from fracture_gs.render.inputs import RasterInputs, check_inputs
from fracture_gs.render.reference import rasterize_reference

_OPTIONAL_NAMES = ("scales", "quats", "covariances", "sh", "colors", "view_rotations")


def _camera_args(camera: Camera) -> tuple:
    return (camera.world_to_camera.detach().to("cpu", torch.float32), float(camera.fx),
            float(camera.fy), float(camera.cx), float(camera.cy), int(camera.width),
            int(camera.height), float(camera.near))


class _RasterizeFunction(torch.autograd.Function):
    """Inputs: means, opacities, scales, quats, covariances, sh, colors, view_rotations,
    background, means2d probe (tensors or None), exclusive flags (uint8 or None), exclusive
    group ring (int32 or None; see fracture_gs.render.exclusive), camera args."""

    @staticmethod
    def forward(ctx, means, opacities, scales, quats, covariances, sh, colors, view_rotations,
                background, means2d_probe, exclusive, exclusive_next, camera_args):
        module = compiled_module()
        outputs = module.raster_forward(means, opacities, scales, quats, covariances, sh, colors,
                                        exclusive, exclusive_next, view_rotations, background,
                                        *camera_args)
        rgb, alpha, depth, radii, proj = outputs[:5]
        ctx.camera_args = camera_args
        ctx.has = tuple(t is not None for t in (scales, quats, covariances, sh, colors, view_rotations))
        ctx.save_for_backward(means, opacities, *(t for t in (scales, quats, covariances, sh, colors,
                                                              view_rotations) if t is not None),
                              background, _or_empty(exclusive), _or_empty(exclusive_next),
                              alpha, *outputs[4:])
        means2d = proj[:, :2].clone()
        ctx.mark_non_differentiable(radii, means2d)
        return rgb, alpha, depth, radii, means2d

    @staticmethod
    def backward(ctx, grad_rgb, grad_alpha, grad_depth, _grad_radii, _grad_means2d):
        saved = list(ctx.saved_tensors)
        means, opacities = saved[0], saved[1]
        cursor = 2
        optional = []
        for present in ctx.has:
            optional.append(saved[cursor] if present else None)
            cursor += int(present)
        background, alpha = saved[cursor], saved[cursor + 3]
        exclusive, exclusive_next = (t if t.numel() > 0 else None for t in saved[cursor + 1:cursor + 3])
        state = saved[cursor + 4:]
        if grad_rgb is None:
            grad_rgb = torch.zeros(*alpha.shape, 3, dtype=alpha.dtype, device=alpha.device)
        grad_rgb = grad_rgb.contiguous()
        grad_alpha = torch.zeros_like(alpha) if grad_alpha is None else grad_alpha.contiguous()
        grad_depth = torch.zeros_like(alpha) if grad_depth is None else grad_depth.contiguous()
        module = compiled_module()
        grads = module.raster_backward(means, opacities, *optional[:5], exclusive, exclusive_next,
                                       optional[5],
                                       background, *ctx.camera_args, *state, grad_rgb,
                                       grad_alpha, grad_depth)
        g_means, g_opacities, g_scales, g_quats, g_cov, g_sh, g_colors, g_view, g_means2d = grads
        grad_background = None
        if ctx.needs_input_grad[8]:
            grad_background = ((1.0 - alpha)[..., None] * grad_rgb).sum(dim=(0, 1))

        def wanted(index: int, grad: torch.Tensor) -> torch.Tensor | None:
            return grad if ctx.needs_input_grad[index] and grad.numel() > 0 else None

        return (wanted(0, g_means), wanted(1, g_opacities), wanted(2, g_scales), wanted(3, g_quats),
                wanted(4, g_cov), wanted(5, g_sh), wanted(6, g_colors), wanted(7, g_view),
                grad_background, wanted(9, g_means2d), None, None, None)


def _or_empty(tensor: torch.Tensor | None) -> torch.Tensor:
    return tensor if tensor is not None else torch.empty(0)


def _as_kernel_input(tensor: torch.Tensor | None) -> torch.Tensor | None:
    return None if tensor is None else tensor.to(torch.float32).contiguous()


def _rasterize_compiled(inputs: RasterInputs, camera: Camera) -> dict[str, torch.Tensor]:
    tensors = [_as_kernel_input(getattr(inputs, name)) for name in
               ("means", "opacities", *_OPTIONAL_NAMES, "background")]
    needs_grad = torch.is_grad_enabled() and any(
        t is not None and t.requires_grad for t in tensors)
    probe = None
    if needs_grad:
        probe = torch.zeros(inputs.means.shape[0], 2, dtype=torch.float32,
                            device=inputs.means.device, requires_grad=True)
    exclusive = exclusive_next = None
    if is_group_ids(inputs.exclusive):
        exclusive_next = group_ring(inputs.exclusive)
    elif inputs.exclusive is not None:
        exclusive = inputs.exclusive.to(torch.uint8).contiguous()
    rgb, alpha, depth, radii, means2d = _RasterizeFunction.apply(
        *tensors, probe, exclusive, exclusive_next, _camera_args(camera))
    if probe is not None:
        with torch.no_grad():
            probe.copy_(means2d)
        means2d = probe
    return {"rgb": rgb, "alpha": alpha, "depth": depth, "radii": radii, "means2d": means2d}


def rasterize(means: torch.Tensor, opacities: torch.Tensor, camera: Camera, *,
              scales: torch.Tensor | None = None, quats: torch.Tensor | None = None,
              covariances: torch.Tensor | None = None, sh: torch.Tensor | None = None,
              colors: torch.Tensor | None = None, background: torch.Tensor | None = None,
              exclusive: torch.Tensor | None = None, view_rotations: torch.Tensor | None = None,
              backend: str = "auto") -> dict[str, torch.Tensor]:
    """Render 3D Gaussians with 3DGS semantics (docs/formulas.md §11); differentiable in every input.

    means (N,3); opacities (N,) activated in [0, 1]; either scales (N,3) (activated, not
    log) + quats (N,4) (w x y z, normalised inside) or covariances (N,3,3); either sh
    (N,K,3), K = 1, 4, 9, 16 (colour = max(0, SH(dir) + 0.5)) or colors (N,3); background
    (3,) (default black); exclusive (N,): bool flags (docs/formulas.md §11: at a pixel only the nearest
    flagged Gaussian with alpha >= 1/255 is blended) or integer group ids (paper §3.2.2: only
    the nearest of each group id >= 0; see ``fracture_gs.render.exclusive``); view_rotations (N,3,3) R: SH uses Rᵀ·dir.

    Returns a dict: rgb (H,W,3), alpha (H,W) = 1 - T_final, depth (H,W) = Σ w·z (camera z,
    not normalised: depth / alpha is the mean depth of the covered part), radii (N,) int32
    (0 = not visible) and means2d (N,2) (see the module docstring). The kernels compute in
    float32; other dtypes are converted (gradients come back in the input dtype).
    """
    inputs = check_inputs(means, opacities, camera, scales=scales, quats=quats,
                          covariances=covariances, sh=sh, colors=colors, background=background,
                          exclusive=exclusive, view_rotations=view_rotations)
    if not use_compiled(means.device, backend):
        return rasterize_reference(means, inputs.opacities, camera, scales=scales, quats=quats,
                                   covariances=covariances, sh=sh, colors=colors,
                                   background=inputs.background, exclusive=exclusive,
                                   view_rotations=view_rotations)
    return _rasterize_compiled(inputs, camera)
