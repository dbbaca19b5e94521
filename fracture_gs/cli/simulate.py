"""``simulate.py``: the command line of the simulate stage (:mod:`fracture_gs.pipeline.simulate`;
the formulas: docs/formulas.md §2–§10).

Exit status: 0 on success, 2 on invalid input (one ``error: <key path or file>: <problem>``
line on stderr, nothing simulated: bad scene keys or numbers out of their range, unreadable
files, a grid too large for the memory, a scene that would take more than 1e8 substeps, an
``--out`` that is a file or holds files the tools did not write there, the scene file's own
folder, a damaged run for ``--resume``), 1 when the run fails
(blow-up, out of memory, a write error; the frames written so far stay valid and
``--resume``-able), 130 when interrupted.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from fracture_gs import bounds
from fracture_gs._backend import KernelBoundError
from fracture_gs.config.scene import SceneError, load_scene
from fracture_gs.folders.sim_reader import OutputError
from fracture_gs.io.device import DEVICE_CHOICES, DeviceError, resolve_device
from fracture_gs.io.lock import FolderBusy
from fracture_gs.io.manifest import FolderTaken
from fracture_gs.io.output_folder import os_error_line
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.mpm.types import SimulationBlowUp
from fracture_gs.pipeline.simulate import InvalidInput, run_simulation

DEFAULT_OUTPUT_ROOT = Path("output") / "sims"


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="simulate.py", description="Run a Collision-MPM fracture simulation of a scene.")
    parser.add_argument("--scene", required=True, help="scene YAML (docs/scenes.md)")
    parser.add_argument("--out", default=None,
                        help="output folder (default: output/sims/<scene name>)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames after frame 0 (overrides the scene)")
    parser.add_argument("--device", choices=DEVICE_CHOICES, default=None,
                        help="default: cuda when available, else cpu")
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto",
                        help="compiled kernels (cpp), PyTorch reference, or auto")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in the output folder from its last frame")
    return parser.parse_args(argv)


def _interrupted_message(out_dir: Path | None) -> str:
    if out_dir is not None and SimLayout(out_dir).checkpoint_path.exists():
        return (f"interrupted; the frames written so far in {out_dir} are valid, continue "
                "with --resume")
    return "interrupted before the first frame was written"


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args = parse_args(argv)
    out_dir: Path | None = Path(args.out) if args.out else None
    try:
        if args.frames is not None and args.frames < 1:
            raise InvalidInput("--frames", f"{args.frames} is not >= 1")
        if args.frames is not None and args.frames > bounds.FRAMES_MAX:
            raise InvalidInput("--frames", f"{args.frames} is not <= {bounds.FRAMES_MAX}")
        config = load_scene(args.scene)
        if args.frames is not None:
            config = replace(config, frames=args.frames)
        device = resolve_device(args.device)
        out_dir = out_dir if out_dir is not None else DEFAULT_OUTPUT_ROOT / config.name
        run_simulation(config, out_dir, device=device, backend=args.backend,
                       resume=args.resume)
    except (SceneError, InvalidInput, OutputError, DeviceError, FolderBusy, FolderTaken) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (SimulationBlowUp, KernelBoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (MemoryError, torch.OutOfMemoryError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else "no memory left"
        print(f"error: out of memory ({reason}); use a coarser domain.grid or fewer particles",
              file=sys.stderr)
        return 1
    except OSError as exc:  # writing the output failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(_interrupted_message(out_dir), file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
