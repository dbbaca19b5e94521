"""How many substeps a scene will take, estimated before it runs.

The solver's substep is the CFL step dt = cfl Δx / (c_max + |v|_max) (``CollisionMPM.stable_dt``),
c_max the largest P-wave speed of the deforming objects' materials (a rigid object sets none) and
|v|_max the largest particle speed. At the start of a run both are known, so the substeps of the
scene's ``frames × frame_dt`` can be counted before the first step: a scene that would take more
than ``bounds.SUBSTEPS_MAX`` of them (a light, stiff material whose wave speed makes the step
nanoseconds long, or days of simulated time) is refused with one line instead of running for ever.
Gravity and impacts only make the particles faster, so the count is a lower bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from fracture_gs import bounds
from fracture_gs.config.scene import SceneConfig, SceneError
from fracture_gs.mpm.scene import BuiltScene

# Above this many substeps per frame the step itself is the problem (the material or the speed
# named in the error); below it the scene simply has too many frames.
SUBSTEPS_PER_FRAME_LIMIT = 1.0e5


@dataclass(frozen=True)
class SubstepEstimate:
    """The CFL step at the start of a run and the substeps the scene's duration needs."""

    dt: float             # s, the first CFL step
    wave_speed: float     # m/s, the largest P-wave speed
    speed: float          # m/s, the largest initial particle speed
    substeps: float       # frames × frame_dt / dt
    per_frame: float      # frame_dt / dt


def estimate_substeps(config: SceneConfig, built: BuiltScene) -> SubstepEstimate:
    """The first CFL step of the built scene and how many such steps its frames take."""
    wave_speed = max((built.materials[row].wave_speed for row in built.step_rows), default=0.0)
    speed = float(built.particles.v.double().norm(dim=1).max())
    dt = config.cfl * config.domain.dx / max(wave_speed + speed, 1e-12)
    return SubstepEstimate(dt=dt, wave_speed=wave_speed, speed=speed,
                           substeps=config.frames * config.frame_dt / dt,
                           per_frame=config.frame_dt / dt)


def check_substeps(config: SceneConfig, built: BuiltScene) -> None:
    """SceneError naming the key that sets the step when the scene would take more than
    ``bounds.SUBSTEPS_MAX`` substeps."""
    estimate = estimate_substeps(config, built)
    if not estimate.substeps > bounds.SUBSTEPS_MAX:
        return
    cost = (f"a substep of {estimate.dt:.3g} s (cfl {config.cfl:g}, cell {config.domain.dx:.3g} m), "
            f"so {config.frames} frames of {config.frame_dt:.3g} s would take "
            f"{estimate.substeps:.3g} substeps, more than {bounds.SUBSTEPS_MAX:.0e}")
    if estimate.per_frame <= SUBSTEPS_PER_FRAME_LIMIT:
        raise SceneError("frames", f"{config.frames} frames is too long a run: {cost}; simulate "
                                   "fewer frames")
    if estimate.wave_speed >= estimate.speed:
        row = max(built.step_rows, key=lambda r: built.materials[r].wave_speed)
        material = built.materials[row]
        raise SceneError(_material_path(config, *built.material_keys[row]),
                         f"E {material.E:g} Pa, nu {material.nu:g} and density {material.density:g} "
                         f"kg/m³ give a P-wave speed of {estimate.wave_speed:.3g} m/s and {cost}; "
                         "use a softer or denser material, a coarser domain.grid or fewer frames")
    index = int(built.particles.obj_id[int(torch.argmax(built.particles.v.double().norm(dim=1)))])
    raise SceneError(f"objects[{index}]", f"its initial speed of {estimate.speed:.3g} m/s (velocity, "
                                          f"angular_velocity, velocity_gradient) gives {cost}; start "
                                          "it slower, use a coarser domain.grid or fewer frames")


def _material_path(config: SceneConfig, object_index: int, part: int) -> str:
    """Key path of the material of one object's part."""
    materials = config.objects[object_index].materials
    position = next(j for j, entry in enumerate(materials) if entry.part == part)
    return f"objects[{object_index}].materials[{position}]"
