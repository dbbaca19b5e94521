"""A frame's Gaussians (:class:`~fracture_gs.render.frame_gaussians.FrameGaussians`) in the form
viser's Gaussian splats take them: per object, one packed buffer (centre, covariance, RGBA per
Gaussian; :class:`ObjectSplats`), ready to assign to a ``GaussianSplatHandle``.

What changes on the way:

* colour: viser stores one RGB per Gaussian, no spherical harmonics. We use the DC band,
  ``SH_C0·sh₀ + 0.5`` clamped to [0, 1] — the SH colour averaged over all view directions
  (the higher bands integrate to zero over the sphere), so it does not depend on the view
  rotations of the frame;
* units: viser sends covariances as float16. Gaussians of millimetres in a metre-sized scene
  (σ² ≈ 1e-6) would fall into float16's subnormal range and lose their shape, so the splats are
  sent in *viewer units* — world coordinates times :attr:`SplatFrame.unit_scale`, chosen so that
  the scene's bounding box diagonal is 100 units (σ = 0.05 % of the scene stays a normal
  float16, a Gaussian as large as the scene stays below float16's maximum) — and the scene
  node is scaled back by ``1 / unit_scale``;
* FPGO's exclusive groups (only the nearest lens of each replaced Gaussian blends at a pixel)
  have no counterpart in viser's renderer: lens Gaussians blend like all others there.
"""
from __future__ import annotations

from dataclasses import dataclass

import matplotlib
import numpy as np
import torch

from fracture_gs.render.frame_gaussians import FrameGaussians
from fracture_gs.render.sh import SH_C0

VIEWER_EXTENT = 100.0                      # the scene's bounding box diagonal in viewer units
HIGHLIGHT_RGB = (1.0, 0.05, 0.75)          # fractured particles' Gaussians, on request
# "colour by piece": the i-th largest fragment gets PIECE_PALETTE[i % 20] (matplotlib's tab20, as
# tools/figures/fragment_strip.py draws them), fragments below 1 % of their object SMALL_PIECE_RGB.
PIECE_PALETTE = np.asarray(matplotlib.colormaps["tab20"].colors, np.float64)
SMALL_PIECE_RGB = (0.6, 0.6, 0.6)
# "colour by damage": the brittle damage d in [0, 1] through matplotlib's inferno (black intact,
# yellow complete), 256 steps.
DAMAGE_PALETTE = np.asarray(matplotlib.colormaps["inferno"](np.linspace(0.0, 1.0, 256))[:, :3], np.float64)


@dataclass(frozen=True)
class ObjectSplats:
    """One object's splats of a frame, packed as viser sends them (in viewer units, see the
    module docstring): per Gaussian 8 uint32 = centre (3 float32), a word the browser uses,
    the covariance's upper triangle xx xy xz yy yz zz (6 float16) and RGBA (4 uint8). Packing
    happens in the background thread, so showing a cached frame costs only the transfer."""

    buffer: np.ndarray       # (N,8) uint32
    fractured: np.ndarray    # (N,) bool: the Gaussian follows a fractured particle or is FPGO's
    piece_rank: np.ndarray | None = None   # (N,) int64: rank of the followed particle's fragment
    #                                        (-1: a fragment below 1 %); None: no fragment_id
    damage: np.ndarray | None = None       # (N,) float32: damage of the followed particle; None: no damage

    def __len__(self) -> int:
        return int(self.buffer.shape[0])

    @property
    def centers(self) -> np.ndarray:
        """(N,3) float32."""
        return self.buffer[:, 0:3].view(np.float32)

    @property
    def covariances(self) -> np.ndarray:
        """(N,3,3) float32 (from the float16 upper triangle)."""
        xx, xy, xz, yy, yz, zz = np.ascontiguousarray(self.buffer[:, 4:7]).view(np.float16) \
            .astype(np.float32).T
        return np.stack([xx, xy, xz, xy, yy, yz, xz, yz, zz], axis=1).reshape(-1, 3, 3)

    @property
    def rgba(self) -> np.ndarray:
        """(N,4) uint8."""
        return np.ascontiguousarray(self.buffer[:, 7]).view(np.uint8).reshape(-1, 4)

    def packed(self, highlight_fractured: bool, colour_pieces: bool = False,
               colour_damage: bool = False) -> np.ndarray:
        """The buffer to send: as prepared; with ``colour_pieces`` every Gaussian in its
        fragment's colour (:data:`PIECE_PALETTE` by size rank, :data:`SMALL_PIECE_RGB` for small
        fragments; nothing changes without fragment ids); with ``colour_damage`` in the colour of
        its particle's damage (:data:`DAMAGE_PALETTE`; over the pieces' colours where both are on);
        with ``highlight_fractured`` the fractured Gaussians in :data:`HIGHLIGHT_RGB` on top.
        Opacities are kept."""
        pieces = colour_pieces and self.piece_rank is not None and len(self) > 0
        damage = colour_damage and self.damage is not None and len(self) > 0
        highlight = highlight_fractured and bool(self.fractured.any())
        if not pieces and not damage and not highlight:
            return self.buffer
        buffer = self.buffer.copy()
        rgba = self.rgba
        if pieces:
            rgba[:, :3] = to_uint8(piece_colours(self.piece_rank))
        if damage:
            rgba[:, :3] = to_uint8(damage_colours(self.damage))
        if highlight:
            rgba[self.fractured, :3] = to_uint8(np.asarray(HIGHLIGHT_RGB))
        buffer[:, 7] = rgba.view(np.uint32).reshape(-1)
        return buffer


def piece_colours(piece_rank: np.ndarray) -> np.ndarray:
    """RGB (N,3) in [0,1] of fragment ranks (:func:`fracture_gs.mpm.fragments.piece_ranks`):
    :data:`PIECE_PALETTE` by rank, :data:`SMALL_PIECE_RGB` where the rank is -1."""
    return np.where((piece_rank >= 0)[:, None],
                    PIECE_PALETTE[np.maximum(piece_rank, 0) % len(PIECE_PALETTE)],
                    np.asarray(SMALL_PIECE_RGB))


def damage_colours(damage: np.ndarray) -> np.ndarray:
    """RGB (N,3) in [0,1] of damage values in [0, 1] (:data:`DAMAGE_PALETTE`)."""
    steps = len(DAMAGE_PALETTE) - 1
    return DAMAGE_PALETTE[np.clip(np.rint(np.asarray(damage, np.float64) * steps), 0, steps).astype(np.int64)]


def to_uint8(values: np.ndarray) -> np.ndarray:
    """[0,1] floats as rounded uint8."""
    return (np.clip(values, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def pack_splats(centers: np.ndarray, covariances: np.ndarray, rgbs: np.ndarray,
                opacities: np.ndarray) -> np.ndarray:
    """(N,8) uint32 in viser's splat layout (see :class:`ObjectSplats`) from float arrays:
    centres (N,3), covariances (N,3,3), RGB (N,3) and opacities (N,) in [0,1]."""
    count = centers.shape[0]
    buffer = np.zeros((count, 8), np.uint32)
    buffer[:, 0:3] = np.ascontiguousarray(centers, np.float32).view(np.uint32)
    upper = covariances.reshape(count, 9)[:, [0, 1, 2, 4, 5, 8]]
    buffer[:, 4:7] = np.ascontiguousarray(upper, np.float16).view(np.uint32)
    rgba = np.empty((count, 4), np.uint8)
    rgba[:, :3] = to_uint8(rgbs)
    rgba[:, 3] = to_uint8(opacities.reshape(count))
    buffer[:, 7] = rgba.view(np.uint32).reshape(count)
    return buffer


@dataclass(frozen=True)
class SplatFrame:
    """All objects' splats of one frame plus what the GUI shows about it."""

    index: int
    objects: list[ObjectSplats]          # one per object, in scene order (possibly empty)
    unit_scale: float                    # viewer units per world unit
    gaussians: int                       # Gaussians drawn (all objects)
    fpgo_gaussians: int                  # of which FPGO made
    fractured_particles: int             # particles with the latched fracture flag
    prepare_ms: float = 0.0              # frame Gaussians + conversion, in the background


def unit_scale_for(lower: np.ndarray, upper: np.ndarray) -> float:
    """Viewer units per world unit for a scene whose bounds are ``lower``..``upper``."""
    diagonal = float(np.linalg.norm(np.asarray(upper, np.float64) - np.asarray(lower, np.float64)))
    return VIEWER_EXTENT / diagonal if diagonal > 0 else 1.0


def dc_colours(sh: np.ndarray) -> np.ndarray:
    """RGB (N,3) of the SH DC band (N,K,3): the colour averaged over view directions."""
    return np.clip(SH_C0 * sh[:, 0, :] + 0.5, 0.0, 1.0)


def object_splats(gaussians: FrameGaussians, object_count: int, unit_scale: float,
                  fractured_particles: torch.Tensor | None = None,
                  particle_piece_rank: torch.Tensor | None = None,
                  particle_damage: torch.Tensor | None = None) -> list[ObjectSplats]:
    """Split ``gaussians`` by object, convert and pack them (see the module docstring).

    ``fractured_particles`` (bool per particle) marks the Gaussians that follow a fractured
    particle; FPGO's own Gaussians always count as fractured. ``particle_piece_rank`` (int per
    particle, :func:`fracture_gs.mpm.fragments.piece_ranks`) gives each Gaussian the rank of the
    fragment of the particle it follows (-1 where it follows none); ``particle_damage`` (float per
    particle) the damage of that particle (0 where it follows none).
    """
    def numpy(values: torch.Tensor) -> np.ndarray:   # numpy from here: no torch thread pool
        return values.detach().cpu().numpy()

    fractured = numpy(gaussians.is_fpgo).copy()
    following = numpy(gaussians.particle)
    valid = following >= 0
    if fractured_particles is not None and len(gaussians):
        fractured[valid] |= numpy(fractured_particles.bool())[following[valid]]
    piece_rank = None
    if particle_piece_rank is not None:
        piece_rank = np.full(len(gaussians), -1, np.int64)
        piece_rank[valid] = numpy(particle_piece_rank.long())[following[valid]]
    damage = None
    if particle_damage is not None:
        damage = np.zeros(len(gaussians), np.float32)
        damage[valid] = numpy(particle_damage.float())[following[valid]]
    object_id = numpy(gaussians.object_id)
    order = None
    if object_id.size and (np.diff(object_id) < 0).any():   # FPGO may append out of order
        order = np.argsort(object_id, kind="stable")
        object_id, fractured = object_id[order], fractured[order]
        piece_rank = piece_rank[order] if piece_rank is not None else None
        damage = damage[order] if damage is not None else None

    def column(values: torch.Tensor) -> np.ndarray:
        array = numpy(values.float())
        return array[order] if order is not None else array

    buffer = pack_splats(column(gaussians.means) * unit_scale,
                         column(gaussians.covariances) * (unit_scale * unit_scale),
                         dc_colours(column(gaussians.sh[:, :1])), column(gaussians.opacities))
    bounds = np.searchsorted(object_id, np.arange(object_count + 1))
    return [ObjectSplats(buffer[bounds[i]:bounds[i + 1]], fractured[bounds[i]:bounds[i + 1]],
                         piece_rank[bounds[i]:bounds[i + 1]] if piece_rank is not None else None,
                         damage[bounds[i]:bounds[i + 1]] if damage is not None else None)
            for i in range(object_count)]


__all__ = ["DAMAGE_PALETTE", "HIGHLIGHT_RGB", "PIECE_PALETTE", "SMALL_PIECE_RGB", "ObjectSplats", "SplatFrame",
           "VIEWER_EXTENT", "damage_colours", "dc_colours", "object_splats", "pack_splats", "piece_colours",
           "to_uint8", "unit_scale_for"]
