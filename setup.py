"""Build script for fracture_gs and its compiled extension ``fracture_gs._C``.

The C++ CPU kernels (OpenMP) are always built. CUDA kernels are added when the CUDA
toolkit (nvcc) and a CUDA build of torch are both present; set ``FRACTURE_GS_NO_CUDA=1``
to skip them. ``FRACTURE_GS_SANITIZE=address`` builds the C++ kernels with AddressSanitizer
(docs/design_mpm.md, Memory safety). Install with ``pip install --no-build-isolation -e .`` so the build uses the
torch that is already installed (build isolation would fetch a different one).
"""
from __future__ import annotations

import glob
import os
import sys

from setuptools import find_packages, setup

# torch guesses /usr/local as CUDA_HOME when nvcc is not on PATH; prefer the standard place.
if "CUDA_HOME" not in os.environ and os.path.exists("/usr/local/cuda/bin/nvcc"):
    os.environ["CUDA_HOME"] = "/usr/local/cuda"
# Without a GPU torch would otherwise build for every architecture it knows.
os.environ.setdefault("TORCH_CUDA_ARCH_LIST", "8.0;9.0")

import torch  # noqa: E402  (needs the environment above)
from torch.utils import cpp_extension  # noqa: E402

ROOT = os.path.dirname(os.path.abspath(__file__))
# Optional parts (``pip install -e .[viewer,video]``; install.sh installs them). Read by
# install.sh too, so keep this a literal.
EXTRAS = {
    "test": ["pytest"],
    "synthetic": ["mitsuba==3.9.1"],      # also in requirements.txt: the demo and CI use it
    "viewer": ["viser>=1.1", "selenium>=4.51"],   # interactive viewer; selenium screenshots it
    "video": ["imageio-ffmpeg>=0.8"],     # mp4 writing without a system ffmpeg
    "ray": ["ray>=2.9"],                  # evaluate.py --experiment ... --ray ADDRESS (sweeps on a cluster)
}


def _want_cuda() -> bool:
    if os.environ.get("FRACTURE_GS_NO_CUDA", "0") not in ("", "0"):
        return False
    return torch.version.cuda is not None and cpp_extension.CUDA_HOME is not None


def _sanitizer() -> str | None:
    """``FRACTURE_GS_SANITIZE=address``: the C++ kernels built with AddressSanitizer (a check
    build; python then needs ``LD_PRELOAD=$(gcc -print-file-name=libasan.so)``)."""
    name = os.environ.get("FRACTURE_GS_SANITIZE", "")
    if name in ("", "0"):
        return None
    if name != "address":
        raise SystemExit(f"setup.py: FRACTURE_GS_SANITIZE={name!r}: only 'address' is supported")
    return name


def _cxx_flags() -> list[str]:
    flags = ["-O3", "-fopenmp", "-std=c++20", "-fno-math-errno", "-fno-trapping-math"]
    if os.environ.get("FRACTURE_GS_PORTABLE", "0") in ("", "0") and sys.platform.startswith("linux"):
        flags.append("-march=native")
    if _sanitizer():
        flags += [f"-fsanitize={_sanitizer()}", "-fno-omit-frame-pointer", "-g"]
    return flags


def _link_flags() -> list[str]:
    return ["-fopenmp"] + ([f"-fsanitize={_sanitizer()}"] if _sanitizer() else [])


def _check_object_names(sources: list[str]) -> None:
    """Two sources with the same stem in one folder would compile to the same object file."""
    seen: dict[str, str] = {}
    for source in sources:
        stem = os.path.splitext(source)[0]
        if stem in seen:
            raise SystemExit(f"setup.py: {seen[stem]} and {source} would both build {stem}.o; rename one")
        seen[stem] = source


def _extensions() -> list:
    cpp_sources = sorted(glob.glob(os.path.join("csrc", "**", "*.cpp"), recursive=True))
    include_dirs = [os.path.join(ROOT, "csrc")]
    cxx = _cxx_flags()
    if _want_cuda():
        cu_sources = sorted(glob.glob(os.path.join("csrc", "**", "*.cu"), recursive=True))
        _check_object_names(cpp_sources + cu_sources)
        nvcc = ["-O3", "-std=c++20", "--expt-relaxed-constexpr", "-lineinfo",
                "-gencode=arch=compute_80,code=sm_80", "-gencode=arch=compute_90,code=sm_90"]
        return [cpp_extension.CUDAExtension(
            name="fracture_gs._C", sources=cpp_sources + cu_sources, include_dirs=include_dirs,
            define_macros=[("FGS_WITH_CUDA", "1")],
            extra_compile_args={"cxx": cxx, "nvcc": nvcc}, extra_link_args=_link_flags())]
    return [cpp_extension.CppExtension(
        name="fracture_gs._C", sources=cpp_sources, include_dirs=include_dirs,
        extra_compile_args={"cxx": cxx}, extra_link_args=_link_flags())]


setup(
    name="fracture_gs",
    version="0.1.0",
    description="Multi-view images to physically simulated, photoreal fracturing collisions "
                "(Collision-MPM + Gaussian splatting), on CPU and GPU.",
    packages=find_packages(include=["fracture_gs", "fracture_gs.*"]),
    python_requires=">=3.10",
    install_requires=[
        "torch==2.14.1", "numpy", "trimesh", "pymcubes", "opencv-python-headless", "lpips",
        "torchmetrics", "tqdm", "pyyaml", "scipy", "plyfile", "matplotlib",
    ],
    extras_require=EXTRAS,
    ext_modules=_extensions(),
    cmdclass={"build_ext": cpp_extension.BuildExtension.with_options(use_ninja=True)},
    zip_safe=False,
)
