"""Readable, vectorised PyTorch twins of the MPM kernels (docs/formulas.md §2, §7, §9).

Each function mirrors one compiled op in ``csrc/mpm`` and has the same inputs and outputs.
They work on any device and run the whole dense grid, so they are slow but easy to check;
the tests compare the compiled kernels against them.
"""
from __future__ import annotations

import torch

from fracture_gs.mpm.grid import (FragmentFields, G2PStats, GridFields, GridGeometry, ParticleBins, node_coords,
                                  node_index)
from fracture_gs.materials import COLUMN, constitutive_update_reference
from fracture_gs.mpm.types import BLOCK

# The 27 stencil offsets, in the order the kernels visit them (a, b, c nested).
STENCIL = torch.tensor([[a, b, c] for a in range(3) for b in range(3) for c in range(3)])

WALL_CONDITIONS = {"none": 0, "slip": 1, "sticky": 2, "separate": 3}


def _bspline(x: torch.Tensor, geometry: GridGeometry):
    """Base node (N,3), fraction f (N,3), weights w (N,3 nodes,3 axes), dw (same, per length)."""
    lower = torch.tensor(geometry.lower, device=x.device, dtype=x.dtype)
    X = (x - lower) * (1.0 / geometry.dx)  # the kernels' grid coordinate (csrc/common/mpm_math.h)
    base = torch.floor(X - 0.5)
    f = X - base
    w = torch.stack([0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2], 1)
    dw = torch.stack([-(1.5 - f), -2.0 * (f - 1.0), f - 0.5], 1) / geometry.dx
    return base.long(), f, w, dw


def _stencil(x: torch.Tensor, geometry: GridGeometry):
    """Node indices (N,27), weights (N,27), weight gradients (N,27,3), offsets x_i - x_p (N,27,3)."""
    base, f, w, dw = _bspline(x, geometry)
    offsets = STENCIL.to(x.device)
    axis = torch.arange(3, device=x.device)
    w_axes = w[:, offsets, axis]      # (N,27,3): weight of each axis for each stencil node
    dw_axes = dw[:, offsets, axis]
    weight = w_axes.prod(-1)
    gradient = torch.stack([dw_axes[..., 0] * w_axes[..., 1] * w_axes[..., 2],
                            w_axes[..., 0] * dw_axes[..., 1] * w_axes[..., 2],
                            w_axes[..., 0] * w_axes[..., 1] * dw_axes[..., 2]], -1)
    dpos = (offsets[None].to(x.dtype) - f[:, None, :]) * geometry.dx
    index = node_index(base[:, None, :] + offsets[None], geometry)
    return index, weight, gradient, dpos


def bin_particles(x: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry) -> ParticleBins:
    """Sort particles by (grid, block) of their stencil base; list touched and contact blocks."""
    device = x.device
    base, _, _, _ = _bspline(x, geometry)
    limit = torch.tensor([b * BLOCK - 3 for b in geometry.blocks], device=device)
    inside = (base >= 0).all(1) & (base < limit).all(1) & torch.isfinite(x).all(1)
    if not bool(inside.all()):
        bad = int(torch.nonzero(~inside)[-1])
        raise RuntimeError(f"particle {bad} is outside the grid (or has a non-finite position)")
    by, bz = geometry.blocks[1], geometry.blocks[2]
    block_ijk = base // BLOCK
    block = (block_ijk[:, 0] * by + block_ijk[:, 1]) * bz + block_ijk[:, 2]
    key = grid_id.long() * geometry.n_blocks + block
    sorted_key, order = torch.sort(key, stable=True)
    cell_key, counts = torch.unique_consecutive(sorted_key, return_counts=True)
    cell_start = torch.zeros(len(cell_key) + 1, dtype=torch.long, device=device)
    cell_start[1:] = torch.cumsum(counts, 0)
    # Does some particle of the cell reach into the next block along each axis?
    reach_particle = ((base % BLOCK) >= BLOCK - 2).long()
    cell_of_particle = torch.repeat_interleave(torch.arange(len(cell_key), device=device), counts)
    reach = torch.zeros(len(cell_key), 3, dtype=torch.long, device=device)
    reach.scatter_reduce_(0, cell_of_particle[:, None].expand(-1, 3), reach_particle[order], "amax")
    cell_grid, cell_block = cell_key // geometry.n_blocks, cell_key % geometry.n_blocks
    bk, bj, bi = cell_block % bz, (cell_block // bz) % by, cell_block // (by * bz)
    color = (bi % 2) * 4 + (bj % 2) * 2 + bk % 2
    color_cells = torch.sort(color, stable=True)[1]
    color_start = torch.zeros(9, dtype=torch.long, device=device)
    color_start[1:] = torch.cumsum(torch.bincount(color, minlength=8), 0)
    neighbours = STENCIL[(STENCIL < 2).all(1)].to(device)  # the 8 offsets in {0,1}^3
    allowed = (neighbours[None] <= reach[:, None, :]).all(-1)  # (P,8)
    nb_ijk = torch.stack([bi, bj, bk], -1)[:, None, :] + neighbours[None]
    nb_key = cell_grid[:, None] * geometry.n_blocks + (nb_ijk[..., 0] * by + nb_ijk[..., 1]) * bz + nb_ijk[..., 2]
    touched = torch.unique(nb_key[allowed])
    if geometry.n_grids >= 2:
        per_block = torch.bincount(touched % geometry.n_blocks, minlength=geometry.n_blocks)
        contact_blocks = torch.nonzero(per_block >= 2).flatten()
    else:
        contact_blocks = torch.zeros(0, dtype=torch.long, device=device)
    i32 = torch.int32
    return ParticleBins(order.to(i32), cell_start.to(i32), cell_key.to(i32), color_cells.to(i32),
                        color_start.to(i32), touched.to(i32), contact_blocks.to(i32))


def p2g(x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, stress: torch.Tensor, mass: torch.Tensor,
        rest_volume: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry, dt: float,
        grid: GridFields, damaged: torch.Tensor | None = None) -> None:
    """Scatter mass, APIC momentum + stress force and mass gradients onto each particle's grid
    (with ``damaged``: also Σ w m D into ``grid.damage``, and ``grid.reference`` cleared)."""
    index, weight, gradient, dpos = _stencil(x, geometry)
    index = index + grid_id.long()[:, None] * geometry.nodes_per_grid
    affine = mass[:, None, None] * C - (4.0 * dt / geometry.dx ** 2) * rest_volume[:, None, None] * stress
    momentum = weight[..., None] * (mass[:, None, None] * v[:, None, :] + torch.einsum("nij,nkj->nki", affine, dpos))
    grid.mass.zero_()
    grid.momentum.zero_()
    grid.mass.view(-1).index_add_(0, index.flatten(), (weight * mass[:, None]).flatten())
    grid.momentum.view(-1, 3).index_add_(0, index.flatten(), momentum.reshape(-1, 3))
    if grid.mass_gradient is not None:
        grid.mass_gradient.zero_()
        grid.mass_gradient.view(-1, 3).index_add_(0, index.flatten(),
                                                  (gradient * mass[:, None, None]).reshape(-1, 3))
    if grid.position_moment is not None:
        grid.position_moment.zero_()
        moment = -(weight * mass[:, None])[..., None] * dpos   # w m (x_p − x_i)
        grid.position_moment.view(-1, 3).index_add_(0, index.flatten(), moment.reshape(-1, 3))
    if damaged is not None:
        assert grid.damage is not None and grid.reference is not None, "fragments need damage fields"
        grid.damage.zero_()
        grid.reference.zero_()
        damage = mass * damaged.to(mass.dtype)                   # m D, D = 1 where damaged
        grid.damage.view(-1).index_add_(0, index.flatten(), (weight * damage[:, None]).flatten())


def _norm_sq_bits(g: torch.Tensor) -> torch.Tensor:
    """Bits of |g|² (float32, summed x + y + z as the kernels do) as int64."""
    norm_sq = (g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1]) + g[:, 2] * g[:, 2]
    return norm_sq.contiguous().view(torch.int32).to(torch.int64)


def fragment_reference(x: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry, mass_eps: float,
                       split_gradient: float, grid: GridFields, split_direction: torch.Tensor | None = None,
                       direction_scale: float = 0.0) -> torch.Tensor:
    """Damage gradients ∇D_p = Σ_i D_i ∇w_ip with D_i = damage_i / mass_i (returned, (N, 3)), and the
    reference key of every node: the maximum over the particles reaching it of
    (bits(|∇D_p|²) << 32) | p, counting only particles with |∇D_p| >= ``split_gradient`` (the keys
    that split a node; 0 where none does). A particle with a non-zero row of ``split_direction`` takes
    ``direction_scale`` times it as its vector. ``geometry``: K object grids."""
    assert grid.damage is not None and grid.reference is not None, "fragments need damage fields"
    index, _, gradient, _ = _stencil(x, geometry)
    index = index + grid_id.long()[:, None] * geometry.nodes_per_grid
    node_mass = grid.mass.reshape(-1)[index]
    node_damage = torch.where(node_mass > mass_eps, grid.damage.reshape(-1)[index] / torch.where(
        node_mass > mass_eps, node_mass, torch.ones_like(node_mass)), torch.zeros_like(node_mass))
    damage_gradient = (node_damage[..., None] * gradient).sum(1)
    if split_direction is not None:
        cracked = (split_direction != 0).any(1)
        damage_gradient = torch.where(cracked[:, None], (direction_scale * split_direction).to(damage_gradient.dtype),
                                      damage_gradient)
    particle = torch.arange(x.shape[0], device=x.device, dtype=torch.int64)
    key = (_norm_sq_bits(damage_gradient) << 32) | particle
    key = torch.where((key >> 32) >= _split_bits(split_gradient), key, torch.zeros_like(key))
    grid.reference.view(-1).scatter_reduce_(0, index.flatten(), key[:, None].expand(-1, 27).flatten(), "amax")
    return damage_gradient


def _fragment_fields(index: torch.Tensor, grid_id: torch.Tensor, damage_gradient: torch.Tensor,
                     reference_keys: torch.Tensor, split_gradient: float, n_fields: int, nodes: int):
    """Per (particle, stencil node): is the node split, and the grid (0..2K-1) the particle uses there."""
    key = reference_keys.reshape(-1)[index]                             # (N,27)
    split = _split_nodes(key, split_gradient)
    ref = key & 0xFFFFFFFF
    side = ((damage_gradient[:, None, :] * damage_gradient[ref]).sum(-1) < 0) & split
    field = grid_id.long()[:, None] + n_fields * side.long()
    return split, field


# Share of a split node's P2G mass below which side A counts as empty once side B's share is taken
# out (kEmptySideShare, csrc/common/mpm_fragments.h).
EMPTY_SIDE_SHARE = 1e-5


def fragment_partition(x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, stress: torch.Tensor, mass: torch.Tensor,
                       rest_volume: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry, dt: float,
                       damage_gradient: torch.Tensor, split_gradient: float,
                       grid: GridFields) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """At split nodes (reference |∇D| >= split_gradient), p is on side B where ∇D_p · ∇D_ref < 0.
    Field B (grid K + g) is summed from the side-B particles; field A (grid g), which holds P2G's
    sum of all of them, becomes that sum minus B — or, where that leaves less than EMPTY_SIDE_SHARE
    of the sum (rounding noise: every particle there is on side B), B takes the whole sum and A is
    emptied. Returns (split_particle (N,) uint8, split_keys (S,) int32: (grid, block) keys of the K
    grids where a split node got side-B mass, ascending, side_mask (N,) int32: bit 9a + 3b + c set
    where p is on side B at stencil node (a, b, c)). ``geometry``: K object grids; ``grid``: 2K
    fields, B zero on entry."""
    assert grid.reference is not None and grid.mass_gradient is not None and grid.position_moment is not None
    K, nodes = geometry.n_grids, geometry.nodes_per_grid
    node, weight, gradient, dpos = _stencil(x, geometry)
    split, field = _fragment_fields(node + grid_id.long()[:, None] * nodes, grid_id, damage_gradient,
                                    grid.reference, split_gradient, K, nodes)
    side_b = field >= K                                                  # implies split
    target = (field * nodes + node)[side_b]
    affine = mass[:, None, None] * C - (4.0 * dt / geometry.dx ** 2) * rest_volume[:, None, None] * stress
    momentum = weight[..., None] * (mass[:, None, None] * v[:, None, :] + torch.einsum("nij,nkj->nki", affine, dpos))
    grid.mass.view(-1).index_add_(0, target, (weight * mass[:, None])[side_b])
    grid.momentum.view(-1, 3).index_add_(0, target, momentum[side_b])
    grid.mass_gradient.view(-1, 3).index_add_(0, target, (gradient * mass[:, None, None])[side_b])
    grid.position_moment.view(-1, 3).index_add_(0, target, (-(weight * mass[:, None])[..., None] * dpos)[side_b])
    # Field A = P2G's sum − B where B got mass; B takes all where A would be rounding noise.
    with_b = grid.mass[K:] != 0                                          # (K, nodes)
    total = grid.mass[:K].clone()
    empty_a = with_b & (total - grid.mass[K:] <= EMPTY_SIDE_SHARE * total)
    subtract = with_b & ~empty_a
    grid.mass[:K] = torch.where(subtract, total - grid.mass[K:], torch.where(empty_a, torch.zeros_like(total), total))
    grid.mass[K:] = torch.where(empty_a, total, grid.mass[K:])
    for tensor in (grid.momentum, grid.mass_gradient, grid.position_moment):
        field_a, field_b = tensor[:K].clone(), tensor[K:].clone()
        tensor[:K] = torch.where(subtract[..., None], field_a - field_b,
                                 torch.where(empty_a[..., None], torch.zeros_like(field_a), field_a))
        tensor[K:] = torch.where(empty_a[..., None], field_a, field_b)
    block = with_b.view(K, geometry.n_blocks, BLOCK ** 3).any(-1).flatten()
    side_mask = (side_b.to(torch.int64) << torch.arange(27, device=x.device)).sum(1).to(torch.int32)
    return split.any(1).to(torch.uint8), torch.nonzero(block).flatten().to(torch.int32), side_mask


def _split_nodes(reference_keys: torch.Tensor, split_gradient: float) -> torch.Tensor:
    """Bool, the shape of ``reference_keys``: where the key names a gradient |∇D| >= split_gradient."""
    return (reference_keys > 0) & ((reference_keys >> 32) >= _split_bits(split_gradient))


def _split_bits(split_gradient: float) -> int:
    """Float32 bits of split_gradient²: a reference key splits its node where its high word is >= them."""
    return int(torch.tensor([split_gradient ** 2], dtype=torch.float32).view(torch.int32))


def fragment_clear(keys: torch.Tensor, geometry: GridGeometry, grid: GridFields) -> None:
    """Zero every field of the given (grid, block) keys."""
    nodes = (keys.long()[:, None] // geometry.n_blocks) * geometry.nodes_per_grid + \
        (keys.long()[:, None] % geometry.n_blocks) * BLOCK ** 3 + torch.arange(BLOCK ** 3, device=keys.device)
    for tensor in (grid.mass, grid.momentum, grid.velocity, grid.mass_gradient, grid.position_moment):
        tensor.view(geometry.nodes_per_grid * tensor.shape[0], -1)[nodes.flatten()] = 0.0


def grid_update(grid: GridFields, dt: float, gravity: torch.Tensor, mass_eps: float) -> None:
    """Velocity = (momentum + mass dt g) / mass on nodes with mass, zero elsewhere. Gravity is added to
    the momentum: added to a velocity that every node of a translating body shares, its rounding
    would be the same on every node and bias the body's momentum."""
    has_mass = grid.mass > mass_eps
    momentum = grid.momentum + grid.mass[..., None] * (dt * gravity.to(grid.momentum))
    velocity = momentum / torch.where(has_mass, grid.mass, torch.ones_like(grid.mass))[..., None]
    grid.velocity.copy_(torch.where(has_mass[..., None], velocity, torch.zeros_like(velocity)))


def boundaries(grid: GridFields, geometry: GridGeometry, wall_condition: str, ground_height: float | None,
               ground_friction: float, mass_eps: float, wall_cells: int = 3) -> None:
    """Domain walls (slip / sticky / separate) and the Coulomb-friction ground on every node."""
    ijk = node_coords(geometry, grid.mass.device)
    velocity = grid.velocity
    new_v = velocity.clone()
    if wall_condition != "none":
        cells = torch.tensor(geometry.cells, device=ijk.device)
        lower_wall, upper_wall = ijk < wall_cells, ijk > cells - wall_cells   # (nodes,3)
        in_wall = lower_wall | upper_wall
        if wall_condition == "sticky":
            new_v = torch.where(in_wall.any(-1)[None, :, None], torch.zeros_like(new_v), new_v)
        else:
            for d in range(3):
                component = new_v[..., d]
                if wall_condition == "slip":
                    zero = in_wall[:, d][None]
                else:
                    zero = (lower_wall[:, d][None] & (component < 0)) | (upper_wall[:, d][None] & (component > 0))
                new_v[..., d] = torch.where(zero, torch.zeros_like(component), component)
    if ground_height is not None:
        z = geometry.lower[2] + ijk[:, 2].to(velocity.dtype) * geometry.dx
        contact = (z <= ground_height)[None] & (new_v[..., 2] < 0)
        speed_in = -new_v[..., 2]
        tangential = new_v[..., :2]
        vt = tangential.norm(dim=-1)
        scale = torch.clamp(1.0 - ground_friction * speed_in / torch.where(vt > 0, vt, torch.ones_like(vt)), min=0.0)
        scale = torch.where(vt > 0, scale, torch.ones_like(scale))
        grounded = torch.cat([tangential * scale[..., None], torch.zeros_like(speed_in)[..., None]], -1)
        new_v = torch.where(contact[..., None], grounded, new_v)
    grid.velocity.copy_(torch.where((grid.mass > mass_eps)[..., None], new_v, velocity))


def collision(grid: GridFields, impulse_scale: float, friction: float, mass_eps: float, max_gap: float,
              inside: float) -> None:
    """Bardenhagen contact between every pair of object grids, pairs in a fixed order (docs/formulas.md §7).

    A node is a contact only where both bodies have mass, the normal is defined and the bodies'
    mass centres at the node, s_k / m_k, are closer than ``max_gap`` along it (a length); the
    impulse is applied only while they approach. The normal is normalize(w_a ĝa − w_b ĝb) with
    w = 1, except w = 0 for the body whose mass centre lies within ``inside`` (a length) of the
    node while the other's does not, or else for the body whose ĝ does not point toward the other
    body's mass centre while the other's does (``contact_normal`` in csrc/common/mpm_math.h).
    """
    assert grid.mass_gradient is not None and grid.position_moment is not None, "collision needs contact fields"
    n_grids = grid.mass.shape[0]
    for a in range(n_grids):
        for b in range(a + 1, n_grids):
            ma, mb = grid.mass[a], grid.mass[b]
            va, vb = grid.velocity[a], grid.velocity[b]
            ga, gb = grid.mass_gradient[a], grid.mass_gradient[b]
            na, nb = ga.norm(dim=-1, keepdim=True), gb.norm(dim=-1, keepdim=True)
            ua = torch.where(na > 0, ga / na.clamp_min(1e-30), torch.zeros_like(ga))
            ub = torch.where(nb > 0, gb / nb.clamp_min(1e-30), torch.zeros_like(gb))
            has_mass = (ma > mass_eps) & (mb > mass_eps)
            centre_a = grid.position_moment[a] / torch.where(has_mass, ma, torch.ones_like(ma))[:, None]
            centre_b = grid.position_moment[b] / torch.where(has_mass, mb, torch.ones_like(mb))[:, None]
            offset = centre_b - centre_a
            inside_a, inside_b = centre_a.norm(dim=-1) < inside, centre_b.norm(dim=-1) < inside
            a_faces_b, b_faces_a = (ua * offset).sum(-1) > 0, (ub * offset).sum(-1) < 0
            one_inside, one_faces = inside_a != inside_b, a_faces_b != b_faces_a
            use_a = torch.where(one_inside, inside_b, torch.where(one_faces, a_faces_b, torch.ones_like(one_faces)))
            use_b = torch.where(one_inside, inside_a, torch.where(one_faces, b_faces_a, torch.ones_like(one_faces)))
            both = has_mass & (~use_a | (na[:, 0] > 0)) & (~use_b | (nb[:, 0] > 0))
            normal = use_a[:, None] * ua - use_b[:, None] * ub
            normal_len = normal.norm(dim=-1, keepdim=True)
            normal = normal / normal_len.clamp_min(1e-30)
            gap = (offset * normal).sum(-1)
            vrel = va - vb
            vn = (vrel * normal).sum(-1, keepdim=True)
            active = both & (normal_len[:, 0] > 1e-6) & (gap < max_gap) & (vn[:, 0] > 0)
            reduced = (ma * mb / (ma + mb).clamp_min(1e-30))[:, None]
            jn = reduced * vn
            impulse = -impulse_scale * jn * normal
            if friction > 0:
                vt = vrel - vn * normal
                vt_norm = vt.norm(dim=-1, keepdim=True)
                jt = torch.minimum(friction * impulse_scale * jn, reduced * vt_norm)
                impulse = impulse - torch.where(vt_norm > 1e-12, jt * vt / vt_norm.clamp_min(1e-30),
                                                torch.zeros_like(vt))
            impulse = torch.where(active[:, None], impulse, torch.zeros_like(impulse))
            grid.velocity[a] = va + impulse / torch.where(active, ma, torch.ones_like(ma))[:, None]
            grid.velocity[b] = vb - impulse / torch.where(active, mb, torch.ones_like(mb))[:, None]


def g2p(x: torch.Tensor, F_E: torch.Tensor, material_state: torch.Tensor, fractured: torch.Tensor,
        grid_id: torch.Tensor, material_id: torch.Tensor, material_table: torch.Tensor,
        grid_velocity: torch.Tensor, geometry: GridGeometry, dt: float,
        clamp_lower: list[float], clamp_upper: list[float], fragments: FragmentFields | None = None,
        dissipated: torch.Tensor | None = None):
    """Gather velocity and APIC affine field, advect, update F and run the material update
    (``material_state``: the (N, S) block, or (N,) for one field). With ``fragments``, each split
    node's velocity comes from the field of the particle's side there.

    Returns (x, v, C, F_E, material_state, stress, fractured, G2PStats).
    """
    index, weight, _, dpos = _stencil(x, geometry)
    if fragments is None:
        index = index + grid_id.long()[:, None] * geometry.nodes_per_grid
    else:
        nodes = geometry.nodes_per_grid
        _, field = _fragment_fields(index + grid_id.long()[:, None] * nodes, grid_id, fragments.damage_gradient,
                                    fragments.reference, fragments.split_gradient, geometry.n_grids, nodes)
        index = index + field * nodes
    node_v = grid_velocity.reshape(-1, 3)[index]                     # (N,27,3)
    v = (weight[..., None] * node_v).sum(1)
    C = (4.0 / geometry.dx ** 2) * torch.einsum("nk,nki,nkj->nij", weight, node_v, dpos)
    moved = x + dt * v
    lo = torch.tensor(clamp_lower, device=x.device, dtype=x.dtype)
    hi = torch.tensor(clamp_upper, device=x.device, dtype=x.dtype)
    x_new = torch.minimum(torch.maximum(moved, lo), hi)
    clamped = int((x_new != moved).any(1).sum())
    eye = torch.eye(3, device=x.device, dtype=x.dtype)
    F_trial = (eye + dt * C) @ F_E
    F_new, state_new, stress, taken = constitutive_update_reference(material_table, material_id, F_trial,
                                                                    material_state)
    if dissipated is not None:
        dissipated.copy_(taken)
    threshold = material_table[material_id.long(), COLUMN["fracture_threshold"]]
    fractured_new = fractured | (state_new.reshape(len(x), -1)[:, 0] >= threshold)
    finite = (torch.isfinite(x_new).all(1) & torch.isfinite(v).all(1) & torch.isfinite(F_new).flatten(1).all(1))
    bad = torch.nonzero(~finite).flatten()
    speed = v[finite].norm(dim=1)
    stats = G2PStats(clamped=clamped, first_nonfinite=int(bad[0]) if len(bad) else -1,
                     max_speed=float(speed.max()) if len(speed) else 0.0)
    return x_new, v, C, F_new, state_new.to(material_state.dtype), stress, fractured_new, stats
