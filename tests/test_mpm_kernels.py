"""Compiled MPM kernels against their PyTorch twins on random inputs.

The twins run in float64 on the same float32 inputs, so the only differences are the float32
arithmetic of the kernels; every field must agree to 1e-4 relative to its magnitude. Each
kernel test runs on every device of ``kernel_devices.KERNEL_DEVICES``; on CUDA the CPU kernel's
result is the reference too.
"""
from __future__ import annotations

import math
from dataclasses import fields as dataclass_fields

import pytest
import numpy as np
import torch

from fracture_gs.mpm import ops, reference
from fracture_gs.mpm.grid import GridFields, GridGeometry, ParticleBins, node_coords
from fracture_gs.materials import BrittleMaterial, ElasticMaterial, MaterialTable, NACCMaterial
from fracture_gs.mpm.types import BLOCK, CONTACT_INSIDE_CELLS, Domain
from kernel_devices import KERNEL_DEVICES

pytestmark = pytest.mark.extension  # tests/conftest.py: skipped without _C, failed in CI

REL_TOL = 1e-4


def rel_err(actual: torch.Tensor, expected: torch.Tensor) -> float:
    scale = float(expected.abs().max()) if expected.numel() else 0.0
    return float((actual.double() - expected.double()).abs().max()) / max(scale, 1e-30) if expected.numel() else 0.0


def random_setup(seed: int, n: int = 3000, n_grids: int = 2, grid: int = 16):
    gen = torch.Generator().manual_seed(seed)
    domain = Domain((0.0, 0.0, 0.0), (1.0, 1.25, 1.0), grid)
    geometry = GridGeometry.from_domain(domain, n_grids)
    lo, hi = geometry.clamp_bounds()
    lo_t, hi_t = torch.tensor(lo), torch.tensor(hi)
    x = lo_t + (hi_t - lo_t) * torch.rand(n, 3, generator=gen)
    # Cluster half the particles so blocks hold many particles and both grids overlap.
    x[: n // 2] = 0.5 + 0.15 * torch.randn(n // 2, 3, generator=gen)
    x = torch.minimum(torch.maximum(x, lo_t), hi_t).contiguous()
    particles = {
        "x": x,
        "v": torch.randn(n, 3, generator=gen),
        "C": 3.0 * torch.randn(n, 3, 3, generator=gen),
        "stress": 1e3 * torch.randn(n, 3, 3, generator=gen),
        "mass": 0.5 + torch.rand(n, generator=gen),
        "rest_volume": 1e-4 * (0.5 + torch.rand(n, generator=gen)),
        "grid_id": torch.randint(0, n_grids, (n,), generator=gen, dtype=torch.int32),
    }
    return geometry, particles, gen


def double(t: torch.Tensor) -> torch.Tensor:
    return t.double() if t.is_floating_point() else t


FIELDS = ("mass", "momentum", "velocity", "mass_gradient", "position_moment")
CPU = torch.device("cpu")


def grids(geometry: GridGeometry, dtype=torch.float32, with_contact=True, device: torch.device = CPU) -> GridFields:
    fields = GridFields.zeros(geometry, device, with_contact)
    return GridFields(*(getattr(fields, f).to(dtype) if getattr(fields, f) is not None else None for f in FIELDS))


def double_copy(fields: GridFields) -> GridFields:
    return GridFields(*(getattr(fields, f).double().clone() for f in FIELDS))


def moved(fields: GridFields, device: torch.device | str) -> GridFields:
    """A copy of every field on ``device``."""
    return GridFields(*(getattr(fields, f).to(device).clone() if getattr(fields, f) is not None else None
                        for f in FIELDS))


def bins_on(bins: ParticleBins, device: torch.device | str) -> ParticleBins:
    return ParticleBins(*(getattr(bins, f.name).to(device) for f in dataclass_fields(bins)))


@pytest.mark.parametrize("seed", range(3))
def test_binning_matches_reference(seed):
    geometry, p, _ = random_setup(seed)
    compiled = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    twin = reference.bin_particles(p["x"], p["grid_id"], geometry)
    for a, b in zip(compiled.as_list(), twin.as_list()):
        assert torch.equal(a, b)
    assert len(compiled.contact_blocks) > 0


def test_binning_rejects_particles_outside_the_grid():
    geometry, p, _ = random_setup(0, n=100)
    p["x"][17] = torch.tensor([-1.0, 0.5, 0.5])
    with pytest.raises(RuntimeError, match="particle 17"):
        ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    with pytest.raises(RuntimeError, match="particle 17"):
        reference.bin_particles(p["x"], p["grid_id"], geometry)


def contact_node_mask(bins, geometry: GridGeometry) -> torch.Tensor:
    """(n_grids, nodes) bool: nodes of the contact blocks, in every grid."""
    by_block = torch.zeros(geometry.n_blocks, dtype=torch.bool)
    by_block[bins.contact_blocks.long()] = True
    return by_block.repeat_interleave(BLOCK ** 3).expand(geometry.n_grids, -1)


def p2g_and_grid_update(device: torch.device | str, bins: ParticleBins, p: dict, geometry: GridGeometry,
                        dt: float, gravity: tuple[float, float, float], eps: float) -> tuple[GridFields, GridFields]:
    """Compiled P2G on ``device``; returns (fields after P2G, fields after the grid update) on the CPU."""
    fields = grids(geometry, device=torch.device(device))
    on = {k: v.to(device) for k, v in p.items()}
    device_bins = bins_on(bins, device)
    ops.p2g(device_bins, on["x"], on["v"], on["C"], on["stress"], on["mass"], on["rest_volume"], on["grid_id"],
            geometry, dt, fields, backend="cpp")
    after_p2g = moved(fields, CPU)
    ops.grid_update(device_bins, geometry, dt, gravity, eps, fields, backend="cpp")
    return after_p2g, moved(fields, CPU)


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("seed", range(3))
def test_p2g_and_grid_update_match_reference(seed, device):
    geometry, p, _ = random_setup(seed)
    p["grid_id"][p["x"][:, 0] < 0.3] = 0  # a region of one body only: no contact blocks there
    dt = 1e-4
    gravity = (0.3, -1.0, -9.8)
    eps = 1e-12
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    compiled, compiled_velocity = p2g_and_grid_update(device, bins, p, geometry, dt, gravity, eps)
    twin = grids(geometry, torch.float64)
    reference.p2g(*(double(p[k]) for k in ("x", "v", "C", "stress", "mass", "rest_volume")), p["grid_id"],
                  geometry, dt, twin)
    assert rel_err(compiled.mass, twin.mass) < REL_TOL
    assert rel_err(compiled.momentum, twin.momentum) < REL_TOL
    # Position moment and mass gradient feed only the contact pass: the CPU kernel sums them on
    # contact blocks (block ids touched by two grids) and leaves them zero elsewhere.
    contact = contact_node_mask(bins, geometry)
    assert 0 < int(contact.sum()) < contact.numel()
    assert rel_err(compiled.mass_gradient[contact], twin.mass_gradient[contact]) < REL_TOL
    assert rel_err(compiled.position_moment[contact], twin.position_moment[contact]) < REL_TOL
    if device == "cpu":
        assert float(compiled.mass_gradient[~contact].abs().max()) == 0.0
        assert float(compiled.position_moment[~contact].abs().max()) == 0.0
    assert float(twin.position_moment[~contact].abs().max()) > 0.0  # the skipped region did have particles
    # Mass is conserved by the transfer (partition of unity), and so is the first moment:
    # sum_i (s_i + m_i x_i) = sum_p m_p x_p (the weights reproduce linear functions).
    assert math.isclose(float(twin.mass.sum()), float(p["mass"].double().sum()), rel_tol=1e-10)
    node_x = node_coords(geometry, CPU).double() * geometry.dx + torch.tensor(geometry.lower).double()
    first_moment = (twin.position_moment + twin.mass[..., None] * node_x).sum((0, 1))
    expected = (p["mass"].double()[:, None] * p["x"].double()).sum(0)
    assert float((first_moment - expected).abs().max()) < 1e-10 * float(expected.abs().max())

    reference.grid_update(twin, dt, torch.tensor(gravity, dtype=torch.float64), eps)
    # Compare velocities where the mass is not vanishingly small (there v = p/m amplifies noise).
    solid = twin.mass > 1e-6 * float(twin.mass.max())
    assert rel_err(compiled_velocity.velocity[solid], twin.velocity[solid]) < REL_TOL
    assert float(compiled_velocity.velocity[~(twin.mass > eps)].abs().max()) == 0.0
    if device != "cpu":  # the CPU kernel's result is the reference of the CUDA one
        cpu, cpu_velocity = p2g_and_grid_update("cpu", bins, p, geometry, dt, gravity, eps)
        for name in ("mass", "momentum"):
            assert rel_err(getattr(compiled, name), getattr(cpu, name)) < REL_TOL, name
        for name in ("mass_gradient", "position_moment"):
            assert rel_err(getattr(compiled, name)[contact], getattr(cpu, name)[contact]) < REL_TOL, name
        assert rel_err(compiled_velocity.velocity[solid], cpu_velocity.velocity[solid]) < REL_TOL


def contact_grids(seed: int, geometry: GridGeometry):
    """Grids with overlapping bodies: particle P2G for masses, gradients and moments, random velocities."""
    _, p, gen = random_setup(seed)
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    fields = grids(geometry)
    ops.p2g(bins, p["x"], p["v"], torch.zeros_like(p["C"]), torch.zeros_like(p["stress"]), p["mass"],
            p["rest_volume"], p["grid_id"], geometry, 1e-4, fields, backend="cpp")
    fields.velocity.copy_(torch.randn(fields.velocity.shape, generator=gen))
    fields.velocity[~(fields.mass > 1e-12)] = 0.0
    return bins, fields


def centre_gaps(fields: GridFields, eps: float) -> torch.Tensor:
    """Mass-centre gaps (float64) along the contact normal of grids 0 and 1 at nodes where both have mass."""
    f = double_copy(fields)
    both = (f.mass[:2] > eps).all(0)
    g0, g1 = f.mass_gradient[0][both], f.mass_gradient[1][both]
    normal = g0 / g0.norm(dim=-1, keepdim=True) - g1 / g1.norm(dim=-1, keepdim=True)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    centres = f.position_moment[:2][:, both] / f.mass[:2][:, both][..., None]
    return ((centres[1] - centres[0]) * normal).sum(-1)


def collision_on(device: str, bins: ParticleBins, fields: GridFields, geometry: GridGeometry, impulse_scale: float,
                 friction: float, max_gap: float) -> GridFields:
    """The compiled contact pass on ``device``; the result on the CPU."""
    on_device = moved(fields, device)
    ops.collision(bins_on(bins, device), geometry, impulse_scale, friction, 1e-12, max_gap, on_device, backend="cpp")
    return moved(on_device, CPU)


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("impulse_scale", [1.0, 0.5])
@pytest.mark.parametrize("friction", [0.0, 0.4])
@pytest.mark.parametrize("n_grids", [2, 3])
def test_collision_matches_reference_and_conserves_momentum(friction, n_grids, impulse_scale, device):
    geometry, _, _ = random_setup(0, n_grids=n_grids)
    bins, fields = contact_grids(n_grids, geometry)
    # A gap threshold that passes about half the nodes, at the widest spacing between neighbouring
    # gap values there, so float32 (kernel) and float64 (twin) gaps fall on the same side of it.
    gaps = torch.sort(centre_gaps(fields, 1e-12)[torch.isfinite(centre_gaps(fields, 1e-12))]).values
    middle = gaps[len(gaps) // 4: 3 * len(gaps) // 4]
    widest = int(torch.argmax(middle[1:] - middle[:-1]))
    max_gap = float(0.5 * (middle[widest] + middle[widest + 1]))
    compiled = collision_on(device, bins, fields, geometry, impulse_scale, friction, max_gap)
    twin = double_copy(fields)
    reference.collision(twin, impulse_scale, friction, 1e-12, max_gap, CONTACT_INSIDE_CELLS * geometry.dx)
    changed = (twin.velocity != fields.velocity.double()).any(-1)
    assert bool(changed.any()), "the test setup must produce contacts"
    assert rel_err(compiled.velocity, twin.velocity) < REL_TOL
    before = (fields.mass.double()[..., None] * fields.velocity.double()).sum((0, 1))
    after = (compiled.mass.double()[..., None] * compiled.velocity.double()).sum((0, 1))
    scale = float((compiled.mass.double()[..., None] * compiled.velocity.double().abs()).sum())
    assert float((after - before).abs().max()) < 1e-6 * scale
    if device != "cpu":
        cpu = collision_on("cpu", bins, fields, geometry, impulse_scale, friction, max_gap)
        assert rel_err(compiled.velocity, cpu.velocity) < REL_TOL


def one_node_fields(gap_in_cells: float, geometry: GridGeometry) -> GridFields:
    """Two bodies at one node: a (mass 1, v = (1, 0.5, 0)) and b (mass 2, at rest), normal +x, their mass
    centres ``gap_in_cells`` apart along it."""
    fields = grids(geometry)
    node = 5
    fields.mass[0, node], fields.mass[1, node] = 1.0, 2.0
    fields.velocity[0, node] = torch.tensor([1.0, 0.5, 0.0])
    fields.mass_gradient[0, node] = torch.tensor([3.0, 0.0, 0.0])   # out of a: toward +x
    fields.mass_gradient[1, node] = torch.tensor([-5.0, 0.0, 0.0])  # out of b: toward -x
    half = 0.5 * gap_in_cells * geometry.dx
    fields.position_moment[0, node] = torch.tensor([-half * 1.0, 0.0, 0.0])  # mass × centre offset
    fields.position_moment[1, node] = torch.tensor([half * 2.0, 0.0, 0.0])
    return fields


def contact_at_one_node(backend: str, device: str, impulse_scale: float, friction: float, gap_in_cells: float,
                        max_gap_cells: float = 0.9) -> torch.Tensor:
    """Velocities (2, 3) of the two bodies at the node after the contact pass."""
    geometry = GridGeometry.from_domain(Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 8), 2)
    fields = moved(one_node_fields(gap_in_cells, geometry), device)
    bins = ParticleBins(*([torch.zeros(0, dtype=torch.int32)] * 6), torch.zeros(1, dtype=torch.int32))
    ops.collision(bins_on(bins, device), geometry, impulse_scale, friction, 1e-12, max_gap_cells * geometry.dx, fields,
                  backend=backend)
    return fields.velocity[:, 5].cpu().double()


BACKEND_DEVICES = [pytest.param("reference", "cpu", id="reference")] + [
    pytest.param("cpp", param.values[0], id=f"cpp-{param.id}", marks=param.marks) for param in KERNEL_DEVICES]


@pytest.mark.parametrize("backend,device", BACKEND_DEVICES)
def test_contact_impulse_by_hand(backend, device):
    # m_a = 1, m_b = 2: reduced mass 2/3; relative velocity (1, 0.5, 0), normal +x: v_n = 1, j_n = 2/3.
    v = contact_at_one_node(backend, device, impulse_scale=1.0, friction=0.0, gap_in_cells=0.4)
    assert torch.allclose(v, torch.tensor([[1 / 3, 0.5, 0.0], [1 / 3, 0.0, 0.0]], dtype=torch.float64), atol=1e-6)
    # Friction caps the tangential impulse at mu_f s j_n (docs/formulas.md §7): s = 0.5, mu_f = 0.4 -> 0.4 * 0.5 * 2/3.
    v = contact_at_one_node(backend, device, impulse_scale=0.5, friction=0.4, gap_in_cells=0.4)
    jn, jt = 0.5 * 2 / 3, 0.4 * 0.5 * 2 / 3
    assert torch.allclose(v, torch.tensor([[1 - jn, 0.5 - jt, 0.0], [jn / 2, jt / 2, 0.0]], dtype=torch.float64),
                          atol=1e-6)
    # s = 0: no normal impulse and so no friction either.
    v = contact_at_one_node(backend, device, impulse_scale=0.0, friction=0.4, gap_in_cells=0.4)
    assert torch.allclose(v, torch.tensor([[1.0, 0.5, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64), atol=1e-7)
    # s = 2: the normal relative velocity is reversed, (1 - s) v_n: kinetic energy at the node is kept.
    v = contact_at_one_node(backend, device, impulse_scale=2.0, friction=0.0, gap_in_cells=0.4)
    assert float(v[0, 0] - v[1, 0]) == pytest.approx(-1.0, abs=1e-6)
    energy = 0.5 * (1.0 * v[0].square().sum() + 2.0 * v[1].square().sum())
    assert float(energy) == pytest.approx(0.5 * 1.25, rel=1e-6)


@pytest.mark.parametrize("backend,device", BACKEND_DEVICES)
def test_contact_needs_the_mass_centres_within_the_gap(backend, device):
    untouched = torch.tensor([[1.0, 0.5, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    # Mass centres 1.2 cells apart along the normal: not touching yet, no impulse.
    assert torch.equal(contact_at_one_node(backend, device, 1.0, 0.0, gap_in_cells=1.2), untouched)
    # Interpenetrated (negative gap): contact.
    assert not torch.equal(contact_at_one_node(backend, device, 1.0, 0.0, gap_in_cells=-0.5), untouched)
    # Without the check (max_gap = inf, no detection test) the distant pair is a contact too.
    assert not torch.equal(contact_at_one_node(backend, device, 1.0, 0.0, gap_in_cells=1.2,
                                               max_gap_cells=math.inf), untouched)


def sheet_and_block_at_one_node(backend: str, device: str, sheet_gradient: tuple[float, float, float],
                                 sheet_centre: float, block_centre: float) -> torch.Tensor:
    """Velocities (2, 3) after the contact pass at one node between a one-layer sheet a (mass 1,
    v = (1, 0.5, 0), its particles ``sheet_centre`` cells along +x from the node) and a block b
    (mass 2, at rest, surface normal -x, mass centre ``block_centre`` cells along +x)."""
    geometry = GridGeometry.from_domain(Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 8), 2)
    fields = grids(geometry)
    node = 5
    fields.mass[0, node], fields.mass[1, node] = 1.0, 2.0
    fields.velocity[0, node] = torch.tensor([1.0, 0.5, 0.0])
    fields.mass_gradient[0, node] = torch.tensor(sheet_gradient)
    fields.mass_gradient[1, node] = torch.tensor([-5.0, 0.0, 0.0])
    fields.position_moment[0, node] = torch.tensor([sheet_centre * geometry.dx, 0.0, 0.0])
    fields.position_moment[1, node] = torch.tensor([2.0 * block_centre * geometry.dx, 0.0, 0.0])
    fields = moved(fields, device)
    bins = ParticleBins(*([torch.zeros(0, dtype=torch.int32)] * 6), torch.zeros(1, dtype=torch.int32))
    ops.collision(bins_on(bins, device), geometry, 1.0, 0.0, 1e-12, 0.9 * geometry.dx, fields, backend=backend)
    return fields.velocity[:, node].cpu().double()


@pytest.mark.parametrize("backend,device", BACKEND_DEVICES)
def test_contact_normal_where_a_sheet_gives_none(backend, device):
    # The normal is the block's (+x) alone: j_n = 2/3 along x, the sheet's sliding speed is kept.
    expected = torch.tensor([[1 / 3, 0.5, 0.0], [1 / 3, 0.0, 0.0]], dtype=torch.float64)
    # The sheet passes 0.1 cell from the node, the block's surface about 0.1 cell beyond it: the
    # sheet's mass gradient there points along it (toward an edge, +y), and the averaged normal
    # would be (1, 1, 0) / sqrt 2.
    v = sheet_and_block_at_one_node(backend, device, (0.0, 3.0, 0.0), 0.1, 0.5)
    assert torch.allclose(v, expected, atol=1e-6)
    # The node lies behind the sheet (0.6 cell before it): the sheet's gradient points away from the
    # block, the averaged normal cancels, and the node used to carry no contact.
    v = sheet_and_block_at_one_node(backend, device, (-3.0, 0.0, 0.0), 0.6, 1.2)
    assert torch.allclose(v, expected, atol=1e-6)


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("wall", ["none", "slip", "sticky", "separate"])
@pytest.mark.parametrize("ground", [None, 0.3])
def test_boundaries_match_reference(wall, ground, device):
    geometry, _, _ = random_setup(1, n_grids=2)
    bins, fields = contact_grids(1, geometry)
    twin = double_copy(fields)
    reference.boundaries(twin, geometry, wall, ground, 0.5, 1e-12)

    def on(where: str) -> GridFields:
        out = moved(fields, where)
        ops.boundaries(bins_on(bins, where), geometry, wall, ground, 0.5, 1e-12, out, backend="cpp")
        return moved(out, CPU)

    compiled = on(device)
    assert rel_err(compiled.velocity, twin.velocity) < REL_TOL
    if device != "cpu":
        assert rel_err(compiled.velocity, on("cpu").velocity) < REL_TOL


def material_table() -> torch.Tensor:
    materials = [ElasticMaterial(E=1e4, nu=0.3, density=1.0),
                 NACCMaterial(E=2e5, nu=0.4, density=2.0, alpha0=-0.02, beta=0.5, xi=1.0, M=2.36),
                 NACCMaterial(E=1e6, nu=0.3, density=5.0, alpha0=-0.005, beta=2.0, xi=3.0, M=1.5)]
    return MaterialTable(materials).table(torch.device("cpu"))


def g2p_on(device: str, p: dict, F_E, state, fractured, material_id, table, fields: GridFields,
           geometry: GridGeometry, dt: float, with_dissipated: bool = False):
    """The compiled G2P on ``device``; tensors back on the CPU, the stats as they are, and with
    ``with_dissipated`` the energy the updates took (per unit rest volume) last."""
    on = [t.to(device) for t in (p["x"], F_E, state, fractured, p["grid_id"], material_id, table)]
    dissipated = torch.full((len(p["x"]),), float("nan"), device=device) if with_dissipated else None
    out = ops.g2p(*on, moved(fields, device), geometry, dt, backend="cpp", dissipated=dissipated)
    return [t.cpu() for t in out[:7]] + [out[7]] + ([dissipated.cpu()] if dissipated is not None else [])


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("seed", range(3))
def test_g2p_and_return_map_match_reference(seed, device):
    geometry, p, gen = random_setup(seed)
    n = p["x"].shape[0]
    bins, fields = contact_grids(seed, geometry)
    table = material_table()
    material_id = torch.randint(0, table.shape[0], (n,), generator=gen, dtype=torch.int32)
    F_E = (torch.eye(3) + 0.05 * torch.randn(n, 3, 3, generator=gen)).contiguous()
    alpha = -0.03 * torch.rand(n, generator=gen)
    fractured = torch.rand(n, generator=gen) < 0.1
    dt = 2e-3  # large enough that a fair share of particles plastically yields
    out = g2p_on(device, p, F_E, alpha, fractured, material_id, table, fields, geometry, dt)
    twin = reference.g2p(double(p["x"]), double(F_E), double(alpha), fractured, p["grid_id"], material_id,
                         table.double(), fields.velocity.double(), geometry, dt, *geometry.clamp_bounds())
    names = ["x", "v", "C", "F_E", "alpha", "stress"]
    for name, a, b in zip(names, out[:6], twin[:6]):
        assert rel_err(a, b) < REL_TOL, name
    assert torch.equal(out[6], twin[6])
    assert out[7].clamped == twin[7].clamped and out[7].first_nonfinite == twin[7].first_nonfinite == -1
    assert abs(out[7].max_speed - twin[7].max_speed) <= REL_TOL * twin[7].max_speed
    # The return map really ran: some particles changed their hardening state.
    assert bool((out[4] != alpha).any())
    if device != "cpu":
        cpu = g2p_on("cpu", p, F_E, alpha, fractured, material_id, table, fields, geometry, dt)
        for name, a, b in zip(names, out[:6], cpu[:6]):
            assert rel_err(a, b) < REL_TOL, name
        assert torch.equal(out[6], cpu[6]) and out[7].clamped == cpu[7].clamped


@pytest.mark.parametrize("device", KERNEL_DEVICES)
def test_g2p_with_brittle_particles_matches_reference(device):
    """Brittle particles with their own (Weibull) strengths, partly damaged, beside NACC ones: the
    compiled G2P (series, eigen and SVD tiers of the update) gives the twin's damage and stress."""
    geometry, p, gen = random_setup(7)
    n = p["x"].shape[0]
    bins, fields = contact_grids(7, geometry)
    glass = BrittleMaterial(E=1e6, nu=0.2, density=50.0, strength=1e4, fracture_energy=1.0, weibull_m=6.0)
    table = MaterialTable([glass, NACCMaterial(E=2e5, nu=0.4, density=2.0, alpha0=-0.02, beta=0.5, xi=1.0, M=2.36)],
                          cell_size=geometry.dx).table(torch.device("cpu"))
    material_id = (torch.rand(n, generator=gen) < 0.2).to(torch.int32)   # 80 % brittle
    brittle = material_id == 0
    F_E = (torch.eye(3) + 0.01 * torch.randn(n, 3, 3, generator=gen)).contiguous()
    alpha = torch.where(brittle, torch.where(torch.rand(n, generator=gen) < 0.7, 0.0, torch.rand(n, generator=gen)),
                        torch.full((n,), -0.01))
    strength = torch.from_numpy(glass.strengths(np.arange(n), np.full(n, 1e-6), seed=3).astype(np.float32))
    state = torch.cat([alpha[:, None], strength[:, None], torch.zeros(n, 3)], 1)   # damage, strength, normal
    fractured = alpha >= 0.5
    dt = 2e-4
    out = g2p_on(device, p, F_E, state, fractured, material_id, table, fields, geometry, dt, with_dissipated=True)
    out[4] = out[4][:, 0]
    twin_dissipated = torch.empty(n, dtype=torch.float64)
    twin = list(reference.g2p(double(p["x"]), double(F_E), double(state), fractured, p["grid_id"], material_id,
                              table.double(), fields.velocity.double(), geometry, dt, *geometry.clamp_bounds(),
                              dissipated=twin_dissipated))
    twin[4] = twin[4][:, 0]
    for name, a, b in zip(["x", "v", "C", "F_E", "stress"], [out[i] for i in (0, 1, 2, 3, 5)],
                          [twin[i] for i in (0, 1, 2, 3, 5)]):
        assert rel_err(a, b) < REL_TOL, name
    grew = brittle & (twin[4] > alpha.double())
    assert int(grew.sum()) > 100, "the substep must damage a fair share of the brittle particles"
    assert float((out[4].double() - twin[4]).abs().max()) < 2e-3
    assert float((out[6] != twin[6]).float().mean()) < 1e-3
    # The energy the damage took: the kernel's own (g(d_old) - g(d)) psi+ against the twin's.
    dissipated = out[8].double()
    assert bool((dissipated[~grew & (out[4].double() == alpha.double())] == 0).all())
    assert float(twin_dissipated.sum()) > 0 and float(dissipated.min()) >= 0
    assert float(dissipated.sum()) == pytest.approx(float(twin_dissipated.sum()), rel=2e-3)
    if device != "cpu":
        cpu = g2p_on("cpu", p, F_E, state, fractured, material_id, table, fields, geometry, dt, with_dissipated=True)
        assert rel_err(out[5], cpu[5]) < REL_TOL and float((out[4] - cpu[4][:, 0]).abs().max()) < 2e-3


def test_g2p_reports_the_first_non_finite_particle():
    geometry, p, gen = random_setup(0, n=500)
    bins, fields = contact_grids(0, geometry)
    n = p["x"].shape[0]
    table = material_table()
    material_id = torch.zeros(n, dtype=torch.int32)
    F_E = torch.eye(3).repeat(n, 1, 1)
    F_E[123, 0, 0] = float("nan")
    F_E[321, 1, 1] = float("inf")
    args = (p["x"], F_E, torch.zeros(n), torch.zeros(n, dtype=torch.bool), p["grid_id"], material_id, table)
    compiled = ops.g2p(*args, fields, geometry, 1e-4, backend="cpp")[7]
    twin = ops.g2p(*args, fields, geometry, 1e-4, backend="reference")[7]
    assert compiled.first_nonfinite == twin.first_nonfinite == 123
