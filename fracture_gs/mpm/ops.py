"""One function per MPM kernel: the compiled op when available, otherwise its torch twin.

``backend`` is ``auto`` | ``cpp`` | ``reference`` (see :func:`fracture_gs._backend.use_compiled`).
"""
from __future__ import annotations

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.mpm import reference
from fracture_gs.mpm.grid import FragmentFields, G2PStats, GridFields, GridGeometry, ParticleBins
from fracture_gs.mpm.types import CONTACT_INSIDE_CELLS

WALL_CONDITIONS = reference.WALL_CONDITIONS


def bin_particles(x: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry,
                  backend: str = "auto") -> ParticleBins:
    """Sort particles into grid blocks (compiled on the CPU; torch ops elsewhere)."""
    if x.device.type == "cpu" and use_compiled(x.device, backend):
        try:
            return ParticleBins(*compiled_module().mpm_bin_particles(x, grid_id, *geometry.args()))
        except RuntimeError as exc:  # keep the one-line message of the kernel
            raise RuntimeError(str(exc).splitlines()[0]) from None
    return reference.bin_particles(x, grid_id, geometry)


def p2g(bins: ParticleBins, x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, stress: torch.Tensor,
        mass: torch.Tensor, rest_volume: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry,
        dt: float, grid: GridFields, backend: str = "auto", damaged: torch.Tensor | None = None) -> None:
    """Particle-to-grid transfer into ``grid`` (mass, momentum; mass gradient and position moment for
    contact).

    The compiled CPU kernel sums mass gradient and position moment on contact blocks only (the
    contact pass reads nothing else); the torch reference and CUDA fill them everywhere. With
    ``damaged`` (fragments: bool per particle, D_p = 1 where set, :meth:`CollisionMPM.damaged`), it
    also sums Σ w m D into ``grid.damage``, clears ``grid.reference`` on the touched blocks, and
    sums mass gradient and position moment everywhere (the two sides of a split node meet through
    the contact pass, wherever it is).
    """
    damage_args = (damaged, grid.damage, grid.reference) if damaged is not None else (None, None, None)
    if use_compiled(x.device, backend):
        compiled_module().mpm_p2g(bins.as_list(), x, v, C, stress, mass, rest_volume, grid_id,
                                  *geometry.args(), dt, grid.mass, grid.momentum, grid.mass_gradient,
                                  grid.position_moment, *damage_args)
    else:
        reference.p2g(x, v, C, stress, mass, rest_volume, grid_id, geometry, dt, grid, damaged)


def grid_update(bins: ParticleBins, geometry: GridGeometry, dt: float, gravity: tuple[float, float, float],
                mass_eps: float, grid: GridFields, backend: str = "auto") -> None:
    """Momentum to velocity plus gravity on every node that has mass."""
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_grid_update(bins.touched, *geometry.args(), dt, list(gravity), mass_eps,
                                          grid.mass, grid.momentum, grid.velocity)
    else:
        reference.grid_update(grid, dt, torch.tensor(gravity, device=grid.mass.device), mass_eps)


def boundaries(bins: ParticleBins, geometry: GridGeometry, wall_condition: str, ground_height: float | None,
               ground_friction: float, mass_eps: float, grid: GridFields, backend: str = "auto") -> None:
    """Domain walls and ground (docs/formulas.md §9)."""
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_boundaries(
            bins.touched, *geometry.args(), WALL_CONDITIONS[wall_condition], 3, list(geometry.cells),
            ground_height is not None, ground_height if ground_height is not None else 0.0, ground_friction,
            mass_eps, grid.mass, grid.velocity)
    else:
        reference.boundaries(grid, geometry, wall_condition, ground_height, ground_friction, mass_eps)


def collision(bins: ParticleBins, geometry: GridGeometry, impulse_scale: float, friction: float, mass_eps: float,
              max_gap: float, grid: GridFields, backend: str = "auto") -> None:
    """Contact impulses between object grids (docs/formulas.md §7) where the bodies' mass centres at a node are
    closer than ``max_gap`` (a length) along the contact normal. A body whose mass centre lies within
    ``CONTACT_INSIDE_CELLS`` of a node gives no normal there (the other body's is used)."""
    inside = CONTACT_INSIDE_CELLS * geometry.dx
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_collision(bins.contact_blocks, *geometry.args(), impulse_scale, friction, mass_eps,
                                        max_gap, inside, grid.mass, grid.velocity, grid.mass_gradient,
                                        grid.position_moment)
    else:
        reference.collision(grid, impulse_scale, friction, mass_eps, max_gap, inside)


def fragment_reference(bins: ParticleBins, x: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry,
                       mass_eps: float, split_gradient: float, grid: GridFields, backend: str = "auto",
                       split_direction: torch.Tensor | None = None, direction_scale: float = 0.0) -> torch.Tensor:
    """Fragments, step 2: every particle's damage gradient ∇D_p = Σ D_i ∇w_ip (returned, (N, 3)) and
    every node's reference key (``grid.reference``: the largest |∇D_p| reaching it, stored only where
    it reaches ``split_gradient`` (1/length), i.e. where it splits the node; 0 elsewhere). A particle
    with a non-zero row of ``split_direction`` (N, 3; rows of unit column stride, e.g. 3 columns of
    the state block) takes ``direction_scale`` (1/length) times it instead of its gradient
    (csrc/common/mpm_fragments.h, apply_split_direction). ``geometry`` names the K object grids; P2G
    must have run with ``damaged``."""
    if use_compiled(x.device, backend):
        return compiled_module().mpm_fragment_reference(bins.as_list(), x, grid_id, *geometry.args(), mass_eps,
                                                        split_gradient, grid.mass, grid.damage, grid.reference,
                                                        split_direction, direction_scale)
    return reference.fragment_reference(x, grid_id, geometry, mass_eps, split_gradient, grid, split_direction,
                                        direction_scale)


def fragment_partition(bins: ParticleBins, x: torch.Tensor, v: torch.Tensor, C: torch.Tensor, stress: torch.Tensor,
                       mass: torch.Tensor, rest_volume: torch.Tensor, grid_id: torch.Tensor, geometry: GridGeometry,
                       dt: float, damage_gradient: torch.Tensor, split_gradient: float, grid: GridFields,
                       backend: str = "auto") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Fragments, step 3: at every split node (reference |∇D| >= ``split_gradient``, 1/length) the
    particles on side B (∇D_p · ∇D_ref < 0) are summed into field B (grid K + g), and field A, which
    holds P2G's sum of all of them, becomes that sum minus B (``split_node_fields`` in
    csrc/common/mpm_fragments.h). Returns (split_particle (N,) uint8, split_keys (S,) int32 (grid,
    block) keys where a split node got side-B mass, side_mask (N,) int32: bit 9a + 3b + c set where
    the particle is on side B at stencil node (a, b, c))."""
    if use_compiled(x.device, backend):
        split_particle, split_keys, side_mask = compiled_module().mpm_fragment_partition(
            bins.as_list(), x, v, C, stress, mass, rest_volume, grid_id, *geometry.args(), dt, damage_gradient,
            grid.reference, split_gradient, grid.mass, grid.momentum, grid.mass_gradient, grid.position_moment)
        return split_particle, split_keys, side_mask
    return reference.fragment_partition(x, v, C, stress, mass, rest_volume, grid_id, geometry, dt, damage_gradient,
                                        split_gradient, grid)


def fragment_field_blocks(bins: ParticleBins, split_keys: torch.Tensor, geometry: GridGeometry,
                          backend: str = "auto") -> tuple[torch.Tensor, torch.Tensor]:
    """The blocks the field passes visit once nodes are split: (``bins.touched`` followed by the
    field-B keys ``split_keys + K * n_blocks``, the union of ``bins.contact_blocks`` and the blocks
    of ``split_keys``, ascending), int32. ``geometry``: the K object grids."""
    if split_keys.device.type == "cpu" and use_compiled(split_keys.device, backend):
        field_touched, field_contact = compiled_module().mpm_fragment_field_blocks(
            bins.touched, bins.contact_blocks, split_keys, geometry.n_blocks, geometry.n_grids)
        return field_touched, field_contact
    field_b = split_keys + geometry.n_grids * geometry.n_blocks
    field_contact = torch.unique(torch.cat([bins.contact_blocks, split_keys % geometry.n_blocks]))
    return (torch.cat([bins.touched, field_b]).to(torch.int32).contiguous(),
            field_contact.to(torch.int32).contiguous())


def fragment_clear(keys: torch.Tensor, geometry: GridGeometry, grid: GridFields, backend: str = "auto") -> None:
    """Zero every field of the given (grid, block) keys (``geometry`` of all 2K grids)."""
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_fragment_clear(keys, *geometry.args(), grid.mass, grid.momentum, grid.velocity,
                                             grid.mass_gradient, grid.position_moment)
    else:
        reference.fragment_clear(keys, geometry, grid)


def g2p(x: torch.Tensor, F_E: torch.Tensor, material_state: torch.Tensor, fractured: torch.Tensor,
        grid_id: torch.Tensor, material_id: torch.Tensor, material_table: torch.Tensor, grid: GridFields,
        geometry: GridGeometry, dt: float, backend: str = "auto", fragments: FragmentFields | None = None,
        dissipated: torch.Tensor | None = None):
    """Grid-to-particle transfer, advection and the material update (``material_state``: the (N, S)
    state block, or (N,) for one field; ``dissipated``: an (N,) float32 tensor that receives the energy per unit rest volume
    each particle's update took).

    ``geometry`` names the object grids (K); with ``fragments`` the grid holds 2K fields and each
    split node is read from the field of the particle's side. Returns (x, v, C, F_E, material_state,
    stress, fractured, G2PStats) with new tensors.
    """
    clamp_lower, clamp_upper = geometry.clamp_bounds()
    # Without fragments G2P reads the K object grids only (the tensors may hold fields B as well).
    velocity = grid.velocity if fragments is not None else grid.velocity[:geometry.n_grids]
    block = material_state if material_state.ndim == 2 else material_state[:, None]  # (N,): one field
    if use_compiled(x.device, backend):
        n = x.shape[0]
        out = [torch.empty_like(x), torch.empty_like(x), torch.empty((n, 3, 3), device=x.device),
               torch.empty_like(F_E), torch.empty_like(block), torch.empty((n, 3, 3), device=x.device),
               torch.empty_like(fractured)]
        clamped, first_bad, max_speed = compiled_module().mpm_g2p(
            x, F_E, block, fractured, grid_id, material_id, material_table, velocity, *geometry.args(), dt,
            clamp_lower, clamp_upper, *out, fragments.as_list() if fragments is not None else None,
            fragments.split_gradient if fragments is not None else 1.0, dissipated)
        out[4] = out[4].reshape(material_state.shape)
        return (*out, G2PStats(int(clamped), int(first_bad), float(max_speed)))
    return reference.g2p(x, F_E, material_state, fractured, grid_id, material_id, material_table, velocity,
                         geometry, dt, clamp_lower, clamp_upper, fragments, dissipated)
