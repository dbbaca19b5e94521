"""The ranges of the numbers a user can type: scene and material keys, seeds, frame rates.

Each range holds every real object the simulator is meant for with room to spare, and keeps the
float32 kernels clear of overflow (docs/scenes.md and docs/materials.md state them). The readers
check each value once, where they read it: the scene keys in :mod:`fracture_gs.config.scene`, the
material keys in the material classes' ``from_yaml`` (through :mod:`fracture_gs.keys`; a model's own
keys have their ranges beside it), the command-line options in the commands.
"""
from __future__ import annotations

SEED_MAX = 2 ** 64 - 1          # seeds are unsigned 64-bit integers (splitmix64, numpy, torch)

# Scene (SI units).
FRAMES_MAX = 1_000_000
FRAME_DT = (0.0, 1.0)               # s (> 0)
GRAVITY = (-1.0e4, 1.0e4)           # m/s², each component (about 1000 g)
VELOCITY = (-1.0e4, 1.0e4)          # m/s, each component of an object's velocity
ANGULAR_VELOCITY = (-1.0e4, 1.0e4)  # rad/s, each component
VELOCITY_GRADIENT = (-1.0e4, 1.0e4)  # 1/s, each entry
# A run is refused before it starts when the CFL substep dt = cfl dx / (c_max + |v|_max) would
# need more substeps than this for the scene's frames x frame_dt.
SUBSTEPS_MAX = 1.0e8

# Materials (SI units).
DENSITY = (1.0e-2, 1.0e5)           # kg/m³ (aerogels ~1, osmium 22 590)
YOUNGS_MODULUS = (1.0, 1.0e13)      # Pa (gels ~1e2, diamond 1.2e12)
STRESS = (1.0, 1.0e11)              # Pa, a strength or yield stress (snow ~1e3, glass fibre ~5e9)
SOFTENING = (1.0, 1.0e6)            # a preset's softening factor k (E / k, strength / √k)
# A material model's own keys have their ranges in its class (fracture_gs/materials/).

# Command lines.
FPS = (0.1, 1000.0)                 # frames per second of render.py's videos and view.py's playback
