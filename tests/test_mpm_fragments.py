"""Crack opening inside an object: damage-gradient partitioning of the object grids.

Kernels against their torch twins (P2G damage, damage gradients and node references, fields A / B
at split nodes, split-aware G2P), thread-count determinism, and physics: a pre-cracked bar comes
apart only with fragments, momentum is conserved with fragments on, energy never rises. Bigger
runs (block drops, the cost) are in benchmarks/bench_fragments.py and
benchmarks/bench_mpm.py.
"""
from __future__ import annotations

import dataclasses
import math
import textwrap

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from fracture_gs.config.scene import SceneError, parse_scene
from fracture_gs.mpm import ops, reference
from fracture_gs.testing.fragment_scenes import block_drop, colliding_spheres, precracked_bar
from fracture_gs.mpm.fragments import (count_fragments, fragment_ids, fragment_sizes, fragments_per_object,
                                      link_radius, object_link_radii, piece_ranks)
from fracture_gs.mpm.grid import FragmentFields, GridFields, GridGeometry, ParticleBins
from fracture_gs.mpm.types import BLOCK, ContactSettings, Domain
from kernel_devices import KERNEL_DEVICES
from thread_counts import last_lines_per_thread_count

pytestmark = pytest.mark.extension  # tests/conftest.py: skipped without _C, failed in CI

REL_TOL = 1e-4
CPU = torch.device("cpu")


def rel_err(actual: torch.Tensor, expected: torch.Tensor) -> float:
    if expected.numel() == 0:
        return 0.0
    scale = max(float(expected.double().abs().max()), 1e-30)
    return float((actual.double() - expected.double()).abs().max()) / scale


def cracked_particles(seed: int, n_grids: int = 2):
    """Two jittered blocks (one per grid) overlapping in a contact region; a damaged slab crosses
    each. Returns (geometry of the K grids, particle dict)."""
    gen = torch.Generator().manual_seed(seed)
    domain = Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 16)
    geometry = GridGeometry.from_domain(domain, n_grids)
    spacing = domain.dx / 2
    axis = torch.arange(0.3, 0.7, spacing)
    lattice = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    x = (lattice + 0.3 * spacing * torch.randn(lattice.shape, generator=gen)).float().contiguous()
    n = x.shape[0]
    grid_id = (x[:, 1] > 0.5 + 0.2 * (x[:, 2] - 0.5)).to(torch.int32)
    damaged = ((x[:, 0] - 0.5).abs() < 0.6 * spacing) | (torch.rand(n, generator=gen) < 0.01)
    particles = {
        "x": x, "v": torch.randn(n, 3, generator=gen), "C": 3.0 * torch.randn(n, 3, 3, generator=gen),
        "stress": 1e3 * torch.randn(n, 3, 3, generator=gen), "mass": 0.5 + torch.rand(n, generator=gen),
        "rest_volume": 1e-4 * (0.5 + torch.rand(n, generator=gen)), "grid_id": grid_id.contiguous(),
        "damaged": damaged.contiguous(),
    }
    return geometry, particles


def field_geometry(geometry: GridGeometry) -> GridGeometry:
    from dataclasses import replace
    return replace(geometry, n_grids=2 * geometry.n_grids)


def cast(fields: GridFields, dtype: torch.dtype, device: torch.device = CPU) -> GridFields:
    def convert(t):
        if t is None:
            return None
        return t.to(device=device, dtype=dtype if t.is_floating_point() else t.dtype).clone()
    return GridFields(*(convert(getattr(fields, name)) for name in
                        ("mass", "momentum", "velocity", "mass_gradient", "position_moment", "damage", "reference")))


P2G_KEYS = ("x", "v", "C", "stress", "mass", "rest_volume")


def compiled_partition(device: str, geometry: GridGeometry, p: dict, dt: float, split_gradient: float):
    """P2G, references and fields A / B with the compiled kernels on ``device``; results on the CPU."""
    fields_geo = field_geometry(geometry)
    on = {k: v.to(device) for k, v in p.items()}
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    bins = type(bins)(*(getattr(bins, f) .to(device) for f in bins.__dataclass_fields__))
    fields = GridFields.zeros(fields_geo, torch.device(device), with_contact=True, with_fragments=True)
    ops.p2g(bins, *(on[k] for k in P2G_KEYS), on["grid_id"], fields_geo, dt, fields, backend="cpp",
            damaged=on["damaged"])
    after_p2g = cast(fields, torch.float32)
    gradient = ops.fragment_reference(bins, on["x"], on["grid_id"], geometry, 1e-12, split_gradient, fields,
                                      backend="cpp")
    after_reference = cast(fields, torch.float32)
    split_particle, split_keys, side_mask = ops.fragment_partition(
        bins, *(on[k] for k in P2G_KEYS), on["grid_id"], geometry, dt, gradient, split_gradient, fields, backend="cpp")
    return (bins, after_p2g, gradient.cpu(), after_reference, cast(fields, torch.float32), split_particle.cpu(),
            split_keys.cpu(), side_mask.cpu())


def touched_mask(bins, geometry: GridGeometry) -> torch.Tensor:
    """(K, nodes) bool: nodes of the blocks some stencil reaches (where the compiled kernels write)."""
    mask = torch.zeros(geometry.n_grids * geometry.n_blocks, dtype=torch.bool)
    mask[bins.touched.cpu().long()] = True
    return mask.view(geometry.n_grids, geometry.n_blocks).repeat_interleave(BLOCK ** 3, dim=1)


@pytest.mark.parametrize("device", KERNEL_DEVICES)
@pytest.mark.parametrize("seed", range(2))
def test_fragment_kernels_match_reference(seed, device):
    geometry, p = cracked_particles(seed)
    K, dt, split_gradient = geometry.n_grids, 1e-4, 0.25 / geometry.dx
    bins, p2g_fields, gradient, ref_fields, parted, split_particle, split_keys, side_mask = compiled_partition(
        device, geometry, p, dt, split_gradient)
    touched = touched_mask(bins, geometry)

    # 1. P2G's damage lane: Σ w m D.
    twin = GridFields.zeros(field_geometry(geometry), CPU, with_contact=True, with_fragments=True)
    twin = cast(twin, torch.float64)
    reference.p2g(*(p[k].double() for k in P2G_KEYS), p["grid_id"], field_geometry(geometry), dt, twin,
                  p["damaged"])
    assert rel_err(p2g_fields.damage[:K][touched], twin.damage[:K][touched]) < REL_TOL
    assert float(twin.damage.sum()) == pytest.approx(float((p["mass"].double() * p["damaged"]).sum()), rel=1e-10)

    # 2. Damage gradients and references (the twin reads the compiled P2G fields).
    twin_ref = cast(p2g_fields, torch.float32)
    twin_gradient = reference.fragment_reference(p["x"], p["grid_id"], geometry, 1e-12, split_gradient, twin_ref)
    assert rel_err(gradient, twin_gradient) < REL_TOL
    assert float(gradient.norm(dim=1).max()) > split_gradient  # the slab does give split nodes
    keys, twin_keys = ref_fields.reference[:K][touched], twin_ref.reference[:K][touched]
    winner_norm = gradient.norm(dim=1)[keys & 0xFFFFFFFF]
    twin_norm = twin_gradient.norm(dim=1)[twin_keys & 0xFFFFFFFF]
    assert torch.equal(keys > 0, twin_keys > 0)
    assert rel_err(winner_norm[keys > 0], twin_norm[keys > 0]) < REL_TOL
    # Same winner almost everywhere (|∇D_p|² may differ in its last bit, which can flip near-ties).
    assert float(((keys & 0xFFFFFFFF) == (twin_keys & 0xFFFFFFFF)).double().mean()) > 0.99

    # 3. Fields A and B at split nodes, from the same gradients and references.
    twin_parted = cast(ref_fields, torch.float64)
    twin_split, twin_keys_split, twin_side_mask = reference.fragment_partition(
        *(p[k].double() for k in P2G_KEYS), p["grid_id"], geometry, dt, gradient.double(), split_gradient,
        twin_parted)
    assert torch.equal(split_particle, twin_split)
    assert torch.equal(split_keys, twin_keys_split)
    # Sides per stencil node (the sign of ∇D_p · ∇D_ref in float32 vs float64 may flip a near-tie).
    assert int((side_mask != 0).sum()) > 0, "some particles must lie on side B"
    assert float((side_mask == twin_side_mask).double().mean()) > 0.999
    assert int((side_mask[split_particle == 0] != 0).sum()) == 0
    assert 0 < int(split_particle.sum()) < len(split_particle)
    split_nodes = reference._split_nodes(ref_fields.reference[:K], split_gradient).view(K, -1)
    both = torch.cat([split_nodes, split_nodes])
    for name in ("mass", "momentum", "mass_gradient", "position_moment"):
        assert rel_err(getattr(parted, name)[both], getattr(twin_parted, name)[both]) < REL_TOL, name
    assert float(twin_parted.mass[K:].sum()) > 0.0, "some particles must lie on side B"
    # The partition moves mass and momentum between the fields, never creates any.
    for name in ("mass", "momentum"):
        before = getattr(twin, name)[:K][split_nodes].sum(0)
        after = getattr(twin_parted, name)[:K][split_nodes].sum(0) + getattr(twin_parted, name)[K:][split_nodes].sum(0)
        assert float((after - before).abs().max()) <= 1e-4 * float(before.abs().max()), name

    # 4. Split-aware G2P on random field velocities.
    gen = torch.Generator().manual_seed(seed + 7)
    parted.velocity.copy_(torch.randn(parted.velocity.shape, generator=gen))
    frag = FragmentFields(gradient, ref_fields.reference, split_particle, split_gradient)
    state = (p["x"], torch.eye(3).expand(len(p["x"]), 3, 3).contiguous(), torch.full((len(p["x"]),), -0.01),
             p["damaged"], p["grid_id"], torch.zeros(len(p["x"]), dtype=torch.int32))  # as the fracture flags
    from fracture_gs.materials import MaterialTable, NACCMaterial
    table = MaterialTable([NACCMaterial(E=1e4, nu=0.3, density=1, alpha0=-0.01, beta=0.5, xi=1, M=2.36)]).table(CPU)
    compiled = ops.g2p(*(t.to(device) for t in state), table.to(device), cast(parted, torch.float32, torch.device(device)),
                       geometry, dt, backend="cpp",
                       fragments=FragmentFields(*(t.to(device) for t in frag.as_list()), split_gradient))
    twin_out = ops.g2p(*state, table, parted, geometry, dt, backend="reference", fragments=frag)
    velocity_scale = float(parted.velocity.abs().max())
    assert float((compiled[1].cpu() - twin_out[1]).abs().max()) <= REL_TOL * velocity_scale
    assert float((compiled[2].cpu() - twin_out[2]).abs().max()) <= REL_TOL * velocity_scale / geometry.dx
    # The same with the partition's side mask (the solver's path): sides read from the mask.
    masked = FragmentFields(*(t.to(device) for t in frag.as_list()), split_gradient, side_mask.to(device))
    compiled_masked = ops.g2p(*(t.to(device) for t in state), table.to(device),
                              cast(parted, torch.float32, torch.device(device)), geometry, dt, backend="cpp",
                              fragments=masked)
    assert float((compiled_masked[1].cpu() - twin_out[1]).abs().max()) <= REL_TOL * velocity_scale
    assert float((compiled_masked[2].cpu() - twin_out[2]).abs().max()) <= REL_TOL * velocity_scale / geometry.dx
    plain = ops.g2p(*state, table, parted, geometry, dt, backend="reference")
    assert float((plain[1] - twin_out[1]).abs().max()) > 1e-3 * velocity_scale, "split nodes must change G2P"


def test_grouped_g2p_reads_each_lanes_side():
    """The CPU G2P gathers runs of consecutive particles with one stencil base together, side B
    included (each lane selects field A or B per node from its side mask). The same particles and
    fields in two orders, shuffled (no runs: one by one) and sorted by stencil base (runs of up to
    8, many with side-B lanes), give the same results particle by particle."""
    geometry, p = cracked_particles(4)
    dt, split_gradient = 1e-4, 0.25 / geometry.dx
    bins, _, gradient, ref_fields, parted, split_particle, _, side_mask = compiled_partition(
        "cpu", geometry, p, dt, split_gradient)
    gen = torch.Generator().manual_seed(9)
    parted.velocity.copy_(torch.randn(parted.velocity.shape, generator=gen))
    n = len(p["x"])
    F = (torch.eye(3) + 0.01 * torch.randn(n, 3, 3, generator=gen)).contiguous()
    from fracture_gs.materials import MaterialTable, NACCMaterial
    table = MaterialTable([NACCMaterial(E=1e4, nu=0.3, density=1, alpha0=-0.01, beta=0.5, xi=1, M=2.36)]).table(CPU)

    def run(order: torch.Tensor):
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(n)
        keys = ref_fields.reference
        remapped = torch.where(keys > 0, ((keys >> 32) << 32) | inverse[(keys & 0xFFFFFFFF)], keys)
        frag = FragmentFields(gradient[order].contiguous(), remapped, split_particle[order].contiguous(),
                              split_gradient, side_mask[order].contiguous())
        out = ops.g2p(p["x"][order].contiguous(), F[order].contiguous(), torch.full((n,), -0.01),
                      p["damaged"][order].contiguous(), p["grid_id"][order].contiguous(),
                      torch.zeros(n, dtype=torch.int32), table, parted, geometry, dt, backend="cpp", fragments=frag)
        return [t[inverse] for t in out[:6]]

    # A run: consecutive particles with one (grid, stencil base); G2P groups runs of 3 or more.
    base = torch.floor(p["x"].double() / geometry.dx - 0.5).long()
    key = ((p["grid_id"].long() * 64 + base[:, 0]) * 64 + base[:, 1]) * 64 + base[:, 2]

    def side_b_in_runs(order: torch.Tensor) -> int:
        ordered = key[order]
        starts = torch.ones(n, dtype=torch.bool)
        starts[1:] = ordered[1:] != ordered[:-1]
        run_id = torch.cumsum(starts.long(), 0) - 1
        run_length = torch.bincount(run_id)[run_id]
        return int(((side_mask[order] != 0) & (run_length >= 3)).sum())

    shuffled = torch.randperm(n, generator=torch.Generator().manual_seed(10))
    by_base = torch.argsort(key, stable=True)
    assert side_b_in_runs(shuffled) == 0
    assert side_b_in_runs(by_base) >= 20, "the sorted order must put side-B particles in runs"
    scattered = run(shuffled)
    grouped = run(by_base)
    # The same gather (a few float ulp apart: other operation order). F_trial differs by an ulp of
    # F, which is 1e-5 of these strains (~1 %): the stress as the twin tests allow (REL_TOL).
    for name, a, b, tolerance in zip(("x", "v", "C", "F_E", "state", "stress"), scattered, grouped,
                                     (1e-6, 1e-6, 1e-6, 1e-5, 1e-5, REL_TOL)):
        assert rel_err(b, a) <= tolerance, name


@pytest.mark.parametrize("device", KERNEL_DEVICES)
def test_crack_normals_make_references_and_cut_along_their_plane(device):
    """A few isolated cracked particles (brittle, complete damage) carry crack normals as their split
    directions (3 columns of the brittle state block, as the solver passes them): the compiled
    reference pass gives the twin's vectors and keys, every node their stencils reach is split, and
    the particles around a lone crack are parted by the side of its plane."""
    geometry, p = cracked_particles(3, n_grids=1)
    p["grid_id"] = torch.zeros_like(p["grid_id"])
    n = len(p["x"])
    gen = torch.Generator().manual_seed(5)
    cracked = torch.zeros(n, dtype=torch.bool)
    cracked[torch.randperm(n, generator=gen)[:6]] = True
    p["damaged"] = cracked.contiguous()
    block = torch.zeros(n, 5)   # damage, strength, normal
    directions = torch.randn(6, 3, generator=gen)
    block[cracked, 2:] = directions / directions.norm(dim=1, keepdim=True)
    normals = block[:, 2:]
    scale = 4.0 / geometry.dx
    split_gradient = 0.25 / geometry.dx
    fields_geo = field_geometry(geometry)
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    fields = GridFields.zeros(fields_geo, CPU, with_contact=True, with_fragments=True)
    ops.p2g(bins, *(p[k] for k in P2G_KEYS), p["grid_id"], fields_geo, 1e-4, fields, backend="cpp",
            damaged=p["damaged"])
    twin_fields = cast(fields, torch.float32)
    on = cast(fields, torch.float32, torch.device(device))
    bins_on = type(bins)(*(getattr(bins, f).to(device) for f in bins.__dataclass_fields__))
    gradient = ops.fragment_reference(bins_on, p["x"].to(device), p["grid_id"].to(device), geometry, 1e-12,
                                      split_gradient, on, backend="cpp", split_direction=block.to(device)[:, 2:],
                                      direction_scale=scale).cpu()
    twin_gradient = reference.fragment_reference(p["x"], p["grid_id"], geometry, 1e-12, split_gradient, twin_fields,
                                                 normals, scale)
    assert torch.equal(gradient[cracked], scale * normals[cracked])
    assert rel_err(gradient, twin_gradient) < REL_TOL
    keys = on.reference[:1].cpu().reshape(-1)
    twin_keys = twin_fields.reference[:1].reshape(-1)
    assert torch.equal(keys > 0, twin_keys > 0)
    assert torch.equal(keys & 0xFFFFFFFF, twin_keys & 0xFFFFFFFF)
    winners = torch.unique(keys[keys > 0] & 0xFFFFFFFF)
    assert set(winners.tolist()) <= set(torch.nonzero(cracked).flatten().tolist())   # the cracks are the references
    # Every node a cracked particle's stencil reaches is split; particles around a lone crack are parted
    # by the side of its plane (their damage gradients point toward it).
    node, _, _, _ = reference._stencil(p["x"], geometry)
    assert bool((keys[node[cracked].flatten()] > 0).all())
    r = int(torch.nonzero(cracked)[0])
    near = torch.nonzero(((p["x"] - p["x"][r]).norm(dim=1) < 0.9 * geometry.dx) & ~cracked).flatten()
    side = (gradient[near] * normals[r]).sum(1) < 0
    plane = ((p["x"][near] - p["x"][r]) * normals[r]).sum(1) > 0
    assert len(near) >= 4 and float((side == plane).float().mean()) >= 0.75


def test_p2g_gives_contact_fields_wherever_a_node_can_split():
    """With fragments, P2G sums the contact fields (mass gradient, position moment) only in blocks
    that may hold a split node (within reach of a damaged particle) and in contact blocks. Every block
    the reference pass splits must have them in full, as the twin sums them over every node: a few
    isolated damaged particles and a split gradient low enough that any particle reaching damage
    splits its whole stencil, the farthest a split reaches (blocks c - 1 .. c + 2 of a damaged cell c)."""
    domain = Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 32)
    geometry = GridGeometry.from_domain(domain, 1)
    gen = torch.Generator().manual_seed(11)
    spacing = domain.dx / 2
    axis = torch.arange(0.15, 0.85, spacing)
    lattice = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    x = (lattice + 0.3 * spacing * torch.randn(lattice.shape, generator=gen)).float().contiguous()
    n = x.shape[0]
    damaged = torch.zeros(n, dtype=torch.bool)
    damaged[torch.randperm(n, generator=gen)[:12]] = True
    p = {"x": x, "v": torch.randn(n, 3, generator=gen), "C": torch.randn(n, 3, 3, generator=gen),
         "stress": 1e2 * torch.randn(n, 3, 3, generator=gen), "mass": 0.5 + torch.rand(n, generator=gen),
         "rest_volume": 1e-4 * torch.ones(n), "grid_id": torch.zeros(n, dtype=torch.int32), "damaged": damaged}
    split_gradient, dt = 1e-3 / domain.dx, 1e-4
    fields_geo = field_geometry(geometry)
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    fields = GridFields.zeros(fields_geo, CPU, with_contact=True, with_fragments=True)
    ops.p2g(bins, *(p[k] for k in P2G_KEYS), p["grid_id"], fields_geo, dt, fields, backend="cpp",
            damaged=p["damaged"])
    after_p2g = cast(fields, torch.float64)
    ops.fragment_reference(bins, p["x"], p["grid_id"], geometry, 1e-12, split_gradient, fields, backend="cpp")
    split = reference._split_nodes(fields.reference[0], split_gradient).view(geometry.n_blocks, -1).any(1)
    twin = cast(GridFields.zeros(fields_geo, CPU, with_contact=True, with_fragments=True), torch.float64)
    reference.p2g(*(p[k].double() for k in P2G_KEYS), p["grid_id"], fields_geo, dt, twin, p["damaged"])
    in_split_block = split.repeat_interleave(BLOCK ** 3)
    for name in ("mass_gradient", "position_moment"):
        got = getattr(after_p2g, name)[0].reshape(-1, 3)[in_split_block]
        assert rel_err(got, getattr(twin, name)[0].reshape(-1, 3)[in_split_block]) < REL_TOL, name
    # The data reaches the far end: some split block lies outside the window (c .. c + 1) of every
    # damaged particle's cell.
    base = torch.floor(x.double() / domain.dx - 0.5).long()       # stencil base node (lower corner 0)
    damaged_cells = torch.unique(torch.div(base[damaged], BLOCK, rounding_mode="floor"), dim=0)
    split_ijk = torch.stack(torch.unravel_index(torch.nonzero(split).flatten(), geometry.blocks), 1)
    offset = split_ijk[:, None, :] - damaged_cells[None, :, :]
    in_window = ((offset >= 0) & (offset <= 1)).all(2).any(1)
    assert int(split.sum()) > 0 and int((~in_window).sum()) > 0


def test_partition_empties_side_a_where_every_particle_is_on_side_b():
    """Field A at a split node is P2G's sum minus side B; where every particle of the node is on side
    B that difference is only rounding, and the node's whole sum must move to B with A exactly 0
    (split_node_fields), in the kernel and in the twin. A row of particles along x: the first is
    every node's reference, all others point their damage gradient the other way (side B)."""
    domain = Domain((0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 16)
    geometry = GridGeometry.from_domain(domain, 1)
    dx = domain.dx
    x = torch.stack([torch.tensor([0.3 + 0.5 * i * dx, 0.5 + 0.1 * dx, 0.5 + 0.2 * dx]) for i in range(9)]).float()
    n = x.shape[0]
    gen = torch.Generator().manual_seed(3)
    p = {"x": x.contiguous(), "v": torch.randn(n, 3, generator=gen), "C": torch.randn(n, 3, 3, generator=gen),
         "stress": 1e2 * torch.randn(n, 3, 3, generator=gen), "mass": 0.5 + torch.rand(n, generator=gen),
         "rest_volume": 1e-4 * torch.ones(n), "grid_id": torch.zeros(n, dtype=torch.int32),
         "damaged": torch.ones(n, dtype=torch.bool)}
    gradient = torch.tensor([[-1.0 / dx, 0.0, 0.0]]).repeat(n, 1)
    gradient[0] = torch.tensor([1.0 / dx, 0.0, 0.0])                  # the reference: side A
    split_gradient, dt = 0.25 / dx, 1e-4
    bins = ops.bin_particles(p["x"], p["grid_id"], geometry, backend="cpp")
    fields = GridFields.zeros(field_geometry(geometry), CPU, with_contact=True, with_fragments=True)
    ops.p2g(bins, *(p[k] for k in P2G_KEYS), p["grid_id"], field_geometry(geometry), dt, fields, backend="cpp",
            damaged=p["damaged"])
    p2g_mass = fields.mass[0].clone()
    norm_sq_bits = int(torch.tensor([float(gradient[0].square().sum())]).view(torch.int32))
    fields.reference[0][p2g_mass > 0] = norm_sq_bits << 32              # particle 0 references every node
    twin = cast(fields, torch.float64)
    ops.fragment_partition(bins, *(p[k] for k in P2G_KEYS), p["grid_id"], geometry, dt, gradient, split_gradient,
                           fields, backend="cpp")
    reference.fragment_partition(*(p[k].double() for k in P2G_KEYS), p["grid_id"], geometry, dt, gradient.double(),
                                 split_gradient, twin)
    index, weight, _, _ = reference._stencil(x, geometry)
    reached_by_reference = torch.zeros_like(p2g_mass, dtype=torch.bool)
    reached_by_reference[index[0][weight[0] > 0]] = True
    only_b = (p2g_mass > 0) & ~reached_by_reference
    assert int(only_b.sum()) > 0, "the row must reach nodes the reference does not"
    assert bool((fields.mass[0][only_b] == 0).all()) and bool((twin.mass[0][only_b] == 0).all())
    assert torch.equal(fields.mass[1][only_b], p2g_mass[only_b])        # moved whole, not re-summed
    assert bool((fields.momentum[0][only_b] == 0).all())
    # Where the reference is, A keeps its share and A + B is P2G's sum.
    both = reached_by_reference & (fields.mass[1] > 0)
    assert int(both.sum()) > 0 and bool((fields.mass[0][both] > 0).all())
    assert float((fields.mass[0] + fields.mass[1] - p2g_mass).abs().max()) <= 1e-6 * float(p2g_mass.max())
    assert rel_err(fields.mass, twin.mass) < REL_TOL and rel_err(fields.momentum, twin.momentum) < REL_TOL


def test_fragment_clear_zeroes_only_the_given_blocks():
    geometry = GridGeometry.from_domain(Domain((0, 0, 0), (1, 1, 1), 16), 2)
    for backend in ("cpp", "reference"):
        fields = GridFields.zeros(geometry, CPU, with_contact=True)
        for name in ("mass", "momentum", "velocity", "mass_gradient", "position_moment"):
            getattr(fields, name).fill_(1.0)
        keys = torch.tensor([3, geometry.n_blocks + 5], dtype=torch.int32)
        ops.fragment_clear(keys, geometry, fields, backend=backend)
        cleared = torch.zeros(2, geometry.n_blocks, dtype=torch.bool)
        cleared[0, 3] = cleared[1, 5] = True
        cleared = cleared.repeat_interleave(BLOCK ** 3, dim=1)
        assert float(fields.mass[cleared].abs().max()) == 0.0 and bool((fields.mass[~cleared] == 1).all())
        assert float(fields.velocity[cleared].abs().max()) == 0.0


def test_fragment_field_blocks_match_twin():
    """The blocks of the field passes after a split (compiled, CPU) equal the torch version: touched
    followed by the field-B keys, and the sorted union of the contact and the split blocks."""
    geometry = GridGeometry.from_domain(Domain((0, 0, 0), (1, 1, 1), 32), 2)
    gen = torch.Generator().manual_seed(5)
    touched = torch.unique(torch.randint(0, 2 * geometry.n_blocks, (200,), generator=gen)).to(torch.int32)
    contact = torch.unique(torch.randint(0, geometry.n_blocks, (40,), generator=gen)).to(torch.int32)
    split_keys = touched[torch.randperm(len(touched), generator=gen)[:60]].sort().values
    bins = ParticleBins(*(torch.zeros(1, dtype=torch.int32) for _ in range(5)), touched, contact)
    compiled = ops.fragment_field_blocks(bins, split_keys, geometry, backend="cpp")
    twin = ops.fragment_field_blocks(bins, split_keys, geometry, backend="reference")
    for got, want in zip(compiled, twin):
        assert got.dtype == torch.int32 and torch.equal(got, want)
    assert torch.equal(compiled[0][len(touched):], split_keys + 2 * geometry.n_blocks)
    assert set(compiled[1].tolist()) == set(contact.tolist()) | set((split_keys % geometry.n_blocks).tolist())


STATE_HASH_SCRIPT = textwrap.dedent("""
    import hashlib, sys
    from fracture_gs.testing.fragment_scenes import precracked_bar
    solver, _ = precracked_bar(grid=32, length=0.3, width=0.1, backend="cpp")
    split = 0
    for _ in range(30):
        solver.step(solver.stable_dt())
        split += solver.last_split_particles
    digest = hashlib.sha256()
    for name in ("x", "v", "C", "F_E", "alpha", "fractured"):
        digest.update(getattr(solver.state, name).numpy().tobytes())
    print(split, digest.hexdigest())
""")


def test_fragment_kernels_are_deterministic_for_any_thread_count():
    outputs = last_lines_per_thread_count(STATE_HASH_SCRIPT)
    assert int(outputs[0].split()[0]) > 0, "the scene must really split nodes"
    assert len(set(outputs)) == 1, outputs


# ----------------------------------------------------------------------------- physics

def total_energy(solver) -> float:
    return solver.diagnostics()["total_energy"]


def halves_gap(solver, half: torch.Tensor) -> float:
    """Smallest distance between a particle of the left half and one of the right half (slab excluded)."""
    x = solver.state_in_input_order().x.numpy()
    left, right = x[half.numpy() < 0], x[half.numpy() > 0]
    return float(cKDTree(right).query(left)[0].min())


@pytest.mark.parametrize("grid, length", [(32, 0.3), (32, 0.4), (64, 0.4), (48, 0.25)])
def test_precracked_bar_has_one_fractured_layer_in_the_middle(grid, length):
    """Whatever the grid and length, exactly one particle layer (the slab) lies on the bar's centre
    plane and is fractured from the start, with equally many layers on either side of it (a length
    of an even number of spacings once gave no slab, and a bar that did not crack)."""
    solver, half = precracked_bar(grid=grid, length=length, width=0.1, backend="reference")
    x = solver.state_in_input_order().x[:, 0].double()
    spacing = solver.geometry.dx / 2
    layers = torch.unique(torch.round(x / (spacing / 4)))  # one value per particle layer along x
    slab = x[half == 0]
    assert slab.numel() > 0 and float(slab.max() - slab.min()) < 1e-6
    assert len(layers) % 2 == 1 and abs(len(layers) * spacing - length) <= spacing
    assert int((half < 0).sum()) == int((half > 0).sum())
    fractured = solver.state_in_input_order().fractured
    assert bool(fractured[half == 0].all()) and not bool(fractured[half != 0].any())


def test_damage_follows_the_nacc_state_not_the_latched_fracture_flag():
    """The partition's damage D_p: current α at least the material's fracture threshold (0 here)
    plus contact.damage_dilation. A particle compacted back below it (NACC's cohesion returns) is
    not damaged although its fracture flag stays latched; an elastic particle never is."""
    solver, half = precracked_bar(grid=32, length=0.3, width=0.1, backend="reference")
    dilation = solver.contact.damage_dilation
    assert dilation > 0
    half_now = half.long()[solver.input_index]  # half of each particle in the solver's order
    slab, strong = torch.nonzero(half_now == 0).flatten(), torch.nonzero(half_now != 0).flatten()
    assert bool(solver.damaged()[slab].all()) and not bool(solver.damaged()[strong].any())  # α0 0.5 / −5
    state = solver.state.material_state.clone()
    state[strong[0], 0], state[strong[1], 0] = 0.999 * dilation, 1.001 * dilation  # lost cohesion, opened: only [1]
    state[slab[0], 0] = -0.1                                                       # compacted again
    solver.state = dataclasses.replace(solver.state, material_state=state)
    damaged = solver.damaged()
    assert not bool(damaged[strong[0]]) and bool(damaged[strong[1]])
    assert not bool(damaged[slab[0]]) and bool(solver.state.fractured[slab[0]])  # the flag stays latched
    assert int(damaged.sum()) == int((half == 0).sum())                         # −1 slab, +1 strong

    elastic = block_drop(6.0, E=1e4, density=100.0, alpha0=None, grid=16, backend="reference")
    elastic.state = dataclasses.replace(elastic.state,
                                        material_state=torch.full_like(elastic.state.material_state, 10.0))
    assert not bool(elastic.damaged().any())
    for bad in (-0.01, math.inf, math.nan):
        with pytest.raises(ValueError, match="damage_dilation"):
            ContactSettings(damage_dilation=bad)


@pytest.mark.parametrize("fragments", [True, False])
def test_precracked_bar_comes_apart_only_with_fragments(fragments):
    solver, half = precracked_bar(grid=32, length=0.3, width=0.1, fragments=fragments)
    start = total_energy(solver)
    peak = start
    initial = halves_gap(solver, half) / solver.geometry.dx  # 1 dx: the slab layer between them
    for _ in range(5):
        solver.advance(0.01)
        peak = max(peak, total_energy(solver))
    gap = halves_gap(solver, half) / solver.geometry.dx
    print(f"[pre-cracked bar] fragments={fragments}: gap between the halves {initial:.2f} -> {gap:.2f} dx "
          f"after 0.05 s at ±1 m/s")
    assert peak <= start * 1.01
    if fragments:
        assert gap > 2.0
    else:
        assert gap < 1.5, "with one field per object the halves stay glued"


def test_momentum_is_conserved_with_fragments():
    solver = colliding_spheres(grid=32, fragments=True)
    p0 = solver.diagnostics()["momentum"]
    start, peak, split = total_energy(solver), total_energy(solver), 0
    for i in range(400):
        solver.step(solver.stable_dt())
        split += solver.last_split_particles
        if i % 20 == 0:
            peak = max(peak, total_energy(solver))
    drift = float(np.linalg.norm(solver.diagnostics()["momentum"] - p0) / np.linalg.norm(p0))
    print(f"[fragments momentum] drift {drift:.2e}, particle-steps on split nodes {split}, "
          f"fractured {int(solver.state.fractured.sum())}")
    assert split > 0, "the collision must crack the spheres and split nodes"
    assert drift <= 1e-5
    assert peak <= start * 1.01


def test_fragment_ids_label_connected_pieces():
    x = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [0.5, 0, 0], [0.55, 0, 0], [0.0, 0, 0]])
    obj = torch.tensor([0, 0, 0, 0, 1], dtype=torch.int32)
    labels = fragment_ids(x, obj, radius=0.12)
    assert labels.tolist() == [0, 0, 1, 1, 2]  # particle 4 sits on particle 0 but is another object
    assert fragment_sizes(labels) == [2, 2, 1]
    assert count_fragments(labels, obj, min_fraction=0.5) == 3
    assert count_fragments(labels, obj, min_fraction=0.6) == 1  # only object 1's single particle
    counted, largest = fragments_per_object(labels, obj, 3, min_fraction=0.6)
    assert counted.tolist() == [0, 1, 0] and largest.tolist() == [2, 1, 0]   # object 2 is empty


def test_objects_sampled_at_different_densities_each_hold_together_at_rest():
    """A dense lattice (spacing 0.01) and a sparse one (spacing 0.03, as a coarsely sampled trained
    table beside a finely sampled teapot): each object links with its own spacing, so both are one
    piece at rest; one radius from the median of all particles would crumble the sparse one."""
    def lattice(spacing: float, n: int, origin: float) -> torch.Tensor:
        axis = origin + spacing * torch.arange(n, dtype=torch.float32)
        return torch.cartesian_prod(axis, axis, axis)

    dense, sparse = lattice(0.01, 12, 0.0), lattice(0.03, 5, 0.5)
    x = torch.cat([dense, sparse])
    obj = torch.cat([torch.zeros(len(dense)), torch.ones(len(sparse))]).to(torch.int32)
    volume = torch.cat([torch.full((len(dense),), 0.01 ** 3), torch.full((len(sparse),), 0.03 ** 3)])
    radii = object_link_radii(volume, obj, 2)
    assert torch.allclose(radii, torch.tensor([0.015, 0.045]), rtol=1e-4)
    per_object = fragment_ids(x, obj, radii)
    assert count_fragments(per_object, obj) == 2 and fragment_sizes(per_object) == [len(dense), len(sparse)]
    one_radius = fragment_ids(x, obj, link_radius(volume))           # 0.015: the sparse lattice falls apart
    assert len(fragment_sizes(one_radius)) == 1 + len(sparse)
    assert count_fragments(one_radius, obj) == 1     # and none of its crumbs holds 1 % of it
    # a cut through the sparse object (a gap of 3 spacings) still parts it
    cut = x.clone()
    cut[len(dense):][sparse[:, 0] > 0.55, 0] += 0.09
    assert count_fragments(fragment_ids(cut, obj, radii), obj) == 3


def test_piece_ranks_order_the_counted_fragments_by_size():
    labels = torch.tensor([3, 3, 3, 0, 0, 5, 6, 6, 6, 6, 9, 9])
    obj = torch.tensor([0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1])
    ranks = piece_ranks(labels, obj, min_fraction=0.3)   # object 0: >= 1.8 particles, object 1: >= 1.8
    assert ranks.tolist() == [1, 1, 1, 2, 2, -1, 0, 0, 0, 0, 3, 3]
    counted = int(count_fragments(labels, obj, min_fraction=0.3))
    assert counted == int(ranks.max()) + 1                  # the same fragments as the diagnostics
    tie = piece_ranks(torch.tensor([4, 4, 1, 1]), torch.tensor([0, 0, 0, 0]))
    assert tie.tolist() == [1, 1, 0, 0]                     # equal sizes: the smaller label first
    assert piece_ranks(torch.zeros(0, dtype=torch.int64), torch.zeros(0, dtype=torch.int32)).numel() == 0


def test_scene_option_fragments_is_validated():
    base = {"name": "s", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 16},
            "objects": [{"name": "cube", "primitive": {"shape": "box", "size": [0.2, 0.2, 0.2]},
                         "transform": {"translate": [0.5, 0.5, 0.5]},
                         "materials": [{"part": 0, "model": "elastic", "E": 1e4, "nu": 0.3, "density": 1}]}]}
    assert parse_scene({**base, "contact": {"fragments": False}}).contact.fragments is False
    assert parse_scene({**base, "contact": {"fragments": True}}).to_dict()["contact"]["fragments"] is True
    with pytest.raises(SceneError, match="contact.fragments"):
        parse_scene({**base, "contact": {"fragments": "yes"}})
