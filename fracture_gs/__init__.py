"""fracture_gs: multi-view images to simulated, photoreal fracturing collisions.

Stages: reconstruction (``train.py``), Collision-MPM simulation (``simulate.py``),
Gaussian-splatting rendering with fracture-surface Gaussians (``render.py``) and
evaluation (``evaluate.py``). Every compiled kernel has a PyTorch twin.
"""
import torch  # noqa: F401  (must be imported before the compiled extension)

__version__ = "0.1.0"
