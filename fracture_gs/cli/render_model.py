"""``render.py -m <model>``: the command line of :mod:`fracture_gs.pipeline.render_model`
(a trained static model's views, like 3DGS's render.py; prints the mean PSNR / SSIM of each
split). Exit status 0, or 2 on invalid input (one
``error: ...`` line).
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from fracture_gs.data import DatasetError
from fracture_gs.gaussians import PlyFormatError
from fracture_gs.io.device import DEVICE_CHOICES
from fracture_gs.io.output_folder import os_error_line
from fracture_gs.io.lock import FolderBusy
from fracture_gs.io.manifest import FolderTaken
from fracture_gs.pipeline.render_model import RenderInputError, render_model


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="render.py",
                                     description="Render a trained static model's views.")
    parser.add_argument("-m", "--model_path", required=True, help="train.py output folder")
    parser.add_argument("-s", "--source_path", default=None,
                        help="dataset folder (default: the one in <model>/cfg_args)")
    parser.add_argument("--iteration", type=int, default=-1,
                        help="point_cloud/iteration_N to render (default: the latest)")
    parser.add_argument("--skip_train", action="store_true")
    parser.add_argument("--skip_test", action="store_true")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default="cpu")
    parser.add_argument("--quiet", action="store_true")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``render.py -m``; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        render_model(args.model_path, source_path=args.source_path, iteration=args.iteration,
                     skip_train=args.skip_train, skip_test=args.skip_test, device=args.device,
                     quiet=args.quiet)
    except (RenderInputError, DatasetError, PlyFormatError, FolderBusy, FolderTaken) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # writing into the model folder failed (read-only, disk full, ...)
        print(f"error: {os_error_line(error)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
