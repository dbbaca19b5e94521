"""Readable, dense PyTorch twin of the Gaussian rasterizer (docs/formulas.md §11).

Every Gaussian is evaluated at every pixel (memory O(H·W·N): small images only), in the
input dtype, with plain autograd for the backward. The semantics are the definition the
C++/CUDA kernels must reproduce exactly:

* projection: camera point p = R·mean + t; culled when p.z <= near. Pixel mean
  (fx·x/z + cx, fy·y/z + cy); 2D covariance T Σ Tᵀ, T = J R, with the EWA Jacobian J of the
  perspective map evaluated at x/z, y/z clamped to 1.3 × the half field of view per side
  (as 3DGS); plus 0.3 px² on the diagonal; culled when its determinant is <= 0.
* a pixel (i, j) has its centre at (i + 0.5, j + 0.5); alpha = min(0.99, o·exp(-½ dᵀ Σ₂⁻¹ d)).
* blending in order of camera depth, ties by index: entries with alpha < 1/255 are skipped;
  exclusive as bool flags (global rule): a flagged Gaussian is skipped once an earlier flagged
  one was blended at that pixel; exclusive as integer group ids (group rule,
  ``fracture_gs.render.exclusive``): a Gaussian of group id >= 0 is skipped where an earlier
  one of the same group has alpha >= 1/255;
  a pixel stops (without blending the entry) when T·(1 - alpha) < 1e-4.
* outputs rgb = Σ w c + T_final · background, alpha = 1 - T_final, and depth = Σ w z
  (NOT normalised: divide by alpha for the mean depth of the covered part), w = alpha·T.
* radii = ceil(3·sqrt(λ_max(Σ₂))) for Gaussians that can reach a pixel (not culled,
  opacity >= 1/255, their alpha >= 1/255 ellipse box overlaps the image), else 0.
"""
from __future__ import annotations

import torch

from fracture_gs.render.camera import Camera
from fracture_gs.render.exclusive import group_blocked, is_group_ids
from fracture_gs.render.inputs import RasterInputs, check_inputs
from fracture_gs.render.sh import sh_to_color, view_directions

LOW_PASS = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
FRUSTUM_SLACK = 0.3


def quaternion_to_rotation(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (N,3,3) of quaternions (N,4) w x y z (normalised here)."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    return torch.stack(rows, -1).reshape(-1, 3, 3)


def covariance_from_scale_rotation(scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """Σ = R diag(s)² Rᵀ, (N,3,3)."""
    m = quaternion_to_rotation(quats) * scales[:, None, :]
    return m @ m.transpose(1, 2)


def project_gaussians(means: torch.Tensor, covariances: torch.Tensor, camera: Camera
                      ) -> dict[str, torch.Tensor]:
    """EWA projection: camera points, pixel means, 2D covariances (a, b, c) and a validity mask."""
    dtype = means.dtype
    w2c = camera.world_to_camera.to(means.device, dtype)
    rotation, translation = w2c[:3, :3], w2c[:3, 3]
    points = means @ rotation.T + translation
    z_raw = points[:, 2]
    in_front = z_raw > camera.near
    z = torch.where(in_front, z_raw, torch.ones_like(z_raw))  # keeps culled rows finite
    x, y = points[:, 0], points[:, 1]
    mean2d = torch.stack([camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy], -1)
    tan_x, tan_y = 0.5 * camera.width / camera.fx, 0.5 * camera.height / camera.fy
    tx = z * torch.clamp(x / z, min=-(camera.cx / camera.fx + FRUSTUM_SLACK * tan_x),
                         max=(camera.width - camera.cx) / camera.fx + FRUSTUM_SLACK * tan_x)
    ty = z * torch.clamp(y / z, min=-(camera.cy / camera.fy + FRUSTUM_SLACK * tan_y),
                         max=(camera.height - camera.cy) / camera.fy + FRUSTUM_SLACK * tan_y)
    zeros = torch.zeros_like(z)
    jacobian = torch.stack([camera.fx / z, zeros, -camera.fx * tx / (z * z),
                            zeros, camera.fy / z, -camera.fy * ty / (z * z)], -1).reshape(-1, 2, 3)
    t = jacobian @ rotation
    cov2d = t @ covariances @ t.transpose(1, 2)
    a = cov2d[:, 0, 0] + LOW_PASS
    b = 0.5 * (cov2d[:, 0, 1] + cov2d[:, 1, 0])
    c = cov2d[:, 1, 1] + LOW_PASS
    det = a * c - b * b
    valid = in_front & (det > 0) & torch.isfinite(det)
    return {"points": points, "depth": z, "mean2d": mean2d, "cov2d": torch.stack([a, b, c], -1),
            "det": det, "valid": valid}


def _support_and_radii(cov2d: torch.Tensor, det: torch.Tensor, mean2d: torch.Tensor,
                       opacities: torch.Tensor, valid: torch.Tensor, camera: Camera
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """Which Gaussians can reach a pixel, and their radii (int32, 0 when not)."""
    with torch.no_grad():
        a, c = cov2d[:, 0], cov2d[:, 2]
        k2 = 2.0 * torch.log(opacities.clamp_min(1e-30) / ALPHA_MIN)
        ex = 1.001 * torch.sqrt((k2 * a).clamp_min(0)) + 0.01
        ey = 1.001 * torch.sqrt((k2 * c).clamp_min(0)) + 0.01
        u, v = mean2d[:, 0], mean2d[:, 1]
        reaches = (valid & (opacities >= ALPHA_MIN) & (u + ex >= 0.5) & (u - ex <= camera.width - 0.5)
                   & (v + ey >= 0.5) & (v - ey <= camera.height - 0.5))
        mid = 0.5 * (a + c)
        lambda_max = mid + torch.sqrt((mid * mid - det).clamp_min(0))
        radii = torch.ceil(3.0 * torch.sqrt(lambda_max.clamp_min(0)))
        radii = torch.where(reaches, radii, torch.zeros_like(radii)).to(torch.int32)
    return reaches, radii


def _blend(alpha: torch.Tensor, exclusive: torch.Tensor | None
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """Blending weights w (P, M) and final transmittance (P,) from alphas (P, M) sorted
    front to back (3DGS rules); exclusive (M,): bool flags or group ids in that order."""
    used = alpha >= ALPHA_MIN
    if is_group_ids(exclusive):
        used = used & ~group_blocked(used, exclusive)
    elif exclusive is not None:
        candidate = exclusive[None, :] & used
        first = candidate & (torch.cumsum(candidate.to(torch.int32), dim=1) == 1)
        used = used & (~exclusive[None, :] | first)
    used_alpha = torch.where(used, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        after = torch.cumprod(1.0 - used_alpha, dim=1)  # T after each entry if it is blended
        blended = used & (after >= TRANSMITTANCE_MIN)
    blended_alpha = torch.where(blended, alpha, torch.zeros_like(alpha))
    transmittance = torch.cumprod(1.0 - blended_alpha, dim=1)
    ones = torch.ones(alpha.shape[0], 1, dtype=alpha.dtype, device=alpha.device)
    before = torch.cat([ones, transmittance[:, :-1]], dim=1)
    final = torch.cat([ones, transmittance], dim=1)[:, -1]
    return blended_alpha * before, final


def rasterize_reference(means: torch.Tensor, opacities: torch.Tensor, camera: Camera, *,
                        scales: torch.Tensor | None = None, quats: torch.Tensor | None = None,
                        covariances: torch.Tensor | None = None, sh: torch.Tensor | None = None,
                        colors: torch.Tensor | None = None, background: torch.Tensor | None = None,
                        exclusive: torch.Tensor | None = None,
                        view_rotations: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Dense PyTorch rasterizer with the semantics of ``fracture_gs.render.rasterize``.

    Returns rgb (H,W,3), alpha (H,W), depth (H,W) (Σ w·z, not normalised), radii (N,) int32
    and means2d (N,2): pixel means of the Gaussians with radius > 0 (0 elsewhere); when it
    requires grad its ``.grad`` is filled by backward (densification statistics).
    """
    inputs: RasterInputs = check_inputs(
        means, opacities, camera, scales=scales, quats=quats, covariances=covariances, sh=sh,
        colors=colors, background=background, exclusive=exclusive, view_rotations=view_rotations)
    dtype, device = means.dtype, means.device
    opacities = inputs.opacities.to(dtype)
    if inputs.covariances is not None:
        sigma = inputs.covariances.to(dtype)
    else:
        sigma = covariance_from_scale_rotation(inputs.scales.to(dtype), inputs.quats.to(dtype))
    projected = project_gaussians(means, sigma, camera)
    valid, depth_cam = projected["valid"], projected["depth"]
    reaches, radii = _support_and_radii(projected["cov2d"], projected["det"], projected["mean2d"],
                                        opacities, valid, camera)
    mean2d = torch.where(reaches[:, None], projected["mean2d"], torch.zeros_like(projected["mean2d"]))
    if mean2d.requires_grad:
        mean2d.retain_grad()
    if inputs.sh is not None:
        w2c = camera.world_to_camera.to(device, dtype)
        center = -w2c[:3, :3].T @ w2c[:3, 3]
        rotations = None if inputs.view_rotations is None else inputs.view_rotations.to(dtype)
        rgb_gauss = sh_to_color(inputs.sh.to(dtype), view_directions(means, center, rotations))
    else:
        rgb_gauss = inputs.colors.to(dtype)

    index = torch.nonzero(reaches).flatten()
    index = index[torch.argsort(depth_cam[index].detach(), stable=True)]
    cov = projected["cov2d"][index]
    det = torch.where(reaches, projected["det"], torch.ones_like(projected["det"]))[index]
    conic_a, conic_b, conic_c = cov[:, 2] / det, -cov[:, 1] / det, cov[:, 0] / det

    ys, xs = torch.meshgrid(torch.arange(camera.height, device=device, dtype=dtype) + 0.5,
                            torch.arange(camera.width, device=device, dtype=dtype) + 0.5,
                            indexing="ij")
    dx = mean2d[index, 0][None, :] - xs.reshape(-1, 1)
    dy = mean2d[index, 1][None, :] - ys.reshape(-1, 1)
    power = -0.5 * (conic_a * dx * dx + conic_c * dy * dy) - conic_b * dx * dy
    gauss = torch.where(power <= 0, torch.exp(power.clamp_max(0.0)), torch.zeros_like(power))
    alpha = torch.clamp(opacities[index][None, :] * gauss, max=ALPHA_MAX)
    excl = None if inputs.exclusive is None else inputs.exclusive[index]
    weights, transmittance = _blend(alpha, excl)
    rgb = weights @ rgb_gauss[index] + transmittance[:, None] * inputs.background.to(dtype)
    depth = weights @ depth_cam[index]
    shape = (camera.height, camera.width)
    return {"rgb": rgb.reshape(*shape, 3), "alpha": (1.0 - transmittance).reshape(shape),
            "depth": depth.reshape(shape), "radii": radii, "means2d": mean2d}
