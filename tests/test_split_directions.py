"""Split directions carried with the material (csrc/common/split_direction.h): the compiled kernel
against its torch twin (fracture_gs/materials/split_directions.py), and what a carried normal means:
it stays the normal of a material plane."""
from __future__ import annotations

import pytest
import torch

from fracture_gs import _backend
from fracture_gs.materials.split_directions import advance_split_directions, advance_split_directions_reference
from kernel_devices import KERNEL_DEVICES

compiled = _backend.compiled_module()
needs_compiled = pytest.mark.extension  # tests/conftest.py: skipped without _C, failed in CI
ORIENTATION = (0.2672612419124244, 0.5345224838248488, 0.8017837257372732)
FIRST, TRIGGER, START = 2, 0, 1.0


def random_batch(n: int, seed: int) -> tuple[torch.Tensor, ...]:
    """(state (n, 6), trigger_old, C, F_E, mine) covering every case: rows with a normal, rows whose
    trigger reached START in this substep, rows that grew but stayed below, rows already at START
    before (no new normal), and rows of another model (mine false)."""
    g = torch.Generator().manual_seed(seed)
    state = torch.rand(n, 6, generator=g)
    kind = torch.randint(0, 5, (n,), generator=g)
    normal = torch.randn(n, 3, generator=g)
    normal = normal / normal.norm(dim=1, keepdim=True)
    state[:, FIRST:FIRST + 3] = torch.where((kind == 0)[:, None], normal, torch.zeros_like(normal))
    trigger_old = state[:, TRIGGER].clone() * 0.9
    state[:, TRIGGER] = torch.where(kind == 1, torch.full((n,), START), state[:, TRIGGER])
    trigger_old = torch.where(kind == 3, torch.full((n,), START), trigger_old)
    state[:, TRIGGER] = torch.where(kind == 3, torch.full((n,), START), state[:, TRIGGER])
    C = 50.0 * torch.randn(n, 3, 3, generator=g)
    # F_E = R diag(stretches) Q^T with well separated stretches: the largest stretch direction is defined.
    R, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=g, dtype=torch.float64))
    Q, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=g, dtype=torch.float64))
    stretch = torch.tensor([1.02, 1.0, 0.97], dtype=torch.float64)[torch.randperm(3, generator=g)]
    F_E = ((R * stretch) @ Q.mT).float()
    mine = kind != 4
    return state, trigger_old, C, F_E, mine


@needs_compiled
@pytest.mark.parametrize("device", KERNEL_DEVICES)
def test_kernel_matches_torch_twin(device: str) -> None:
    state, trigger_old, C, F_E, mine = random_batch(3000, seed=3)
    expected = state.clone()
    advance_split_directions_reference(expected, trigger_old, C, F_E, mine, FIRST, TRIGGER, START, 1e-3, ORIENTATION)
    got = state.clone().to(device)
    compiled.advance_split_directions(got, trigger_old.to(device), C.to(device), F_E.to(device), mine.to(device),
                                      FIRST, TRIGGER, START, 1e-3, list(ORIENTATION))
    got = got.cpu()
    assert torch.allclose(got, expected, atol=2e-6, rtol=0)
    # Every case happened, and the others' columns are untouched.
    normals_before = (state[:, FIRST:FIRST + 3] != 0).any(1)
    normals_after = (got[:, FIRST:FIRST + 3] != 0).any(1)
    started = normals_after & ~normals_before
    assert int(started.sum()) > 100 and int((normals_before & mine).sum()) > 100
    assert torch.equal(got[~mine], state[~mine])
    assert torch.equal(got[:, :FIRST], state[:, :FIRST]) and torch.equal(got[:, FIRST + 3:], state[:, FIRST + 3:])
    # New normals: unit, along the largest principal stretch of F_E, on the side of ORIENTATION.
    new = got[started, FIRST:FIRST + 3].double()
    assert torch.allclose(new.norm(dim=1), torch.ones(len(new), dtype=torch.float64), atol=1e-6)
    assert bool((new @ torch.tensor(ORIENTATION, dtype=torch.float64) > 0).all())
    F = F_E[started].double()
    stretched = torch.linalg.vector_norm(F.mT @ new[:, :, None], dim=(1, 2))
    assert torch.allclose(stretched, torch.linalg.matrix_norm(F, ord=2), rtol=1e-6)


@needs_compiled
def test_dispatch_runs_the_kernel_or_the_twin_alike() -> None:
    state, trigger_old, C, F_E, mine = random_batch(500, seed=4)
    results = []
    for backend in ("cpp", "reference"):
        out = state.clone()
        advance_split_directions(out, trigger_old, C, F_E, mine, FIRST, TRIGGER, START, 1e-3, ORIENTATION,
                                 backend=backend)
        results.append(out)
    assert torch.allclose(results[0], results[1], atol=2e-6, rtol=0)


@pytest.mark.parametrize("backend", [pytest.param("cpp", marks=needs_compiled), "reference"])
def test_carried_normal_stays_normal_to_a_material_plane(backend: str) -> None:
    """Under a constant velocity gradient L (F(t) = exp(t L)), a material plane with rest normal N has
    the normal F^-T N: the normal carried substep by substep follows it to the step's first order."""
    L = torch.tensor([[0.0, 3.0, 0.5], [-1.0, 0.2, 0.0], [0.4, 0.0, -0.3]], dtype=torch.float64)
    rest_normal = torch.tensor([0.6, 0.0, 0.8], dtype=torch.float64)
    steps, dt = 2000, 1e-4
    state = torch.zeros(1, 5)
    state[0, FIRST:FIRST + 3] = rest_normal.float()
    mine = torch.ones(1, dtype=torch.bool)
    C = L.float()[None]
    for _ in range(steps):
        advance_split_directions(state, state[:, TRIGGER].clone(), C, torch.eye(3)[None], mine, FIRST, TRIGGER,
                                 START, dt, ORIENTATION, backend=backend)
    F = torch.linalg.matrix_exp(L * steps * dt)
    exact = torch.linalg.solve(F.mT, rest_normal)
    exact = exact / exact.norm()
    assert float((state[0, FIRST:FIRST + 3].double() - exact).abs().max()) < 2e-3


@needs_compiled
def test_bad_inputs_are_refused_with_one_line() -> None:
    state, trigger_old, C, F_E, mine = random_batch(10, seed=5)
    with pytest.raises(ValueError, match="columns"):
        compiled.advance_split_directions(state, trigger_old, C, F_E, mine, 4, TRIGGER, START, 1e-3,
                                          list(ORIENTATION))
    with pytest.raises(TypeError, match="bool"):
        compiled.advance_split_directions(state, trigger_old, C, F_E, mine.int(), FIRST, TRIGGER, START, 1e-3,
                                          list(ORIENTATION))
    with pytest.raises(ValueError, match="contiguous"):
        compiled.advance_split_directions(state.t().contiguous().t(), trigger_old, C, F_E, mine, FIRST, TRIGGER,
                                          START, 1e-3, list(ORIENTATION))
