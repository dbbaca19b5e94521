"""Metric speed (docs/formulas.md §14): LPIPS (AlexNet) ms per image pair, FID-Inception ms per image, and the
FID distance itself from N reference / M compared images.

Images are random smooth pictures of ``--size``² (default 400, the dataset resolution), fed
in batches of ``--batch`` as the protocol does. Reports median wall ms and process CPU ms (all
threads) over ``--repeats`` runs after one warm-up. ``--torchmetrics-compute`` also times
torchmetrics' own FID formula (eigvals of a 2048² matrix: minutes on a 2-core CPU).
Prints one JSON object.

Usage: PYTHONPATH=. python benchmarks/bench_metrics.py [--device cpu|cuda] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import torch
import torch.nn.functional as F
from torchmetrics.image.fid import FrechetInceptionDistance

from fracture_gs.metrics.fid import InceptionFeatures, frechet_distance_from_features, image_features
from fracture_gs.metrics.lpips_alex import LpipsAlex


def smooth_images(count: int, size: int, seed: int) -> torch.Tensor:
    """(count, size, size, 3) in [0, 1]: upsampled random 8×8 colour fields."""
    generator = torch.Generator().manual_seed(seed)
    coarse = torch.rand(count, 3, 8, 8, generator=generator)
    return F.interpolate(coarse, size=(size, size), mode="bilinear", align_corners=False).permute(0, 2, 3, 1)


def time_ms(fn, repeats: int) -> tuple[float, float]:
    """Median wall-clock ms and median process CPU ms of fn() after one warm-up call."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        wall.append((time.perf_counter() - start) * 1e3)
        cpu.append((time.process_time() - start_cpu) * 1e3)
    return statistics.median(wall), statistics.median(cpu)


def filled_fid(inception: InceptionFeatures, reference: torch.Tensor, compared: torch.Tensor,
               device: torch.device) -> FrechetInceptionDistance:
    """torchmetrics' FID metric with the features of both sets already accumulated."""
    metric = FrechetInceptionDistance(feature=inception, normalize=True).to(device)
    with torch.no_grad():
        metric.update(reference.permute(0, 3, 1, 2).to(device), real=True)
        metric.update(compared.permute(0, 3, 1, 2).to(device), real=False)
    return metric


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--size", type=int, default=400)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--fid-sets", type=int, nargs=2, default=(8, 40), metavar=("N_REF", "N_CMP"),
                        help="set sizes for the FID distance timing (default: 8 views, 5 frames each)")
    parser.add_argument("--torchmetrics-compute", action="store_true")
    args = parser.parse_args()
    device = torch.device(args.device)

    result = {"device": str(device), "threads": torch.get_num_threads(), "cpus": os.cpu_count(),
              "image_size": args.size, "batch": args.batch, "repeats": args.repeats}

    lpips = LpipsAlex.load(device)
    first, second = smooth_images(args.batch, args.size, 0), smooth_images(args.batch, args.size, 1)
    wall, cpu = time_ms(lambda: lpips.distance(first, second, args.batch), args.repeats)
    result["lpips_ms_per_pair"] = wall / args.batch
    result["lpips_cpu_ms_per_pair"] = cpu / args.batch

    inception = InceptionFeatures.load(device)
    batch = first.permute(0, 3, 1, 2).to(device)

    def features() -> None:
        with torch.no_grad():
            inception(batch)

    wall, cpu = time_ms(features, args.repeats)
    result["fid_features_ms_per_image"] = wall / args.batch
    result["fid_features_cpu_ms_per_image"] = cpu / args.batch

    n_reference, n_compared = args.fid_sets
    reference, compared = smooth_images(n_reference, 64, 2), smooth_images(n_compared, 64, 3)
    reference_rows = image_features(inception, reference, device, args.batch)
    compared_rows = image_features(inception, compared, device, args.batch)
    result["fid_sets"] = [n_reference, n_compared]
    result["fid_value"] = frechet_distance_from_features(reference_rows, compared_rows)
    result["fid_compute_ms"] = time_ms(
        lambda: frechet_distance_from_features(reference_rows, compared_rows), args.repeats)[0]
    if args.torchmetrics_compute:
        theirs = filled_fid(inception, reference, compared, device)
        start = time.perf_counter()
        # the class method: Metric.compute on the instance caches its result
        result["torchmetrics_fid_value"] = float(FrechetInceptionDistance.compute(theirs))
        result["torchmetrics_fid_compute_ms"] = (time.perf_counter() - start) * 1e3
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
