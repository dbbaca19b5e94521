"""Halo: how much of a rendered object shows outside its mask.

A model fitted to photos whose background was not masked out carries splats of that background
around the object (a halo that then travels with it in a simulation). Measured on a render of a
view with a known object mask: the pixels farther than ``dilate_px`` from the mask whose colour
differs from the background by more than ``threshold`` (largest channel difference), as a share
of all pixels farther than ``dilate_px`` from the mask. The dilation forgives the soft edge of
the silhouette and small errors of the mask itself.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

DEFAULT_DILATE_PX = 4
DEFAULT_THRESHOLD = 10.0 / 255.0
MASK_LEVEL = 0.5


@dataclass(frozen=True)
class Halo:
    """Halo of one view: pixels outside the dilated mask, and how many differ from the background."""

    outside: int
    differing: int

    @property
    def share(self) -> float:
        return self.differing / self.outside if self.outside else 0.0


def outside_mask(mask: np.ndarray, dilate_px: int) -> np.ndarray:
    """(H, W) bool: pixels farther than ``dilate_px`` (Euclidean) from the mask (values >= 0.5)."""
    inside = (np.asarray(mask, dtype=np.float32) >= MASK_LEVEL).astype(np.uint8)
    if not inside.any():
        return np.ones(inside.shape, dtype=bool)
    distance = cv2.distanceTransform(1 - inside, cv2.DIST_L2, 5)
    return distance > dilate_px


def halo(render: np.ndarray, mask: np.ndarray, background: tuple[float, float, float],
         dilate_px: int = DEFAULT_DILATE_PX, threshold: float = DEFAULT_THRESHOLD) -> Halo:
    """The :class:`Halo` of ``render`` ((H, W, 3) floats in [0, 1]) against ``mask`` ((H, W) in
    [0, 1]) on ``background`` (RGB in [0, 1])."""
    render = np.asarray(render, dtype=np.float32)
    if render.shape[:2] != np.shape(mask):
        raise ValueError(f"render {render.shape[:2]} and mask {np.shape(mask)} differ in size")
    outside = outside_mask(mask, dilate_px)
    difference = np.abs(render - np.asarray(background, dtype=np.float32)).max(axis=2)
    return Halo(int(outside.sum()), int((outside & (difference > threshold)).sum()))
