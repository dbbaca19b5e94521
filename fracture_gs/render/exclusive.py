"""The rasterizer's exclusive rules (docs/formulas.md §11, exclusive Gaussians; paper §3.2.2).

``exclusive`` given to ``rasterize`` is either

* a bool (N,) tensor — the **global rule**: of all flagged Gaussians only the nearest one
  with alpha >= 1/255 blends at a pixel; or
* an integer (N,) tensor of **group ids** — the paper's occlusion-aware sampling: Gaussians with
  the same id >= 0 (the lenses that replace one fractured particle's Gaussian) blend only their
  nearest member with alpha >= 1/255 at a pixel; different groups, and ids < 0, blend as usual.

The compiled kernels take groups as a ring (``group_ring``): ``next[i]`` is the next member of
i's group (i itself for a group of one), -1 outside any group; a member is skipped at a pixel
where another member that comes before it in blending order (camera depth, then index) has
alpha >= 1/255 there.
"""
from __future__ import annotations

import torch


def is_group_ids(exclusive: torch.Tensor | None) -> bool:
    """True when ``exclusive`` holds group ids (integer dtype) rather than global flags (bool)."""
    return exclusive is not None and exclusive.dtype != torch.bool


def group_ring(groups: torch.Tensor) -> torch.Tensor:
    """int32 (N,) ring of group members: next member of the same group id (>= 0), wrapping to
    the group's first; -1 for ids < 0. Members follow each other in index order."""
    n = groups.shape[0]
    device = groups.device
    ring = torch.full((n,), -1, dtype=torch.int64, device=device)
    members = torch.nonzero(groups >= 0).flatten()
    if members.numel() == 0:
        return ring.to(torch.int32)
    ids = groups[members]
    order = torch.argsort(ids, stable=True)
    sorted_members, sorted_ids = members[order], ids[order]
    position = torch.arange(sorted_ids.numel(), device=device)
    starts = torch.ones_like(sorted_ids, dtype=torch.bool)
    starts[1:] = sorted_ids[1:] != sorted_ids[:-1]
    first_position = torch.cummax(torch.where(starts, position, torch.zeros_like(position)), 0).values
    ends = torch.ones_like(starts)
    ends[:-1] = starts[1:]
    following = torch.where(ends, first_position, (position + 1).clamp_max(position.numel() - 1))
    ring[sorted_members] = sorted_members[following]
    return ring.to(torch.int32)


def group_blocked(usable: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """Dense form of the group rule for the torch twin: usable (P, M) bool (alpha >= 1/255 at
    pixel p of entry m, entries in blending order), groups (M,) ids in that order. True where
    an earlier entry of the same group (id >= 0) is usable at the same pixel."""
    m = groups.shape[0]
    earlier = torch.ones(m, m, dtype=torch.bool, device=groups.device).triu(diagonal=1)
    same = (groups[:, None] == groups[None, :]) & (groups[:, None] >= 0) & earlier  # [j', j]
    return (usable.to(torch.float32) @ same.to(torch.float32)) > 0
