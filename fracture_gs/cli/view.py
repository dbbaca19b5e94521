"""``view.py``: look at a simulation (or a trained model) in the browser.

``python view.py output/sims/<name>`` serves the simulation's frames as Gaussian splats on
``http://127.0.0.1:8080`` (``--host``, ``--port``); ``python view.py -m output/<model>`` shows a
trained model. Frames are prepared with the renderer's own code (the same Gaussians and FPGO as
``render.py``). Open the printed address in a browser.

The viewer runs until Ctrl-C, or until the last browser tab has been closed for ``--grace``
seconds (default 10; a reload is fine) unless ``--keep-alive``.

Exit status: 0 when it ended normally (Ctrl-C or browser gone), 130 on Ctrl-C before it
served, 2 on invalid input (one
``error: ...`` line naming the folder, file or option — the same checks as ``render.py`` — or
a port that is taken).
"""
from __future__ import annotations

import argparse
import importlib.util
import signal
import sys
import threading
from collections.abc import Sequence

from fracture_gs import bounds
from fracture_gs.cli.render import InvalidInput
from fracture_gs.folders.sim_reader import SimulationError
from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.io.device import DEVICE_CHOICES, DeviceError, resolve_device
from fracture_gs.io.model_layout import ModelError


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="view.py", description="Interactive browser viewer (viser) of a simulation folder "
        "or, with -m, of a trained model.")
    parser.add_argument("sim", nargs="?", default=None,
                        help="simulation folder (output/sims/<name>)")
    parser.add_argument("-m", "--model", default=None, help="trained model folder instead")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default 127.0.0.1; 0.0.0.0 for all)")
    parser.add_argument("--port", type=int, default=8080, help="port (default 8080; 0: any free)")
    parser.add_argument("--keep-alive", action="store_true",
                        help="keep serving after the last browser tab has gone")
    parser.add_argument("--grace", type=float, default=10.0,
                        help="seconds without a browser before the viewer exits (default 10)")
    parser.add_argument("--fps", type=float, default=10.0, help="initial playback speed in "
                        f"frames per second, {bounds.FPS[0]:g} to {bounds.FPS[1]:g} (default 10)")
    parser.add_argument("--frame", type=int, default=None, help="frame shown first")
    parser.add_argument("--no-fpgo", dest="fpgo", action="store_false",
                        help="start with FPGO off (the GUI toggles it)")
    parser.add_argument("--cache-frames", type=int, default=32,
                        help="prepared frames kept in memory (default 32)")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=None,
                        help="where frames are prepared (default: cuda when available)")
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto",
                        help="compiled kernels (cpp), PyTorch reference, or auto")
    return parser.parse_args(argv)


def _checked(args: argparse.Namespace) -> None:
    if (args.sim is None) == (args.model is None):
        raise InvalidInput("give a simulation folder or -m <model folder> (exactly one)")
    if not 0 <= args.port <= 65535:
        raise InvalidInput(f"--port {args.port}: must be 0..65535")
    if not args.grace >= 0:
        raise InvalidInput(f"--grace {args.grace}: must be >= 0")
    if not bounds.FPS[0] <= args.fps <= bounds.FPS[1]:
        raise InvalidInput(f"--fps {args.fps:g}: must be within [{bounds.FPS[0]:g}, {bounds.FPS[1]:g}]")
    if args.cache_frames < 1:
        raise InvalidInput(f"--cache-frames {args.cache_frames}: must be >= 1")
    if importlib.util.find_spec("viser") is None:
        raise InvalidInput("the viewer needs viser: pip install -e .[viewer]")


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = parse_args(argv)
    from fracture_gs.viewer.app import PortInUseError, Viewer, ViewerOptions, check_port_free
    from fracture_gs.viewer.sources import ModelSource, SimulationSource

    try:
        _checked(args)
        check_port_free(args.host, args.port)   # before loading: a taken port fails at once
        device = resolve_device(args.device)
        if args.model is not None:
            source = ModelSource(args.model, device)
            what = f"model {args.model}"
        else:
            source = SimulationSource(args.sim, device, FPGOSettings(), args.backend)
            what = f"simulation {args.sim}"
        if args.frame is not None and args.frame not in source.frames:
            raise InvalidInput(f"--frame {args.frame}: not a frame of the run "
                               f"({source.frames[0]}..{source.frames[-1]})")
        viewer = Viewer(source, ViewerOptions(
            host=args.host, port=args.port, keep_alive=args.keep_alive, grace_seconds=args.grace,
            play_fps=args.fps, cache_frames=args.cache_frames, fpgo=args.fpgo,
            start_frame=args.frame))
        url = viewer.start()
    except (SimulationError, ModelError, InvalidInput, PortInUseError, DeviceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted while loading", file=sys.stderr)
        return 130
    interrupted = threading.Event()

    def on_sigint(_signum: int, _frame: object) -> None:
        # Ctrl-C asks the viewer to stop instead of raising wherever the main thread happens to
        # be; a second Ctrl-C while it stops ends the process the default way.
        interrupted.set()
        viewer.stop_requested.set()
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        policy = "Ctrl-C to stop" + ("" if args.keep_alive else
                                     f"; exits {args.grace:g} s after the last browser tab closes")
        print(f"viewer: {url}  ({what}: {len(source.frames)} frame(s), "
              f"{len(source.object_names)} object(s)); {policy}", flush=True)
        reason = viewer.run()
    finally:
        signal.signal(signal.SIGINT, previous)
    print(f"viewer stopped ({'interrupted' if interrupted.is_set() else reason})", flush=True)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
