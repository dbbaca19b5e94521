"""Random Gaussian scenes shared by the rasterizer tests (a helper module, not a test module)."""
from __future__ import annotations

import math

import torch

from fracture_gs.render import Camera


def make_camera(width: int, height: int, seed: int = 0, near: float = 0.01) -> Camera:
    """A camera about 4 units from the origin looking at it, slightly off-axis."""
    gen = torch.Generator().manual_seed(10_000 + seed)
    jitter = (torch.rand(3, generator=gen) - 0.5) * 1.0
    eye = torch.tensor([0.0, 0.0, -4.0]) + jitter
    return Camera.look_at(eye, (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), math.radians(50), width, height,
                          near=near)


def random_scene(seed: int, num: int, *, sh_degree: int | None = 1, full_covariance: bool = False,
                 exclusive: bool | str = False, view_rotations: bool = False,
                 dtype: torch.dtype = torch.float32) -> dict[str, torch.Tensor]:
    """Random Gaussians around the origin as rasterize keyword arguments (plus means, opacities).
    exclusive: True = random global-rule flags, "groups" = random group ids (about 3 Gaussians per
    group, 40 % in none)."""
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(num, 3, generator=gen) * 2 - 1) * 1.2
    scales = 0.03 + 0.2 * torch.rand(num, 3, generator=gen)
    quats = torch.randn(num, 4, generator=gen)
    opacities = 0.05 + 0.94 * torch.rand(num, generator=gen)
    scene: dict[str, torch.Tensor] = {"means": means, "opacities": opacities}
    if full_covariance:
        from fracture_gs.render.reference import covariance_from_scale_rotation
        deformation = torch.eye(3) + 0.4 * torch.randn(num, 3, 3, generator=gen)
        base = covariance_from_scale_rotation(scales, quats)
        scene["covariances"] = deformation @ base @ deformation.transpose(1, 2)
    else:
        scene["scales"], scene["quats"] = scales, quats
    if sh_degree is None:
        scene["colors"] = torch.rand(num, 3, generator=gen)
    else:
        k = (sh_degree + 1) ** 2
        sh = 0.3 * torch.randn(num, k, 3, generator=gen)
        sh[:, 0] += 0.8
        scene["sh"] = sh
        if view_rotations:
            q = torch.randn(num, 4, generator=gen)
            from fracture_gs.render.reference import quaternion_to_rotation
            scene["view_rotations"] = quaternion_to_rotation(q)
    scene["background"] = torch.rand(3, generator=gen)
    if exclusive == "groups":
        groups = torch.randint(0, max(num // 3, 1), (num,), generator=gen)
        scene["exclusive"] = torch.where(torch.rand(num, generator=gen) < 0.4, -1, groups)
    elif exclusive:
        scene["exclusive"] = torch.rand(num, generator=gen) < 0.5
    return {k: (v.to(dtype) if v.is_floating_point() else v) for k, v in scene.items()}


def split(scene: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """(means, opacities, keyword arguments) of a scene."""
    rest = {k: v for k, v in scene.items() if k not in ("means", "opacities")}
    return scene["means"], scene["opacities"], rest
