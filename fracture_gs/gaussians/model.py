"""A set of 3D Gaussians with raw (pre-activation) parameters, as in 3DGS (Kerbl et al. 2023)."""
from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

SH_C0 = 0.28209479177387814  # Y_0^0 = 1 / (2 sqrt(pi))
MAX_SH_DEGREE = 3


def num_sh_coefficients(degree: int) -> int:
    """Number of SH basis functions K = (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_degree_of(num_coefficients: int) -> int:
    """Inverse of :func:`num_sh_coefficients`; ValueError if K is not (d + 1)^2, d <= 3."""
    degree = math.isqrt(num_coefficients) - 1
    if num_coefficients < 1 or num_sh_coefficients(degree) != num_coefficients \
            or degree > MAX_SH_DEGREE:
        raise ValueError(f"{num_coefficients} SH coefficients is not (d+1)^2 for d in 0..3")
    return degree


def rgb_to_sh_dc(rgb: torch.Tensor) -> torch.Tensor:
    """Degree-0 SH coefficient that renders as ``rgb`` (3DGS adds 0.5 after evaluating SH)."""
    return (rgb - 0.5) / SH_C0


def sh_dc_to_rgb(sh_dc: torch.Tensor) -> torch.Tensor:
    return sh_dc * SH_C0 + 0.5


def inverse_sigmoid(values: torch.Tensor) -> torch.Tensor:
    return torch.log(values / (1.0 - values))


def quaternion_to_rotation_matrix(quats: torch.Tensor) -> torch.Tensor:
    """(N, 4) quaternions w x y z (normalised here) -> (N, 3, 3) rotation matrices."""
    w, x, y, z = F.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(*quats.shape[:-1], 3, 3)


class GaussianModel(torch.nn.Module):
    """N Gaussians stored as the raw parameters an optimiser updates.

    Parameters (all ``nn.Parameter``):
        means (N, 3); sh_dc (N, 1, 3); sh_rest (N, K-1, 3) with K = (degree+1)^2;
        opacity_logit (N, 1); log_scales (N, 3), or (N, 1) for an isotropic model;
        quats (N, 4) as w x y z, not necessarily normalised.
    The activated values are the properties ``opacities``, ``scales``, ``rotations``, ``sh``.
    """

    def __init__(self, means: torch.Tensor, sh_dc: torch.Tensor, sh_rest: torch.Tensor,
                 opacity_logit: torch.Tensor, log_scales: torch.Tensor,
                 quats: torch.Tensor) -> None:
        super().__init__()
        count = means.shape[0]
        expected = {"means": (means, (count, 3)), "sh_dc": (sh_dc, (count, 1, 3)),
                    "opacity_logit": (opacity_logit, (count, 1)), "quats": (quats, (count, 4))}
        for name, (tensor, shape) in expected.items():
            if tuple(tensor.shape) != shape:
                raise ValueError(f"GaussianModel: {name} must have shape {shape}, "
                                 f"got {tuple(tensor.shape)}")
        if sh_rest.ndim != 3 or sh_rest.shape[0] != count or sh_rest.shape[2] != 3:
            raise ValueError(f"GaussianModel: sh_rest must be ({count}, K-1, 3), "
                             f"got {tuple(sh_rest.shape)}")
        sh_degree_of(sh_rest.shape[1] + 1)
        if log_scales.shape not in ((count, 3), (count, 1)):
            raise ValueError(f"GaussianModel: log_scales must be ({count}, 3) or ({count}, 1), "
                             f"got {tuple(log_scales.shape)}")
        self.means = torch.nn.Parameter(means.detach().float())
        self.sh_dc = torch.nn.Parameter(sh_dc.detach().float())
        self.sh_rest = torch.nn.Parameter(sh_rest.detach().float())
        self.opacity_logit = torch.nn.Parameter(opacity_logit.detach().float())
        self.log_scales = torch.nn.Parameter(log_scales.detach().float())
        self.quats = torch.nn.Parameter(quats.detach().float())

    @classmethod
    def from_points(cls, points: torch.Tensor, colors: torch.Tensor | None = None,
                    sh_degree: int = 3, isotropic: bool = False,
                    initial_opacity: float = 0.1) -> "GaussianModel":
        """3DGS initialisation from a point cloud.

        Colours (N, 3) in [0, 1] (grey if None) become the SH DC term, higher bands start at
        zero, opacity at ``initial_opacity``, rotation at identity, and every scale at the
        root mean squared distance to the 3 nearest other points (3DGS's ``distCUDA2``).
        """
        from scipy.spatial import cKDTree

        points = torch.as_tensor(points, dtype=torch.float32)
        if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 1:
            raise ValueError(f"from_points: points must be (N>=1, 3), got {tuple(points.shape)}")
        if not 0.0 < initial_opacity < 1.0:
            raise ValueError(f"from_points: initial_opacity must be in (0, 1), "
                             f"got {initial_opacity}")
        count = points.shape[0]
        if colors is None:
            colors = torch.full((count, 3), 0.5)
        colors = torch.as_tensor(colors, dtype=torch.float32, device=points.device)
        if colors.shape != (count, 3):
            raise ValueError(f"from_points: colors must be ({count}, 3), got {tuple(colors.shape)}")
        if count > 1:
            neighbours = min(3, count - 1)
            distances, _ = cKDTree(points.cpu().numpy()).query(points.cpu().numpy(),
                                                               k=neighbours + 1)
            mean_squared = np.mean(np.square(distances[:, 1:]), axis=1)
        else:
            mean_squared = np.ones(1)
        log_scale = torch.from_numpy(0.5 * np.log(np.maximum(mean_squared, 1e-7))).float()
        log_scales = log_scale[:, None].repeat(1, 1 if isotropic else 3).to(points.device)
        quats = torch.zeros(count, 4, device=points.device)
        quats[:, 0] = 1.0
        return cls(points, rgb_to_sh_dc(colors)[:, None, :],
                   torch.zeros(count, num_sh_coefficients(sh_degree) - 1, 3,
                               device=points.device),
                   torch.full((count, 1), float(inverse_sigmoid(torch.tensor(initial_opacity))),
                              device=points.device),
                   log_scales, quats)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def num_gaussians(self) -> int:
        return self.means.shape[0]

    @property
    def isotropic(self) -> bool:
        """True when one log-scale per Gaussian is stored."""
        return self.log_scales.shape[1] == 1

    @property
    def sh_degree(self) -> int:
        return sh_degree_of(self.sh_rest.shape[1] + 1)

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) sigmoid of the opacity logits."""
        return torch.sigmoid(self.opacity_logit[:, 0])

    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) exp of the log-scales (repeated for isotropic models)."""
        return torch.exp(self.log_scales).expand(-1, 3)

    @property
    def rotations(self) -> torch.Tensor:
        """(N, 4) unit quaternions w x y z."""
        return F.normalize(self.quats, dim=-1)

    @property
    def sh(self) -> torch.Tensor:
        """(N, K, 3) SH coefficients, DC first."""
        return torch.cat([self.sh_dc, self.sh_rest], dim=1)

    def rotation_matrices(self) -> torch.Tensor:
        return quaternion_to_rotation_matrix(self.quats)

    def covariances(self) -> torch.Tensor:
        """(N, 3, 3) world covariances R S^2 R^T."""
        scaled_axes = self.rotation_matrices() * self.scales[:, None, :]  # R S
        return scaled_axes @ scaled_axes.transpose(1, 2)

    def param_groups(self, spatial_lr_scale: float = 1.0, means_lr: float = 1.6e-4,
                     sh_dc_lr: float = 2.5e-3, opacity_lr: float = 2.5e-2,
                     scaling_lr: float = 5e-3, rotation_lr: float = 1e-3) -> list[dict]:
        """Adam parameter groups with the learning rates of 3DGS (``sh_rest`` gets the DC
        rate / 20, ``means`` is scaled by the scene extent ``spatial_lr_scale``)."""
        return [
            {"params": [self.means], "lr": means_lr * spatial_lr_scale, "name": "means"},
            {"params": [self.sh_dc], "lr": sh_dc_lr, "name": "sh_dc"},
            {"params": [self.sh_rest], "lr": sh_dc_lr / 20.0, "name": "sh_rest"},
            {"params": [self.opacity_logit], "lr": opacity_lr, "name": "opacity_logit"},
            {"params": [self.log_scales], "lr": scaling_lr, "name": "log_scales"},
            {"params": [self.quats], "lr": rotation_lr, "name": "quats"},
        ]

    def raw_tensors(self) -> dict[str, torch.Tensor]:
        """The raw parameters by name (detached)."""
        return {name: parameter.detach() for name, parameter in self.named_parameters()}

    def select(self, index: torch.Tensor) -> "GaussianModel":
        """A new model with the Gaussians at ``index`` (bool mask or integer indices)."""
        tensors = self.raw_tensors()
        return GaussianModel(*(tensors[name][index] for name in PARAMETER_NAMES))

    @staticmethod
    def concatenate(models: list["GaussianModel"]) -> "GaussianModel":
        """One model holding the Gaussians of all ``models`` (same SH degree and isotropy)."""
        if not models:
            raise ValueError("concatenate: no models")
        if len({(m.sh_degree, m.isotropic) for m in models}) != 1:
            raise ValueError("concatenate: models differ in SH degree or isotropy")
        return GaussianModel(*(torch.cat([m.raw_tensors()[name] for m in models])
                               for name in PARAMETER_NAMES))

    def extra_repr(self) -> str:
        return (f"num_gaussians={self.num_gaussians}, sh_degree={self.sh_degree}, "
                f"isotropic={self.isotropic}")


PARAMETER_NAMES = ("means", "sh_dc", "sh_rest", "opacity_logit", "log_scales", "quats")
