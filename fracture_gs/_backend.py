"""Loading of the compiled extension and choice of backend for every op.

``torch`` is imported before ``fracture_gs._C`` (the extension links against it). When the
extension is missing, ops fall back to their readable PyTorch references and one warning
says so.
"""
from __future__ import annotations

import functools
import importlib
import warnings
from types import ModuleType

import torch

BACKENDS = ("auto", "cpp", "reference")


class KernelBoundError(RuntimeError):
    """A compiled kernel refused an input that breaks a bound it is built for (an index outside
    the buffer it indexes, a particle outside the grid block it was sorted into, more entries
    than an int32 list holds). The message names the bound; the kernel wrote nothing out of
    bounds. Raised by ``fracture_gs._C`` (csrc/bound_error.h)."""


@functools.lru_cache(maxsize=None)
def compiled_module() -> ModuleType | None:
    """Return ``fracture_gs._C`` or None (with a single warning) if it cannot be imported."""
    try:
        return importlib.import_module("fracture_gs._C")
    except ImportError as exc:  # pragma: no cover - depends on the build
        warnings.warn(
            f"fracture_gs._C is not built ({exc}); using the slow PyTorch reference kernels. "
            "Build it with `pip install --no-build-isolation -e .`.",
            RuntimeWarning, stacklevel=2)
        return None


def cuda_kernels_available() -> bool:
    """True if the extension was compiled with CUDA kernels."""
    module = compiled_module()
    return module is not None and bool(module.built_with_cuda())


def use_compiled(device: torch.device, backend: str = "auto") -> bool:
    """Decide whether an op on ``device`` runs the compiled kernel (True) or the reference.

    ``backend`` is ``auto`` (compiled when available for that device), ``cpp`` (compiled,
    error if unavailable) or ``reference`` (always the PyTorch twin).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "reference":
        return False
    module = compiled_module()
    available = module is not None and (device.type == "cpu" or
                                        (device.type == "cuda" and cuda_kernels_available()))
    if backend == "cpp" and not available:
        raise RuntimeError(f"compiled kernels are not available for device {device}")
    return available


def active_backends() -> dict[str, bool]:
    """Which implementations are usable in this process."""
    module = compiled_module()
    return {
        "cpu_kernels": module is not None,
        "cuda_kernels": cuda_kernels_available(),
        "cuda_device": torch.cuda.is_available(),
        "reference": True,
    }
