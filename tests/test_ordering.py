"""spatial_order: the particle order build_scene hands the solver (faster transfers, same physics)."""
from __future__ import annotations

import pytest
import torch

from fracture_gs._backend import compiled_module
from fracture_gs.mpm.lattice import LatticeBody, lattice_box, lattice_sphere, particle_set
from fracture_gs.mpm.materials import ElasticMaterial, NACCMaterial
from fracture_gs.mpm.ordering import spatial_order
from fracture_gs.mpm.solver import CollisionMPM
from fracture_gs.mpm.types import BLOCK, BoxBoundary, ContactSettings, Domain, GroundBoundary, ParticleSet

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
    blocks = torch.tensor(DOMAIN.resolution) // BLOCK
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


@pytest.mark.skipif(compiled_module() is None, reason="fracture_gs._C is not built")
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
