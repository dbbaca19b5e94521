"""``render.py``: the command line of the render stage.

``render.py --sim output/sims/<name>`` renders a simulation (:mod:`fracture_gs.pipeline.render`:
``<sim>/renders/`` or, with ``--no-fpgo``, ``renders_nofpgo/``, with a ``render.json`` naming the
simulation and whether FPGO was on); ``render.py -m <model>`` renders
a trained model without simulation (handed to ``fracture_gs.cli.render_model``).

Exit status: 0 on success, 2 on invalid input (one ``error: ...`` line naming the folder, file
or option; an output folder that cannot be made, that another render is writing, or that holds a
file in the way that the tools did not write there included), 1 when writing fails later (a full
disk), 130 when interrupted (images written so far stay, videos are not kept).
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from fracture_gs import bounds
from fracture_gs._backend import KernelBoundError
from fracture_gs.folders.sim_reader import SimulationError
from fracture_gs.fracture.fpgo import EXCLUSIVE_RULES, INTERIOR_RULES, FPGOSettings
from fracture_gs.io.device import DEVICE_CHOICES, DeviceError, resolve_device
from fracture_gs.io.lock import FolderBusy
from fracture_gs.io.manifest import FolderTaken
from fracture_gs.io.model_layout import ModelError
from fracture_gs.io.output_folder import OutputFolderError, os_error_line
from fracture_gs.pipeline.background import BACKGROUNDS
from fracture_gs.pipeline.render import RenderOptions, render_simulation
from fracture_gs.render.views import ViewSpecError, check_image_size


class InvalidInput(ValueError):
    """Bad command-line input; the message names the option."""


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="render.py", description="Render a simulation (--sim) or a trained model (-m) "
        "with Gaussian splatting; FPGO fills fracture surfaces.",
        epilog="render.py -m MODEL renders a trained model's train and test views into "
        "MODEL/{train,test}/ours_N/; its options: render.py -m MODEL --help.")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--sim", help="simulation folder (output/sims/<name>)")
    target.add_argument("-m", "--model_path", metavar="MODEL",
                        help="a train.py model folder: render its dataset's train and test views "
                        "(see the note below)")
    parser.add_argument("--views", default="orbit:8",
                        help="orbit:N | train | test | path/to/cameras.json (default orbit:8)")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--fpgo", dest="fpgo", action="store_true", default=True,
                       help="fracture-surface Gaussians (default)")
    group.add_argument("--no-fpgo", dest="fpgo", action="store_false",
                       help="baseline: the particles' original Gaussians only")
    parser.add_argument("--frames", default=None,
                        help="a, a:b (b excluded), a: or :b (default: every frame)")
    parser.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), default=None,
                        help="image size (default 800 800 for orbit views, the cameras' own "
                        "size otherwise)")
    parser.add_argument("--background", choices=BACKGROUNDS, default=None,
                        help="default: the background the scene's trained objects were trained "
                        "on (train.py -w: white, else black); white for primitives")
    parser.add_argument("--export-ply", action="store_true",
                        help="also write ply/frame_XXXXX.ply (3DGS layout) per frame")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=None,
                        help="default: cuda when available, else cpu")
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto",
                        help="compiled kernels (cpp), PyTorch reference, or auto")
    parser.add_argument("--out", default=None,
                        help="output folder (default <sim>/renders or <sim>/renders_nofpgo)")
    parser.add_argument("--fps", type=float, default=30.0,
                        help=f"video frame rate, {bounds.FPS[0]:g} to {bounds.FPS[1]:g} (default 30)")
    parser.add_argument("--preview-view", default=None,
                        help="view of preview.gif (default: the first)")
    defaults = FPGOSettings()
    parser.add_argument("--dc-factor", type=float, default=defaults.dc_factor,
                        help="FPGO neighbour radius d_c in rest particle spacings (default 1.5)")
    parser.add_argument("--k-neighbours", type=int, default=defaults.k_neighbours,
                        help="FPGO intact neighbours per fractured particle (default 2)")
    parser.add_argument("--k-sigma", type=float, default=defaults.k_sigma,
                        help="FPGO sphere radius in Gaussian scales (default 2)")
    parser.add_argument("--min-fragment", type=int, default=defaults.min_fragment,
                        help="FPGO: fragments with fewer particles are not drawn (default 10)")
    parser.add_argument("--exclusive", choices=EXCLUSIVE_RULES, default=defaults.exclusive,
                        help="FPGO lens Gaussians at a pixel: 'group' (default, paper §3.2.2) "
                        "only the nearest of the lenses that replace one fractured particle's "
                        "Gaussian blends; 'all' only the nearest of all lenses (docs/formulas.md §11's "
                        "global rule); 'none' they blend like all others")
    parser.add_argument("--no-exclusive", dest="exclusive", action="store_const", const="none",
                        help="same as --exclusive none")
    add_interior_options(parser)
    return parser.parse_args(argv)


def add_interior_options(parser: argparse.ArgumentParser) -> None:
    """``--interior`` and ``--exposure`` (FPGOSettings.interior / .exposure); the benchmarks
    take the same options."""
    defaults = FPGOSettings()
    parser.add_argument("--interior", choices=INTERIOR_RULES, default=defaults.interior,
                        help="FPGO Gaussians for fractured interior particles: 'exposed' "
                        "(default) only on fracture surfaces, where they kept fewer than "
                        "--exposure of their rest neighbours (paper App. A.6); 'all' every "
                        "fractured one")
    parser.add_argument("--exposure", type=float, default=defaults.exposure,
                        help=f"FPGO exposure test: share of the rest neighbours within d_c "
                        f"below which a particle is on a fracture surface (default "
                        f"{defaults.exposure})")


def options_from_args(args: argparse.Namespace) -> RenderOptions:
    """Checked :class:`RenderOptions` (InvalidInput naming the option)."""
    if args.resolution is not None:
        try:
            check_image_size(*args.resolution, "--resolution")
        except ViewSpecError as exc:
            raise InvalidInput(str(exc)) from None
    if not bounds.FPS[0] <= args.fps <= bounds.FPS[1]:
        raise InvalidInput(f"--fps {args.fps:g}: must be within [{bounds.FPS[0]:g}, {bounds.FPS[1]:g}]")
    try:
        settings = FPGOSettings(dc_factor=args.dc_factor, k_neighbours=args.k_neighbours,
                                k_sigma=args.k_sigma, min_fragment=args.min_fragment,
                                exclusive=args.exclusive, interior=args.interior,
                                exposure=args.exposure)
    except ValueError as exc:
        name = str(exc).split()[0].replace("_", "-")
        raise InvalidInput(f"--{name}: {exc}") from None
    from fracture_gs._backend import use_compiled

    device = resolve_device(args.device)  # DeviceError naming --device
    try:
        use_compiled(device, args.backend)
    except RuntimeError as exc:
        raise InvalidInput(f"--backend: {exc}") from None
    return RenderOptions(
        sim=Path(args.sim), views=args.views, fpgo=args.fpgo, frames=args.frames,
        resolution=tuple(args.resolution) if args.resolution else None,
        background=args.background, export_ply=args.export_ply, device=device,
        out=Path(args.out) if args.out else None, fps=args.fps, preview_view=args.preview_view,
        settings=settings, backend=args.backend)


def _render_model(argv: list[str]) -> int:
    """``render.py -m <model> ...``: static renders of a trained model."""
    if "--sim" in argv or any(a.startswith("--sim=") for a in argv):
        print("error: give either --sim (a simulation) or -m (a trained model), not both",
              file=sys.stderr)
        return 2
    from fracture_gs.cli import render_model

    return int(render_model.main(argv))


def _wants_model(argv: Sequence[str]) -> bool:
    return any(a in ("-m", "--model", "--model_path") or
               a.startswith(("--model=", "--model_path=", "-m=")) or
               (a.startswith("-m") and not a.startswith("--") and len(a) > 2) for a in argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if _wants_model(argv):
        return _render_model(argv)
    args = parse_args(argv)
    try:
        render_simulation(options_from_args(args))
    except (SimulationError, ModelError, ViewSpecError, InvalidInput, OutputFolderError,
            DeviceError, FolderBusy, FolderTaken) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # writing an image or video failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 1
    except KernelBoundError as exc:  # e.g. more Gaussian-tile pairs than the rasterizer counts
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; the images written so far are kept, the videos are not",
              file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
