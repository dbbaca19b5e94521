"""Gaussian-splatting rendering: camera, differentiable rasterizer and its PyTorch twin."""
from fracture_gs.render.camera import Camera
from fracture_gs.render.rasterize import rasterize
from fracture_gs.render.reference import rasterize_reference

__all__ = ["Camera", "rasterize", "rasterize_reference"]
