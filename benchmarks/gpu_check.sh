#!/usr/bin/env bash
# GPU check: build the CUDA kernels, run every kernel-vs-twin test on the GPU
# (MPM ops, constitutive update, rasterizer forward + backward; the CPU kernel's result is the
# reference there), then bench_mpm.py and bench_raster.py with --device cuda. Prints everything and
# keeps a copy in $GPU_CHECK_OUT (default /tmp/fracture_gs_gpu_check). Meant to finish in under
# 10 minutes on one GPU machine; the CUDA build is most of it.
#
#   bash benchmarks/gpu_check.sh                 # from the repository root, on a machine with a GPU
#   bash benchmarks/gpu_check.sh --skip-build    # the extension is already built with CUDA
#   bash benchmarks/gpu_check.sh --dry-run-cpu   # the same steps on the CPU (small sizes): checks the script
#
# Exit status: 0 when every step passed, 1 otherwise (no GPU, no CUDA kernels, a failed or
# skipped CUDA test, a benchmark error or a step over its time limit).
set -uo pipefail
cd "$(dirname "$0")/.."

mode=${1:-}
device=cuda
if [[ "$mode" == "--dry-run-cpu" ]]; then
  device=cpu
fi
out=${GPU_CHECK_OUT:-/tmp/fracture_gs_gpu_check}
mkdir -p "$out"
status=0
started=$(date +%s)

step() {  # step NAME SECONDS COMMAND...: run with a time limit, show and keep the output
  local name=$1 limit=$2
  shift 2
  echo "=== $name (limit ${limit}s) ==="
  timeout "$limit" "$@" 2>&1 | tee "$out/$name.txt"
  local rc=${PIPESTATUS[0]}
  if [[ $rc -ne 0 ]]; then
    echo "=== $name FAILED (exit $rc$([[ $rc -eq 124 ]] && echo ', time limit')) ==="
    status=1
  fi
  return "$rc"
}

if [[ "$device" == cuda && "$mode" != "--skip-build" ]]; then
  unset FRACTURE_GS_NO_CUDA
  step build 330 env MAX_JOBS="${MAX_JOBS:-$(nproc)}" python setup.py -q build_ext --inplace || exit 1
fi

step environment 60 python - "$device" <<'EOF' || exit 1
import sys
import torch
from fracture_gs import _backend
device = sys.argv[1]
print(f"torch {torch.__version__}, CUDA runtime {torch.version.cuda}, device available: {torch.cuda.is_available()}")
print(f"extension: {_backend.compiled_module() is not None}, CUDA kernels: {_backend.cuda_kernels_available()}")
if device == "cuda":
    if not (torch.cuda.is_available() and _backend.cuda_kernels_available()):
        sys.exit("gpu_check: no CUDA device, or fracture_gs._C was built without CUDA kernels")
    print(torch.cuda.get_device_name(0))
EOF

# The kernel-vs-twin tests of the chosen device (cpu in the dry run); on a GPU a skipped CUDA
# test is a failure.
step tests 150 python -m pytest -q -rs -p no:cacheprovider -k "$device" \
  tests/test_mpm_kernels.py tests/test_materials.py tests/test_raster.py
if [[ "$device" == cuda ]] && grep -q "skipped" "$out/tests.txt"; then
  echo "=== tests: CUDA tests were skipped ==="
  status=1
fi

if [[ "$device" == cuda ]]; then
  step bench_mpm 90 python benchmarks/bench_mpm.py --device cuda --particles 50000 200000
  step bench_raster 60 python benchmarks/bench_raster.py --device cuda
else
  step bench_mpm 300 python benchmarks/bench_mpm.py --device cpu --grid 32 --particles 2000 --steps 3 \
    --repeats 1 --reference-steps 1
  step bench_raster 300 python benchmarks/bench_raster.py --device cpu --size 64 --skip-1m --repeats 1 \
    --reference-num 100 --reference-size 16
fi

verdict=$([[ $status -eq 0 ]] && echo passed || echo FAILED)
echo "=== gpu_check: device $device, $(( $(date +%s) - started )) s, $verdict ==="
exit $status
