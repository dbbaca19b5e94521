"""``render.py``: a simulation's frames as Gaussian splats, with FPGO (docs/formulas.md §12–§13).

``render.py --sim output/sims/<name>`` renders every frame from every view into
``<sim>/renders/`` (``renders_nofpgo/`` with ``--no-fpgo``): ``<view>/00000.png``,
``video_<view>.mp4`` (H.264), ``preview.gif`` (one view), ``timing.csv``, ``render.json``
(which simulation, FPGO on or off: :mod:`fracture_gs.render.render_info`) and, with
``--export-ply``, ``ply/frame_00000.ply`` (3DGS layout). ``render.py -m <model>`` renders a
trained model without simulation (handed to ``fracture_gs.cli.render_model``).

Exit status: 0 on success, 2 on invalid input (one ``error: ...`` line naming the folder, file
or option; an output folder that cannot be made included), 1 when writing fails later (a full
disk), 130 when interrupted (images written so far stay, videos are not kept).
"""
from __future__ import annotations

import argparse
import csv
import io
import sys
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np
import torch

from fracture_gs.cli.output_folder import OutputFolderError, os_error_line, prepare_output_folder
from fracture_gs.fracture.fpgo import EXCLUSIVE_RULES, INTERIOR_RULES, FPGOSettings
from fracture_gs.mpm.output import write_text_atomic
from fracture_gs.render.frame_gaussians import FrameGaussians, ModelError, SceneGaussians
from fracture_gs.render.render_info import RenderInfo, write_render_info
from fracture_gs.render.video import Mp4Writer, to_uint8, write_gif, write_png
from fracture_gs.render.views import (View, ViewSpecError, bounds_sphere, cameras_from_json,
                                      check_image_size, dataset_views, orbit_views)
from fracture_gs.sim.folder import Simulation, SimulationError

DEFAULT_ORBIT_SIZE = (800, 800)
TIMING_COLUMNS = ("frame", "gaussians", "fpgo_gaussians", "fractured", "hidden_particles",
                  "buried_particles", "load_wait_ms", "deform_ms", "fpgo_ms", "raster_ms",
                  "raster_ms_per_view", "ply_ms")


class InvalidInput(ValueError):
    """Bad command-line input; the message names the option."""


@dataclass
class RenderOptions:
    """Everything ``render.py --sim`` needs (the parsed command line)."""

    sim: Path
    views: str = "orbit:8"
    fpgo: bool = True
    frames: str | None = None
    resolution: tuple[int, int] | None = None
    background: str = "white"
    export_ply: bool = False
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    out: Path | None = None
    fps: float = 30.0
    preview_view: str | None = None
    settings: FPGOSettings = field(default_factory=FPGOSettings)
    backend: str = "auto"


@dataclass
class RenderSummary:
    """What :func:`render_simulation` did (also printed as its last line)."""

    out_dir: Path
    frames: int
    views: list[str]
    ms_per_frame: float          # deformation + FPGO + rasterization of all views
    fpgo_ms_per_frame: float
    raster_ms_per_frame: float
    wall_seconds: float
    max_gaussians: int
    rows: list[dict[str, float]]


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="render.py", description="Render a simulation (--sim) or a trained model (-m) "
        "with Gaussian splatting; FPGO fills fracture surfaces.")
    parser.add_argument("--sim", required=True, help="simulation folder (output/sims/<name>)")
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
    parser.add_argument("--background", choices=("white", "black"), default="white")
    parser.add_argument("--export-ply", action="store_true",
                        help="also write ply/frame_XXXXX.ply (3DGS layout) per frame")
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None,
                        help="default: cuda when available, else cpu")
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto",
                        help="compiled kernels (cpp), PyTorch reference, or auto")
    parser.add_argument("--out", default=None,
                        help="output folder (default <sim>/renders or <sim>/renders_nofpgo)")
    parser.add_argument("--fps", type=float, default=30.0, help="video frame rate (default 30)")
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


def resolve_device(name: str | None) -> torch.device:
    if name is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InvalidInput("--device: cuda was requested but no CUDA device is available")
    return torch.device(name)


def options_from_args(args: argparse.Namespace) -> RenderOptions:
    """Checked :class:`RenderOptions` (InvalidInput naming the option)."""
    if args.resolution is not None:
        try:
            check_image_size(*args.resolution, "--resolution")
        except ViewSpecError as exc:
            raise InvalidInput(str(exc)) from None
    if not args.fps > 0:
        raise InvalidInput(f"--fps {args.fps}: must be > 0")
    try:
        settings = FPGOSettings(dc_factor=args.dc_factor, k_neighbours=args.k_neighbours,
                                k_sigma=args.k_sigma, min_fragment=args.min_fragment,
                                exclusive=args.exclusive, interior=args.interior,
                                exposure=args.exposure)
    except ValueError as exc:
        name = str(exc).split()[0].replace("_", "-")
        raise InvalidInput(f"--{name}: {exc}") from None
    from fracture_gs._backend import use_compiled

    device = resolve_device(args.device)
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


def resolve_views(spec: str, sim: Simulation, frames: Sequence[int],
                  size: tuple[int, int] | None) -> list[View]:
    """The cameras named by ``--views`` for this simulation (ViewSpecError naming the spec)."""
    if spec.startswith("orbit:"):
        count_text = spec[len("orbit:"):]
        if not count_text.isdigit() or int(count_text) < 1:
            raise ViewSpecError(f"--views {spec}: orbit:N needs a whole number N >= 1")
        points = [sim.particles.rest_x, sim.load_frame(frames[-1]).x.numpy()]
        centre, radius = bounds_sphere(np.concatenate(points))
        gravity = np.asarray(sim.scene.gravity, dtype=np.float64)
        up = -gravity / np.linalg.norm(gravity) if np.linalg.norm(gravity) > 0 else (0, 0, 1)
        width, height = size if size is not None else DEFAULT_ORBIT_SIZE
        return orbit_views(int(count_text), centre, radius, width, height, up=up)
    if spec in ("train", "test"):
        trained = [obj for obj in sim.scene.objects if obj.model is not None and obj.model.is_dir()]
        if not trained:
            raise ViewSpecError(f"--views {spec}: no object of {sim.root / 'scene.yaml'} has a "
                                "trained model folder")
        from fracture_gs.mpm.scene import rotation_matrix_xyz

        obj = trained[0]
        return dataset_views(obj.model, spec, rotation_matrix_xyz(obj.transform.rotate_deg),
                             obj.transform.scale, obj.transform.translate, size)
    path = Path(spec)
    if path.suffix.lower() == ".json" or path.exists():
        return cameras_from_json(path, size)
    raise ViewSpecError(f"--views {spec}: unknown view spec (orbit:N, train, test or a "
                        "cameras.json)")


def _timing_csv(rows: list[dict[str, float]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=TIMING_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.3f}" if isinstance(v, float) else v) for k, v in row.items()})
    return buffer.getvalue()


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _render_views(gaussians: FrameGaussians, views: list[View], background: torch.Tensor,
                  backend: str, device: torch.device) -> tuple[list[np.ndarray], float]:
    started = time.perf_counter()
    images = [to_uint8(gaussians.rasterize(view.camera, background, backend)["rgb"])
              for view in views]
    _synchronize(device)
    return images, (time.perf_counter() - started) * 1e3


def render_simulation(options: RenderOptions, log: TextIO | None = None,
                      progress: bool | None = None) -> RenderSummary:
    """Render ``options.sim`` (see the module docstring); raises SimulationError, ModelError or
    ViewSpecError for bad input before anything is written."""
    from tqdm import tqdm

    log = log if log is not None else sys.stdout
    started = time.perf_counter()
    sim = Simulation.open(options.sim)
    frames = sim.select_frames(options.frames)
    views = resolve_views(options.views, sim, frames, options.resolution)
    names = [view.name for view in views]
    preview = options.preview_view if options.preview_view is not None else names[0]
    if preview not in names:
        raise ViewSpecError(f"--preview-view {preview}: not one of the views "
                            f"({', '.join(names[:8])}{', ...' if len(names) > 8 else ''})")
    out_dir = prepare_output_folder(  # checked now, made once the model files have loaded
        options.out or sim.root / ("renders" if options.fpgo else "renders_nofpgo"), "--out",
        keep=False)
    scene = SceneGaussians.from_simulation(sim, options.device, options.settings)
    device = options.device
    views = [View(view.name, view.camera.to(device)) for view in views]
    background = torch.full((3,), 1.0 if options.background == "white" else 0.0, device=device)
    for name in names:
        (out_dir / name).mkdir(parents=True, exist_ok=True)
    write_render_info(out_dir, RenderInfo.of(sim, options.fpgo))
    if options.export_ply:
        (out_dir / "ply").mkdir(parents=True, exist_ok=True)

    videos = {view.name: Mp4Writer(out_dir / f"video_{view.name}.mp4", view.camera.width,
                                   view.camera.height, options.fps) for view in views}
    preview_frames: list[np.ndarray] = []
    rows: list[dict[str, float]] = []
    loader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-loader")
    writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="png-writer")
    writes: list[Future] = []
    bar = tqdm(total=len(frames), unit="frame", desc=f"render {sim.scene.name}",
               disable=None if progress is None else not progress, dynamic_ncols=True)
    completed = False
    try:
        upcoming = loader.submit(sim.load_frame, frames[0], device)
        for position, frame_index in enumerate(frames):
            tick = time.perf_counter()
            frame = upcoming.result()
            load_wait = (time.perf_counter() - tick) * 1e3
            if position + 1 < len(frames):  # load the next frame while this one renders
                upcoming = loader.submit(sim.load_frame, frames[position + 1], device)
            tick = time.perf_counter()
            gaussians = scene.frame(frame, fpgo=options.fpgo, backend=options.backend)
            _synchronize(device)
            frame_ms = (time.perf_counter() - tick) * 1e3
            fpgo_ms = gaussians.stats.milliseconds if gaussians.stats is not None else 0.0
            images, raster_ms = _render_views(gaussians, views, background, options.backend, device)
            for view, image in zip(views, images):
                writes.append(writer.submit(write_png, out_dir / view.name / f"{frame_index:05d}.png",
                                            image))
                videos[view.name].write(image)
                if view.name == preview:
                    preview_frames.append(image)
            ply_ms = 0.0
            if options.export_ply:
                tick = time.perf_counter()
                gaussians.write_ply(out_dir / "ply" / f"frame_{frame_index:05d}.ply")
                ply_ms = (time.perf_counter() - tick) * 1e3
            stats = gaussians.stats
            rows.append({"frame": frame_index, "gaussians": len(gaussians),
                         "fpgo_gaussians": int(gaussians.is_fpgo.sum()),
                         "fractured": int(frame.fractured.sum()),
                         "hidden_particles": stats.hidden_particles if stats else 0,
                         "buried_particles": stats.buried_particles if stats else 0,
                         "load_wait_ms": load_wait, "deform_ms": frame_ms - fpgo_ms,
                         "fpgo_ms": fpgo_ms, "raster_ms": raster_ms,
                         "raster_ms_per_view": raster_ms / len(views), "ply_ms": ply_ms})
            bar.update(1)
            bar.set_postfix(gaussians=len(gaussians), ms=f"{frame_ms + raster_ms:.0f}")
            for done in [w for w in writes if w.done()]:
                done.result()
                writes.remove(done)
        for pending in writes:
            pending.result()
        for video in videos.values():
            video.close()
        write_gif(out_dir / "preview.gif", preview_frames, options.fps)
        write_text_atomic(out_dir / "timing.csv", _timing_csv(rows))
        completed = True
    finally:
        bar.close()
        loader.shutdown(wait=True, cancel_futures=True)
        writer.shutdown(wait=True)
        if not completed:
            for video in videos.values():
                video.abort()
    count = len(rows)
    per_frame = [r["deform_ms"] + r["fpgo_ms"] + r["raster_ms"] for r in rows]
    summary = RenderSummary(
        out_dir=out_dir, frames=count, views=names, ms_per_frame=float(np.mean(per_frame)),
        fpgo_ms_per_frame=float(np.mean([r["fpgo_ms"] for r in rows])),
        raster_ms_per_frame=float(np.mean([r["raster_ms"] for r in rows])),
        wall_seconds=time.perf_counter() - started,
        max_gaussians=int(max(r["gaussians"] for r in rows)), rows=rows)
    width, height = views[0].camera.width, views[0].camera.height
    print(f"rendered {count} frames x {len(views)} views ({width}x{height}, "
          f"{'FPGO' if options.fpgo else 'no FPGO'}, up to {summary.max_gaussians} Gaussians) in "
          f"{summary.wall_seconds:.1f} s: {summary.ms_per_frame:.1f} ms per frame "
          f"(FPGO {summary.fpgo_ms_per_frame:.1f} ms, raster {summary.raster_ms_per_frame:.1f} ms "
          f"= {summary.raster_ms_per_frame / len(views):.1f} ms per view) -> {out_dir}", file=log)
    return summary


def _render_model(argv: list[str]) -> int:
    """``render.py -m <model> ...``: static renders of a trained model."""
    if "--sim" in argv or any(a.startswith("--sim=") for a in argv):
        print("error: give either --sim (a simulation) or -m (a trained model), not both",
              file=sys.stderr)
        return 2
    from fracture_gs.cli import render_model

    return int(render_model.main(argv))


def _wants_model(argv: Sequence[str]) -> bool:
    return any(a in ("-m", "--model") or a.startswith(("--model=", "-m=")) or
               (a.startswith("-m") and not a.startswith("--") and len(a) > 2) for a in argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if _wants_model(argv):
        return _render_model(argv)
    args = parse_args(argv)
    try:
        render_simulation(options_from_args(args))
    except (SimulationError, ModelError, ViewSpecError, InvalidInput, OutputFolderError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # writing an image or video failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; the images written so far are kept, the videos are not",
              file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
