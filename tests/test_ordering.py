"""spatial_order: the particle order build_scene hands the solver (faster transfers, same physics)."""
from __future__ import annotations

import pytest
import torch

from fracture_gs.testing.lattice import LatticeBody, lattice_box, lattice_sphere, particle_set
from fracture_gs.materials import ElasticMaterial, NACCMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import (BLOCK, BoxBoundary, ContactSettings, Domain, GroundBoundary, ParticleSet,
                                   grid_resolution)

DOMAIN = Domain((0, 0, 0), (1, 1, 1), 24)
MATERIALS = [NACCMaterial(E=5e4, nu=0.3, density=300.0, alpha0=-0.01, beta=0.5, xi=1.0, M=2.36),
             ElasticMaterial(E=2e4, nu=0.3, density=500.0)]


def two_bodies() -> ParticleSet:
    spacing = DOMAIN.dx / 2
    bodies = [LatticeBody(lattice_sphere((0.45, 0.5, 0.42), 0.1, spacing), (1.0, 0.0, -4.0), 0, spacing),
              LatticeBody(lattice_box((0.5, 0.5, 0.22), (0.4, 0.3, 0.1), spacing), (0, 0, 0), 1, spacing)]
    return particle_set(bodies, [m.density for m in MATERIALS])


def test_order_groups_objects_then_blocks_then_cells() -> None:
    particles = two_bodies()
    shuffled = particles.take(torch.randperm(len(particles), generator=torch.Generator().manual_seed(0)))
    order = spatial_order(shuffled.x, shuffled.obj_id, DOMAIN)
    assert torch.equal(torch.sort(order).values, torch.arange(len(particles)))
    ordered = shuffled.take(order)
    base = torch.floor(ordered.x.double() / DOMAIN.dx - 0.5).long()
    blocks = torch.tensor(grid_resolution(DOMAIN)) // BLOCK
    block = base // BLOCK
    block_index = (block[:, 0] * blocks[1] + block[:, 1]) * blocks[2] + block[:, 2]
    cell = base % BLOCK
    key = torch.stack([ordered.obj_id.long(), block_index, (cell[:, 0] * BLOCK + cell[:, 1]) * BLOCK + cell[:, 2]], 1)
    # Lexicographically non-decreasing: each (object, block) and each cell is one run.
    previous, following = key[:-1], key[1:]
    first_difference = (following != previous).long().argmax(1)
    step = following.gather(1, first_difference[:, None]) - previous.gather(1, first_difference[:, None])
    assert bool((step >= 0).all())
    # Rows stay intact: the same multiset of (x, obj_id, mass) as before.
    before = torch.cat([particles.x, particles.obj_id[:, None].float(), particles.mass[:, None]], 1)
    after = torch.cat([ordered.x, ordered.obj_id[:, None].float(), ordered.mass[:, None]], 1)
    assert torch.equal(torch.unique(before, dim=0), torch.unique(after, dim=0))


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="spatial_order"):
        spatial_order(torch.zeros(5, 2), torch.zeros(5, dtype=torch.int32), DOMAIN)


@pytest.mark.extension
def test_particle_order_does_not_change_the_physics() -> None:
    # The same scene in lattice order and in spatial order: P2G sums a node's contributions in a
    # different order, so results agree to float rounding, not bit for bit.
    particles = two_bodies()
    order = spatial_order(particles.x, particles.obj_id, DOMAIN)
    assert not torch.equal(order, torch.arange(len(particles)))
    solvers = [CollisionMPM(p, MATERIALS, DOMAIN, contact=ContactSettings(friction=0.2),
                            boundaries=[BoxBoundary("slip"), GroundBoundary(0.15, 0.4)], backend="cpp")
               for p in (particles, particles.take(order))]
    for _ in range(30):
        dt = solvers[0].stable_dt()
        assert dt == pytest.approx(solvers[1].stable_dt(), rel=1e-5)
        for solver in solvers:
            solver.step(dt)
    plain, ordered = solvers
    sphere = plain.particles.obj_id == 0
    assert bool((plain.state.alpha[sphere] != MATERIALS[0].alpha0).any())  # the NACC sphere yielded
    for name in ("x", "v", "F_E", "alpha"):
        a, b = getattr(plain.state, name)[order], getattr(ordered.state, name)
        assert float((a - b).abs().max()) <= 1e-4 * float(a.abs().max()), name


def scene_solver(particles: ParticleSet, reorder_every: int) -> CollisionMPM:
    return CollisionMPM(particles, MATERIALS, DOMAIN, contact=ContactSettings(friction=0.2),
                        boundaries=[BoxBoundary("slip"), GroundBoundary(0.15, 0.4)], backend="cpp",
                        reorder_every=reorder_every)


@pytest.mark.extension
def test_reordering_during_a_run_keeps_the_physics_and_the_input_order() -> None:
    particles = two_bodies()  # lattice order: the first reorder really moves particles
    fixed, moving = scene_solver(particles, 0), scene_solver(particles, 7)
    for _ in range(30):
        dt = fixed.stable_dt()
        fixed.step(dt)
        moving.step(dt)
    assert not torch.equal(moving.input_index, torch.arange(len(particles)))
    # particles and state move together: rows still belong to the same particles
    assert torch.equal(moving.particles.mass, particles.mass[moving.input_index])
    assert torch.equal(moving.particles.obj_id, particles.obj_id[moving.input_index])
    assert torch.equal(moving.grid_id, particles.obj_id[moving.input_index])
    in_input_order = moving.state_in_input_order()
    for name in ("x", "v", "F_E", "alpha"):
        a, b = getattr(fixed.state, name), getattr(in_input_order, name)
        assert float((a - b).abs().max()) <= 1e-4 * float(a.abs().max()), name
    assert torch.equal(fixed.state.fractured, in_input_order.fractured)
    assert fixed.diagnostics()["total_energy"] == pytest.approx(moving.diagnostics()["total_energy"], rel=1e-5)


@pytest.mark.extension
def test_checkpoint_across_reorders_continues_bit_identically() -> None:
    particles = two_bodies()
    first = scene_solver(particles, 5)
    for _ in range(12):
        first.step(first.stable_dt())
    saved = {k: (v.copy() if hasattr(v, "copy") else v) for k, v in first.state_dict().items()}
    for _ in range(9):  # crosses the reorders at steps 15 and 20
        first.step(first.stable_dt())
    second = scene_solver(particles, 5)
    second.load_state_dict(saved)
    for _ in range(9):
        second.step(second.stable_dt())
    assert torch.equal(first.input_index, second.input_index)
    for name in ("x", "v", "C", "F_E", "alpha", "fractured"):
        assert torch.equal(getattr(first.state, name), getattr(second.state, name)), name
    bad = dict(saved, input_index=saved["input_index"][::-1].copy() * 0)
    with pytest.raises(ValueError, match="input_index"):
        second.load_state_dict(bad)


def test_negative_reorder_interval_is_refused() -> None:
    with pytest.raises(ValueError, match="reorder_every"):
        scene_solver(two_bodies(), -1)
