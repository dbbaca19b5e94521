"""``train.py``: the command line of the train stage (:mod:`fracture_gs.pipeline.train`):
reconstruct an object from posed, masked images (docs/training.md).

Exit status: 0 on success, 2 on invalid input (one ``error: ...`` line on stderr naming the
file or flag, nothing left half-written in the model folder), 1 when a write fails (a full disk;
the line names the file), 130 when interrupted (the last checkpoint stays usable with
``--start_checkpoint``).
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Sequence

from fracture_gs.io.device import DEVICE_CHOICES
from fracture_gs.io.output_folder import os_error_line
from fracture_gs.pipeline.train import TRAIN_INPUT_ERRORS, train_model
from fracture_gs.recon.pipeline import PRESETS, TrainConfig

PRESET_KEYS = ("resolution", "iterations", "sdf_res", "sdf_iters", "n_surface", "nv",
               "particle_res", "n_interior", "feature_lr", "opacity_lr", "scaling_lr")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="train.py",
        description="Reconstruct an object from multi-view images: visual hull, NeuS-style "
                    "SDF refinement, mesh, surface + interior particles, isotropic Gaussians.")
    parser.add_argument("-s", "--source_path", required=True,
                        help="dataset folder (Blender/NeRF-synthetic, COLMAP or DTU)")
    parser.add_argument("-m", "--model_path", default=None,
                        help="output folder (default: output/<dataset folder name>)")
    parser.add_argument("-r", "--resolution", type=int, default=None,
                        help="image downscale factor 1|2|4|8, or -1 (width <= 1600)")
    parser.add_argument("-w", "--white_background", action="store_true",
                        help="composite transparent pixels on white (default black)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="default",
                        help="default: sized for a 2-core CPU; paper: the paper's sizes "
                             "(200k surface, 100k interior particles, full resolution)")
    parser.add_argument("--iterations", type=int, default=None,
                        help=f"Gaussian fitting iterations (default {PRESETS['default']['iterations']})")
    parser.add_argument("--sdf-res", type=int, default=None,
                        help="SDF grid cells along the longest side (default 160; paper preset 256)")
    parser.add_argument("--sdf-iters", type=int, default=None,
                        help="NeuS-style SDF refinement iterations after the stereo carving; "
                             "0 keeps the visual hull (no carving either) (default 300)")
    parser.add_argument("--n-surface", type=int, default=None,
                        help="surface particles = Gaussians (default 40000; paper 200000)")
    parser.add_argument("--nv", type=int, default=None,
                        help="interior samples per interior voxel (default 8; 0 = surface only)")
    parser.add_argument("--particle-res", type=int, default=None,
                        help="interior voxels along the longest side (default 48)")
    parser.add_argument("--n-interior", type=int, default=None,
                        help="choose the interior voxel size for about this many interior "
                             "particles (overrides --particle-res; paper preset 100000)")
    parser.add_argument("--shell", type=float, default=0.0,
                        help="sample a hollow body: interior particles only within this wall "
                             "thickness of the surface, as a share of the longest side (a teapot, a "
                             "vase: 0.06; default 0 = solid)")
    parser.add_argument("--holdout-every", type=int, default=0, metavar="N",
                        help="COLMAP / DTU folders: hold out every N-th view (views 0, N, 2N, "
                             "...) as the test split that render.py -m and evaluate.py -m use "
                             "(3DGS's --eval uses 8; default 0 = train on every view)")
    parser.add_argument("--up", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                        help="the object's up direction in dataset coordinates, recorded in "
                             "object.json for placing it in scenes (default: estimated from the "
                             "cameras, which photographers hold level)")
    parser.add_argument("--keep-underside", action="store_true",
                        help="keep the part of the geometry below the lowest point any camera "
                             "sees (default: cut it flat there, where the object stood on its "
                             "support; only objects photographed from above have one)")
    parser.add_argument("--parts", default=None,
                        help="part spec JSON (default: the dataset's parts.json, else one part)")
    parser.add_argument("--sh-degree", type=int, default=3, help="SH degree 0..3 (default 3)")
    parser.add_argument("--max-offset", type=float, default=1.0,
                        help="largest Gaussian/particle move from the mesh, in particle "
                             "spacings (default 1: the Gaussians settle about one spacing "
                             "inside, so their footprint ends at the silhouette; 0 = fixed)")
    parser.add_argument("--min-component", type=float, default=0.005,
                        help="drop mesh components with fewer faces than this fraction of the "
                             "largest (default 0.005)")
    parser.add_argument("--from-ply", default=None,
                        help="import a trained 3DGS point_cloud.ply instead of fitting Gaussians")
    parser.add_argument("--from-sdf", default=None,
                        help="reuse the sdf.npz of an earlier run (skips the visual hull, "
                             "carving and SDF refinement; e.g. to refit the Gaussians)")
    parser.add_argument("--bbox", type=float, nargs=6, default=None,
                        metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                        help="object box for the opacity-field SDF (--from-ply without masks)")
    parser.add_argument("--start_checkpoint", default=None,
                        help="continue from a chkpnt<N>.pth of an interrupted run")
    parser.add_argument("--checkpoint_every", type=int, default=1000,
                        help="write chkpnt<N>.pth every N Gaussian iterations (newest kept; "
                             "0 = never)")
    parser.add_argument("--save_iterations", type=int, nargs="*", default=[],
                        help="extra iterations at which point_cloud/iteration_N is written")
    for flag, what in (("feature_lr", "SH colour (the higher degrees get 1/20)"),
                       ("opacity_lr", "opacity logit"), ("scaling_lr", "log-scale")):
        parser.add_argument(f"--{flag}", type=float, default=None,
                            help=f"Adam learning rate of the {what} (default {PRESETS['default'][flag]}; "
                                 f"3DGS and --preset paper {PRESETS['paper'][flag]})")
    parser.add_argument("--sdf-rays", type=int, default=1024,
                        help="rays per SDF refinement iteration (default 1024)")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default="cpu")
    parser.add_argument("--seed", type=int, default=0, help="0 to 2^64 - 1 (default 0)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """Apply the preset to every size option the user did not give."""
    preset = PRESETS[args.preset]
    sizes = {key: getattr(args, key) if getattr(args, key) is not None else preset[key]
             for key in PRESET_KEYS}
    source = args.source_path
    model_path = args.model_path
    if model_path is None:
        if args.start_checkpoint is not None:
            model_path = os.path.dirname(os.path.abspath(args.start_checkpoint))
        else:
            model_path = os.path.join("output", os.path.basename(os.path.normpath(source)))
    return TrainConfig(source_path=source, model_path=model_path,
                       white_background=args.white_background, parts=args.parts,
                       sh_degree=args.sh_degree, shell=args.shell, device=args.device, seed=args.seed,
                       holdout_every=args.holdout_every, keep_underside=args.keep_underside,
                       up=list(args.up) if args.up is not None else None,
                       preset=args.preset, min_component=args.min_component,
                       max_offset=args.max_offset, from_ply=args.from_ply,
                       from_sdf=args.from_sdf,
                       bbox=list(args.bbox) if args.bbox is not None else None,
                       start_checkpoint=args.start_checkpoint,
                       checkpoint_every=args.checkpoint_every,
                       save_iterations=list(args.save_iterations), sdf_rays=args.sdf_rays,
                       quiet=args.quiet, **sizes)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        train_model(config_from_args(args))
    except TRAIN_INPUT_ERRORS as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # writing the model failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(error)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; continue with --start_checkpoint <model>/chkpnt<N>.pth if the "
              "Gaussian stage had written one", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
