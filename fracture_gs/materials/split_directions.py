"""Split directions carried with the material: a unit normal per particle in three fields of its
material state (0 0 0: none yet). It starts when a trigger field of the state reaches a value (the
direction of the particle's largest principal stretch then) and afterwards turns with the material like
the normal of a material plane, n ← (I − Δt Cᵀ) n, normalised. Normals point to the side of
``orientation``. The kernel is ``csrc/common/split_direction.h``; :func:`advance_split_directions_reference`
is its torch twin.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch

from fracture_gs import _backend


def advance_split_directions_reference(state: torch.Tensor, trigger_old: torch.Tensor, C: torch.Tensor,
                                       F_E: torch.Tensor, mine: torch.Tensor, first: int, trigger: int, start: float,
                                       dt: float, orientation: Sequence[float]) -> None:
    """Torch twin of the kernel: changes ``state`` (N, S) in place on the rows where ``mine`` is set."""
    columns = slice(first, first + 3)
    normal = state[:, columns]
    has_normal = mine & (normal != 0).any(1)
    carried = torch.nonzero(has_normal).flatten()
    value = state[:, trigger]
    started = torch.nonzero(mine & ~has_normal & (value > trigger_old) & (value >= start)).flatten()
    if len(carried):
        turned = normal[carried] - dt * (C[carried].mT @ normal[carried][:, :, None])[:, :, 0]
        state[carried, columns] = turned / torch.linalg.vector_norm(turned, dim=1, keepdim=True)
    if len(started):
        F = F_E[started].double()
        _, vectors = torch.linalg.eigh(F @ F.mT)
        largest = vectors[:, :, -1]
        side = torch.tensor(tuple(orientation), dtype=largest.dtype, device=largest.device)
        sign = torch.where(largest @ side < 0, -1.0, 1.0).to(largest.dtype)
        state[started, columns] = (largest * sign[:, None]).to(state.dtype)


def advance_split_directions(state: torch.Tensor, trigger_old: torch.Tensor, C: torch.Tensor, F_E: torch.Tensor,
                             mine: torch.Tensor, first: int, trigger: int, start: float, dt: float,
                             orientation: Sequence[float], backend: str = "auto") -> None:
    """Carries the split directions held in columns ``first``..``first + 2`` of ``state`` (N, S) float32
    through a substep, in place, on the rows where ``mine`` (N,) bool is set: a row with a normal turns
    with the material (``C`` (N, 3, 3) after the substep); a row without one gets the direction of its
    largest principal stretch (``F_E`` (N, 3, 3)) once its column ``trigger`` grew past ``trigger_old``
    (N,) to at least ``start``. Compiled kernel or torch twin (``_backend.use_compiled``)."""
    if _backend.use_compiled(state.device, backend):
        _backend.compiled_module().advance_split_directions(
            state, trigger_old.contiguous(), C, F_E, mine, int(first), int(trigger), float(start), float(dt),
            [float(c) for c in orientation])
        return
    advance_split_directions_reference(state, trigger_old, C, F_E, mine, first, trigger, start, dt, orientation)
