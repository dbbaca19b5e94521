"""One function per MPM kernel: the compiled op when available, otherwise its torch twin.

``backend`` is ``auto`` | ``cpp`` | ``reference`` (see :func:`fracture_gs._backend.use_compiled`).
"""
from __future__ import annotations

import torch

from fracture_gs._backend import compiled_module, use_compiled
from fracture_gs.mpm import reference
from fracture_gs.mpm.grid import G2PStats, GridFields, GridGeometry, ParticleBins

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
        dt: float, grid: GridFields, backend: str = "auto") -> None:
    """Particle-to-grid transfer into ``grid`` (mass, momentum; mass gradient and position moment for
    contact).

    The compiled CPU kernel sums mass gradient and position moment on contact blocks only (the
    contact pass reads nothing else); the torch reference and CUDA fill them everywhere.
    """
    if use_compiled(x.device, backend):
        compiled_module().mpm_p2g(bins.as_list(), x, v, C, stress, mass, rest_volume, grid_id,
                                  *geometry.args(), dt, grid.mass, grid.momentum, grid.mass_gradient,
                                  grid.position_moment)
    else:
        reference.p2g(x, v, C, stress, mass, rest_volume, grid_id, geometry, dt, grid)


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
    """Domain walls and ground (SPEC §5.5)."""
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_boundaries(
            bins.touched, *geometry.args(), WALL_CONDITIONS[wall_condition], 3, list(geometry.cells),
            ground_height is not None, ground_height if ground_height is not None else 0.0, ground_friction,
            mass_eps, grid.mass, grid.velocity)
    else:
        reference.boundaries(grid, geometry, wall_condition, ground_height, ground_friction, mass_eps)


def collision(bins: ParticleBins, geometry: GridGeometry, strength: float, friction: float, mass_eps: float,
              max_gap: float, grid: GridFields, backend: str = "auto") -> None:
    """Contact impulses between object grids (SPEC §5.4) where the bodies' mass centres at a node are
    closer than ``max_gap`` (a length) along the contact normal."""
    if use_compiled(grid.mass.device, backend):
        compiled_module().mpm_collision(bins.contact_blocks, *geometry.args(), strength, friction, mass_eps,
                                        max_gap, grid.mass, grid.velocity, grid.mass_gradient, grid.position_moment)
    else:
        reference.collision(grid, strength, friction, mass_eps, max_gap)


def g2p(x: torch.Tensor, F_E: torch.Tensor, alpha: torch.Tensor, fractured: torch.Tensor, grid_id: torch.Tensor,
        material_id: torch.Tensor, material_table: torch.Tensor, grid: GridFields, geometry: GridGeometry,
        dt: float, backend: str = "auto"):
    """Grid-to-particle transfer, advection and return map.

    Returns (x, v, C, F_E, alpha, stress, fractured, G2PStats) with new tensors.
    """
    clamp_lower, clamp_upper = geometry.clamp_bounds()
    if use_compiled(x.device, backend):
        n = x.shape[0]
        out = [torch.empty_like(x), torch.empty_like(x), torch.empty((n, 3, 3), device=x.device),
               torch.empty_like(F_E), torch.empty_like(alpha), torch.empty((n, 3, 3), device=x.device),
               torch.empty_like(fractured)]
        clamped, first_bad, max_speed = compiled_module().mpm_g2p(
            x, F_E, alpha, fractured, grid_id, material_id, material_table, grid.velocity, *geometry.args(), dt,
            clamp_lower, clamp_upper, *out)
        return (*out, G2PStats(int(clamped), int(first_bad), float(max_speed)))
    return reference.g2p(x, F_E, alpha, fractured, grid_id, material_id, material_table, grid.velocity,
                         geometry, dt, clamp_lower, clamp_upper)
