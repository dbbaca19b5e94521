"""Reading and writing Gaussians in the standard 3DGS ``point_cloud.ply`` layout.

One ``vertex`` element of float32 properties, binary little-endian:
``x y z nx ny nz f_dc_0..2 f_rest_0..M-1 opacity scale_0..2 rot_0..3`` with raw
(pre-activation) values: logit opacity, log scales, quaternion w x y z. ``f_rest`` is
channel-major: the in-memory (N, K-1, 3) coefficients are written transposed to (N, 3, K-1)
and flattened, so ``f_rest_{c (K-1) + k}`` is channel c of coefficient k + 1.
"""
from __future__ import annotations

import os
import re

import numpy as np
import plyfile
import torch

from fracture_gs.gaussians.model import GaussianModel, num_sh_coefficients
from fracture_gs.io.atomic import atomic_write

REST_COUNT_TO_DEGREE = {3 * (num_sh_coefficients(d) - 1): d for d in range(4)}  # 0 9 24 45
REQUIRED_PROPERTIES = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                       "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
ISOTROPY_TOLERANCE = 1e-6


class PlyFormatError(ValueError):
    """A Gaussian PLY file that does not follow the 3DGS layout (message names the file)."""


def ply_property_names(sh_degree: int) -> list[str]:
    """Property names, in file order, of a 3DGS PLY with SH degree ``sh_degree``."""
    rest = 3 * (num_sh_coefficients(sh_degree) - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(path: str, model: GaussianModel, normals: torch.Tensor | None = None) -> None:
    """Write ``model`` as a 3DGS PLY (parent folders are created; the file appears only once
    complete). Isotropic models repeat their log-scale in scale_0..2; normals (N, 3) are zero
    unless given (3DGS renderers ignore them)."""
    tensors = {name: value.cpu().float() for name, value in model.raw_tensors().items()}
    for name, value in tensors.items():
        if not torch.isfinite(value).all():
            raise ValueError(f"write_ply({path}): model parameter {name} contains NaN or Inf")
    count = model.num_gaussians
    rest = tensors["sh_rest"].transpose(1, 2).reshape(count, -1)  # channel-major
    if normals is None:
        normals = torch.zeros(count, 3)
    elif tuple(normals.shape) != (count, 3):
        raise ValueError(f"write_ply({path}): normals must be ({count}, 3), got {tuple(normals.shape)}")
    columns = torch.cat([tensors["means"], normals.detach().cpu().float(),
                         tensors["sh_dc"].reshape(count, 3), rest, tensors["opacity_logit"], tensors["log_scales"].expand(-1, 3),
                         tensors["quats"]], dim=1).numpy()
    names = ply_property_names(model.sh_degree)
    vertices = np.empty(count, dtype=[(name, "<f4") for name in names])
    for column, name in enumerate(names):
        vertices[name] = columns[:, column]
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertices, "vertex")], byte_order="<")
    atomic_write(path, ply.write)


def _columns(vertex: plyfile.PlyElement, names: list[str], path: str) -> np.ndarray:
    """(N, len(names)) float32 array of the named properties, checked to be finite."""
    if not names:
        return np.zeros((vertex.count, 0), dtype=np.float32)
    values = np.stack([np.asarray(vertex[name], dtype=np.float32) for name in names], axis=1)
    bad = ~np.isfinite(values).all(axis=0)
    if bad.any():
        raise PlyFormatError(f"{path}: property {names[int(np.argmax(bad))]} contains NaN or Inf")
    return values


def read_ply(path: str, isotropic: bool = False,
             device: torch.device | str | None = None) -> GaussianModel:
    """Read a 3DGS PLY (from the original 3DGS, gsplat, or :func:`write_ply`).

    The SH degree follows from the number of ``f_rest_*`` properties (0, 9, 24, 45 ->
    degree 0..3). With ``isotropic`` the three scales of every Gaussian must be equal and a
    (N, 1) log-scale model is returned.

    Raises:
        PlyFormatError: unreadable file, no ``vertex`` element, a missing property, an
            ``f_rest`` count that is no SH degree, NaN values, or unequal scales when
            ``isotropic`` is set.
    """
    if not os.path.isfile(path):
        raise PlyFormatError(f"{path}: file not found")
    try:
        ply = plyfile.PlyData.read(path)
    except Exception as error:  # plyfile raises several unrelated types on corrupt files
        raise PlyFormatError(f"{path}: not a readable PLY file ({type(error).__name__}: "
                             f"{str(error).splitlines()[0] if str(error) else ''})") from None
    if "vertex" not in ply:
        raise PlyFormatError(f"{path}: no 'vertex' element")
    vertex = ply["vertex"]
    present = [prop.name for prop in vertex.properties]
    for name in REQUIRED_PROPERTIES:
        if name not in present:
            raise PlyFormatError(f"{path}: missing property '{name}'")
    rest_indices = sorted(int(match.group(1)) for name in present
                          if (match := re.fullmatch(r"f_rest_(\d+)", name)))
    if rest_indices != list(range(len(rest_indices))):
        raise PlyFormatError(f"{path}: f_rest_* properties are not numbered "
                             f"0..{len(rest_indices) - 1}")
    if len(rest_indices) not in REST_COUNT_TO_DEGREE:
        raise PlyFormatError(f"{path}: {len(rest_indices)} f_rest_* properties match no SH "
                             f"degree (expected 0, 9, 24 or 45)")
    rest_count = len(rest_indices) // 3
    count = vertex.count
    means = _columns(vertex, ["x", "y", "z"], path)
    sh_dc = _columns(vertex, ["f_dc_0", "f_dc_1", "f_dc_2"], path).reshape(count, 1, 3)
    rest = _columns(vertex, [f"f_rest_{i}" for i in rest_indices], path)
    sh_rest = rest.reshape(count, 3, rest_count).transpose(0, 2, 1)  # channel-major on disk
    opacity = _columns(vertex, ["opacity"], path)
    log_scales = _columns(vertex, ["scale_0", "scale_1", "scale_2"], path)
    quats = _columns(vertex, ["rot_0", "rot_1", "rot_2", "rot_3"], path)
    if isotropic:
        spread = np.abs(log_scales - log_scales[:, :1]).max() if count else 0.0
        if spread > ISOTROPY_TOLERANCE:
            raise PlyFormatError(f"{path}: scale_0..2 differ by up to {spread:.3g}, the model is "
                                 f"not isotropic")
        log_scales = log_scales[:, :1]
    model = GaussianModel(*(torch.from_numpy(np.ascontiguousarray(array)) for array in
                            (means, sh_dc, sh_rest, opacity, log_scales, quats)))
    return model if device is None else model.to(device)
