"""Per-particle cost of the compiled constitutive update and 3x3 SVD, single-threaded (prints JSON).

Workloads: F = I + 0.05 randn (near identity, what MPM sees most) and F = R1 diag(exp s) R2ᵀ
with log-stretches of spread 0.03 and 0.3, for a NACC material (alpha = alpha0 < 0, so p0 uses
sinh) and an elastic one. Best of ``--repeats`` timings.

``--baseline PATH`` also times another build of the extension (e.g. a copy of the ``_C*.so``
built from an older commit) in the same run, so that old and new are compared under the same
machine load:

    OMP_NUM_THREADS=1 PYTHONPATH=$PWD python benchmarks/bench_constitutive.py \
        --baseline /tmp/old/_C.cpython-311-x86_64-linux-gnu.so
"""
from __future__ import annotations

import argparse
import importlib.machinery
import importlib.util
import json
import math
import os
import time
from types import ModuleType
from typing import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402  (after OMP_NUM_THREADS)

from fracture_gs.materials import ElasticMaterial, MaterialTable, NACCMaterial  # noqa: E402


def load_extension(path: str) -> ModuleType:
    """Import a built ``_C`` extension from an explicit file path (for the baseline)."""
    if not os.path.isfile(path):
        raise ValueError(f"--baseline: no such file {path!r}")
    loader = importlib.machinery.ExtensionFileLoader("_C", path)
    spec = importlib.util.spec_from_loader("_C", loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def random_rotations(n: int, generator: torch.Generator) -> torch.Tensor:
    """Random proper rotations (N,3,3), float64."""
    q, r = torch.linalg.qr(torch.randn(n, 3, 3, generator=generator, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1)).unsqueeze(-2)
    q[torch.linalg.det(q) < 0, :, 2] *= -1
    return q


def workloads(n: int, seed: int) -> dict[str, torch.Tensor]:
    """Named batches of float32 deformation gradients (N,3,3)."""
    generator = torch.Generator().manual_seed(seed)
    batches = {"identity+0.05randn": torch.eye(3, dtype=torch.float64)
               + 0.05 * torch.randn(n, 3, 3, generator=generator, dtype=torch.float64)}
    for spread in (0.03, 0.3):
        stretch = spread * (torch.randn(n, 3, generator=generator, dtype=torch.float64)
                            + torch.randn(n, 1, generator=generator, dtype=torch.float64))
        rotation_left, rotation_right = random_rotations(n, generator), random_rotations(n, generator)
        batches[f"stretch_spread_{spread}"] = (rotation_left * torch.exp(stretch).unsqueeze(-2)) @ rotation_right.mT
    return {name: batch.float().contiguous() for name, batch in batches.items()}


def best_time_ns(function: Callable[[], object], count: int, repeats: int) -> float:
    """Best wall time of ``function`` over ``repeats`` runs, in ns per item."""
    function()  # warm-up
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best / count * 1e9


def time_module(module: ModuleType, batches: dict[str, torch.Tensor], repeats: int) -> dict[str, dict[str, float]]:
    """ns per particle of svd3_batch and constitutive_update (NACC and elastic) on each batch."""
    nacc = NACCMaterial(E=1.5e4, nu=0.39, density=1.0, alpha0=-0.05, beta=0.5, xi=1.0, M=2.36)
    elastic = ElasticMaterial(E=1.0e4, nu=0.3, density=1.0)
    table = MaterialTable([nacc, elastic]).table()
    results: dict[str, dict[str, float]] = {}
    for name, F in batches.items():
        n = F.shape[0]
        alpha = torch.full((n,), nacc.alpha0)
        nacc_ids = torch.zeros(n, dtype=torch.int32)
        elastic_ids = torch.ones(n, dtype=torch.int32)
        results[name] = {
            "svd3_ns": best_time_ns(lambda: module.svd3_batch(F), n, repeats),
            "nacc_update_ns": best_time_ns(lambda: module.constitutive_update(F, alpha, table, nacc_ids), n, repeats),
            "elastic_update_ns": best_time_ns(
                lambda: module.constitutive_update(F, alpha, table, elastic_ids), n, repeats),
        }
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=50000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline", type=str, default=None,
                        help="path of another _C*.so to time in the same run")
    args = parser.parse_args()
    if args.particles <= 0 or args.repeats <= 0:
        raise ValueError("--particles and --repeats must be positive")
    torch.set_num_threads(1)
    from fracture_gs._backend import compiled_module

    current = compiled_module()
    if current is None:
        raise RuntimeError("fracture_gs._C is not built")
    batches = workloads(args.particles, seed=0)
    report: dict[str, object] = {"threads": 1, "particles": args.particles, "repeats": args.repeats,
                                 "current": time_module(current, batches, args.repeats)}
    if args.baseline:
        report["baseline"] = time_module(load_extension(args.baseline), batches, args.repeats)
        report["speedup"] = {
            name: {key: report["baseline"][name][key] / value for key, value in timings.items()}
            for name, timings in report["current"].items()}
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
