"""Which torch device a command runs on (its ``--device`` option)."""
from __future__ import annotations

import torch

DEVICE_CHOICES = ("cpu", "cuda")


class DeviceError(ValueError):
    """A device that was asked for but cannot be used; the message names ``--device``."""


def resolve_device(name: str | None) -> torch.device:
    """The device named ``name`` (one of :data:`DEVICE_CHOICES`), or with ``None`` the CUDA
    device when one is available and the CPU otherwise. DeviceError when CUDA is asked for
    but missing."""
    if name is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name not in DEVICE_CHOICES:
        raise DeviceError(f"--device: '{name}' is not one of {', '.join(DEVICE_CHOICES)}")
    if name == "cuda" and not torch.cuda.is_available():
        raise DeviceError("--device: cuda was requested but no CUDA device is available")
    return torch.device(name)
