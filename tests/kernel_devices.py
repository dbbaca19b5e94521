"""Devices the compiled kernels are tested on: the CPU always, CUDA where a GPU and the CUDA
kernels are both present (``benchmarks/gpu_check.sh`` runs the tests there).

Kernel-vs-twin tests take a ``device`` parameter from :data:`KERNEL_DEVICES`; on CUDA they
compare the CUDA kernel with the CPU kernel's result (the reference) as well as with the twin.
Without a GPU the CUDA case is reported as skipped, with the reason.
"""
from __future__ import annotations

import pytest
import torch

from fracture_gs._backend import cuda_kernels_available


def cuda_kernels_runnable() -> bool:
    """A CUDA device is visible and the extension was built with CUDA kernels."""
    return torch.cuda.is_available() and cuda_kernels_available()


KERNEL_DEVICES = [
    pytest.param("cpu", id="cpu"),
    pytest.param("cuda", id="cuda", marks=pytest.mark.skipif(
        not cuda_kernels_runnable(), reason="no CUDA device, or the extension was built without CUDA kernels")),
]
