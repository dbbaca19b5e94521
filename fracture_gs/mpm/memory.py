"""Memory a scene will need, estimated before anything is allocated.

A ``domain.grid`` of 4096 asks for terabytes of grid fields; allocating them fails deep inside
torch (or, worse, the kernel's out-of-memory killer ends the process). :func:`check_scene_memory`
compares the two big allocations of a run with the memory available on the device and names
the key that asks too much:

* the dense grid fields of the solver (one grid per object in collision mode, one shared grid
  for ``mls``), counted from :class:`GridFields` itself on torch's ``meta`` device, so the
  estimate follows the fields the solver really allocates;
* the candidate particles a primitive is sampled from (one per sub-cell of its bounding box).
"""
from __future__ import annotations

import math
import os

import numpy as np
import torch

from fracture_gs.config.scene import SceneConfig, SceneError
from fracture_gs.mpm.grid import GridFields, GridGeometry
from fracture_gs.mpm.scene import primitive_lattice

# Peak bytes per candidate particle while a primitive is sampled (float64 centres, jittered
# positions, signed distance, masks).
SAMPLING_BYTES_PER_CANDIDATE = 96
UNITS = ("B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB")


def format_bytes(count: float) -> str:
    """``3.1 TiB``-style binary size."""
    exponent = 0 if count < 1024 else min(int(math.log(count, 1024)), len(UNITS) - 1)
    value = count / 1024 ** exponent
    return f"{value:.0f} {UNITS[exponent]}" if exponent == 0 else f"{value:.1f} {UNITS[exponent]}"


def grid_memory_bytes(config: SceneConfig) -> tuple[int, int, int]:
    """(bytes, grids, nodes per grid) of the solver's grid fields for ``config`` (with fragments,
    grids counts the fields: two per object grid)."""
    collision = config.contact.mode == "collision"
    n_grids = len(config.objects) if collision else 1
    fragments = config.contact.fragments  # a second field per grid, as the solver allocates
    geometry = GridGeometry.from_domain(config.domain, 2 * n_grids if fragments else n_grids)
    fields = GridFields.zeros(geometry, torch.device("meta"),
                              with_contact=collision and n_grids >= 2, with_fragments=fragments)
    total = sum(t.numel() * t.element_size() for t in vars(fields).values()
                if isinstance(t, torch.Tensor))
    return total, n_grids, geometry.nodes_per_grid


def available_memory_bytes(device: torch.device) -> int | None:
    """Free memory of ``device`` (CUDA: free device memory; CPU: the kernel's MemAvailable),
    or None when it cannot be told."""
    if device.type == "cuda":
        return int(torch.cuda.mem_get_info(device)[0])
    try:
        with open("/proc/meminfo", encoding="ascii") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def check_scene_memory(config: SceneConfig, device: torch.device,
                       available: int | None = None) -> None:
    """SceneError naming ``domain.grid`` or ``objects[i].primitive`` when the grid fields or a
    primitive's sampling would need more than the ``available`` bytes (default: what
    :func:`available_memory_bytes` reports for ``device``)."""
    available = available_memory_bytes(device) if available is None else available
    if available is None:
        return
    where = f"{device.type} memory"
    grid_bytes, n_grids, nodes = grid_memory_bytes(config)
    if grid_bytes > available:
        side = round(nodes ** (1 / 3))
        raise SceneError("domain.grid", f"{config.domain.grid} needs {format_bytes(grid_bytes)} of "
                         f"grid memory ({n_grids} grid{'s' if n_grids > 1 else ''} of about "
                         f"{side}³ nodes), more than the {format_bytes(available)} of free "
                         f"{where}; use a coarser grid")
    for index, obj in enumerate(config.objects):
        if obj.primitive is None:
            continue
        _, counts = primitive_lattice(obj.primitive, config.domain.dx, obj.transform.scale)
        candidates = int(np.prod(counts.astype(np.float64)))
        sampling = candidates * SAMPLING_BYTES_PER_CANDIDATE
        if grid_bytes + sampling > available:
            raise SceneError(f"objects[{index}].primitive",
                             f"sampling {candidates:.3g} candidate particles at grid "
                             f"{config.domain.grid} ({obj.primitive.particles_per_cell} per cell) "
                             f"needs {format_bytes(sampling)} besides the "
                             f"{format_bytes(grid_bytes)} of grid memory, more than the "
                             f"{format_bytes(available)} of free {where}")
