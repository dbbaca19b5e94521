"""``python -m fracture_gs.info``: versions and which kernel backends are active."""
from __future__ import annotations

import json
import platform
import sys

import numpy as np
import torch

from fracture_gs import __version__
from fracture_gs._backend import active_backends, compiled_module


def collect() -> dict:
    """Versions of the toolkit and its main dependencies plus the usable backends."""
    module = compiled_module()
    return {
        "fracture_gs": __version__,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "torch": torch.__version__,
        "torch_cuda_build": torch.version.cuda,
        "numpy": np.__version__,
        "openmp_threads": int(module.openmp_max_threads()) if module is not None else None,
        "backends": active_backends(),
    }


def main() -> None:
    print(json.dumps(collect(), indent=2))


if __name__ == "__main__":
    main()
