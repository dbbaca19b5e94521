"""The in-memory result of every dataset loader (docs/file_formats.md §1)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from fracture_gs.render.camera import Camera


class DatasetError(ValueError):
    """A malformed or unreadable dataset; the message is one line naming the file."""


@dataclass
class Dataset:
    """Posed images of one scene, with every camera in the OpenCV convention of docs/formulas.md §1.

    Attributes:
        cameras: one :class:`Camera` per image (world-to-camera, fx fy cx cy, size).
        images: (N, H, W, 3) float32 RGB in [0, 1]; RGBA inputs, and photos with a mask
            file, are composited on the background colour the loader was asked for (the alpha
            channel or the mask as opacity).
        masks: (N, H, W) float32 in [0, 1] (alpha channel or mask images), or None.
        image_paths: the file each image was read from.
        format: ``"blender"``, ``"colmap"`` or ``"dtu"``.
        points: (P, 3) float32 sparse points (COLMAP ``points3D``), or None.
        point_colors: (P, 3) float32 colours in [0, 1] of ``points``, or None.
        scale_mat: 4x4 float64 matrix mapping the loader's (normalised) world frame back to
            the original one (DTU/NeuS ``scale_mat_0``); None when the frames coincide.
        background: the RGB colour transparent pixels were composited on.
    """

    cameras: list[Camera]
    images: torch.Tensor
    masks: torch.Tensor | None
    image_paths: list[str]
    format: str
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    scale_mat: np.ndarray | None = None
    background: tuple[float, float, float] = field(default=(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        count = len(self.cameras)
        if self.images.ndim != 4 or self.images.shape[0] != count or self.images.shape[-1] != 3:
            raise ValueError(f"images must be ({count},H,W,3), got {tuple(self.images.shape)}")
        if self.masks is not None and self.masks.shape != self.images.shape[:3]:
            raise ValueError(f"masks must be {tuple(self.images.shape[:3])}, "
                             f"got {tuple(self.masks.shape)}")
        if len(self.image_paths) != count:
            raise ValueError(f"{len(self.image_paths)} image paths for {count} cameras")

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])

    def camera_centers(self) -> torch.Tensor:
        """(N, 3) camera positions in world coordinates."""
        if not self.cameras:
            return torch.zeros(0, 3)
        return torch.stack([camera.center for camera in self.cameras])

    def scene_bounds(self) -> tuple[torch.Tensor, float]:
        """Centre and radius of the camera rig, as 3DGS's ``getNerfppNorm``.

        The centre is the mean camera position; the radius is 1.1 times the largest distance
        of a camera from it (3DGS uses it to scale position learning rates).
        """
        centers = self.camera_centers()
        if centers.shape[0] == 0:
            raise ValueError("scene_bounds: the dataset has no cameras")
        center = centers.mean(0)
        radius = 1.1 * float((centers - center).norm(dim=1).max())
        return center, radius

    def to(self, device: torch.device | str) -> "Dataset":
        """A copy with cameras, images and masks on ``device`` (sparse points stay NumPy)."""
        return Dataset(
            cameras=[camera.to(device) for camera in self.cameras],
            images=self.images.to(device),
            masks=None if self.masks is None else self.masks.to(device),
            image_paths=list(self.image_paths),
            format=self.format,
            points=self.points,
            point_colors=self.point_colors,
            scale_mat=self.scale_mat,
            background=self.background,
        )

    def subset(self, indices: list[int]) -> "Dataset":
        """A dataset with only the views at ``indices`` (sparse points are shared)."""
        index = torch.as_tensor(indices, dtype=torch.long)
        return Dataset(
            cameras=[self.cameras[i] for i in indices],
            images=self.images[index],
            masks=None if self.masks is None else self.masks[index],
            image_paths=[self.image_paths[i] for i in indices],
            format=self.format,
            points=self.points,
            point_colors=self.point_colors,
            scale_mat=self.scale_mat,
            background=self.background,
        )
