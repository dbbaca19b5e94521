"""Fitting with the C++ rasterizer: optimising colours, opacities and scales of 5k Gaussians
to an image rendered from a different random scene lowers the L1 loss by >= 80 %."""
from __future__ import annotations

import pytest
import torch

from fracture_gs.render import Camera, rasterize

SIZE = 32


def _random_gaussians(num: int, seed: int, scale: float) -> dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    depth = 1.5 + torch.rand(num, generator=gen)
    xy = (torch.rand(num, 2, generator=gen) * 2.2 - 1.1) * depth[:, None] / 2.0
    quats = torch.randn(num, 4, generator=gen)
    return {"means": torch.cat([xy, depth[:, None]], 1), "quats": quats,
            "scales": scale * (0.5 + torch.rand(num, 3, generator=gen)),
            "opacities": 0.3 + 0.6 * torch.rand(num, generator=gen),
            "colors": torch.rand(num, 3, generator=gen)}


@pytest.mark.extension("raster_forward")
def test_fitting_lowers_l1_by_80_percent() -> None:
    camera = Camera(torch.eye(4), SIZE, SIZE, SIZE / 2, SIZE / 2, SIZE, SIZE)
    background = torch.tensor([0.1, 0.1, 0.1])
    target_scene = _random_gaussians(150, seed=1, scale=0.12)
    with torch.no_grad():
        target = rasterize(target_scene["means"], target_scene["opacities"], camera,
                           scales=target_scene["scales"], quats=target_scene["quats"],
                           colors=target_scene["colors"], background=background, backend="cpp")["rgb"]
    start = _random_gaussians(5000, seed=2, scale=0.03)
    color_logits = torch.logit(start["colors"].clamp(0.02, 0.98)).requires_grad_(True)
    opacity_logits = torch.logit(start["opacities"]).requires_grad_(True)
    log_scales = start["scales"].log().requires_grad_(True)
    optimizer = torch.optim.Adam([color_logits, opacity_logits, log_scales], lr=0.05)

    def loss_now() -> torch.Tensor:
        out = rasterize(start["means"], torch.sigmoid(opacity_logits), camera,
                        scales=log_scales.exp(), quats=start["quats"],
                        colors=torch.sigmoid(color_logits), background=background, backend="cpp")
        return (out["rgb"] - target).abs().mean()

    initial = loss_now().item()
    for _ in range(300):
        optimizer.zero_grad()
        loss = loss_now()
        loss.backward()
        optimizer.step()
    final = loss_now().item()
    assert initial > 0.05
    assert final <= 0.2 * initial, f"L1 {initial:.4f} -> {final:.4f}"
