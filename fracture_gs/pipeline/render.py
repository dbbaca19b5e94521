"""The render stage: a simulation's frames as Gaussian splats, with FPGO filling fracture surfaces.

Renders every frame from every view into ``<sim>/renders/`` (``renders_nofpgo/`` without
FPGO): ``<view>/00000.png``, ``video_<view>.mp4`` (H.264), ``preview.gif`` (one view),
``timing.csv`` and, with ``export_ply``, ``ply/frame_00000.ply`` (3DGS layout). The files are
recorded in the output folder's manifest (:mod:`fracture_gs.io.manifest`).

One render at a time writes a folder (its lock ``.render.lock``). A render writes only where no
file is in the way that the tools did not write there, and first removes the files of the earlier
render in the folder, so no image of another render (more frames, other views, FPGO otherwise)
stays beside this one's. Everything it reads is checked before the first file is written (every
frame of the run, :meth:`Simulation.open`); a frame found damaged later still stops the render
with the files it wrote removed.
"""
from __future__ import annotations

import csv
import io
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TextIO

import numpy as np
import torch

from fracture_gs.folders.sim_reader import Simulation, SimulationError
from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import claim_folder, replace_written
from fracture_gs.io.output_folder import prepare_output_folder
from fracture_gs.io.sim_layout import SimLayout
from fracture_gs.pipeline.background import training_background
from fracture_gs.render.frame_gaussians import FrameGaussians, SceneGaussians
from fracture_gs.render.render_info import RENDER_INFO_FILE, RenderInfo, write_render_info
from fracture_gs.pipeline.views import resolve_views
from fracture_gs.render.video import Mp4Writer, to_uint8, write_gif, write_png
from fracture_gs.render.views import View, ViewSpecError

PREVIEW_FILE = "preview.gif"
TIMING_FILE = "timing.csv"
LOCK_FILE = ".render.lock"
KIND = "render"               # the manifest kind of a render folder
TIMING_COLUMNS = ("frame", "gaussians", "fpgo_gaussians", "fractured", "hidden_particles",
                  "buried_particles", "load_wait_ms", "deform_ms", "fpgo_ms", "raster_ms",
                  "raster_ms_per_view", "ply_ms")


@dataclass
class RenderOptions:
    """Everything ``render.py --sim`` needs (the parsed command line)."""

    sim: Path
    views: str = "orbit:8"
    fpgo: bool = True
    frames: str | None = None
    resolution: tuple[int, int] | None = None
    background: str | None = None     # white | black; None: the objects' training background
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


def _png_path(out_dir: Path, view: str, frame: int) -> Path:
    return out_dir / view / f"{frame:05d}.png"


def _video_path(out_dir: Path, view: str) -> Path:
    return out_dir / f"video_{view}.mp4"


def _ply_path(out_dir: Path, frame: int) -> Path:
    return out_dir / "ply" / f"frame_{frame:05d}.ply"


def _output_files(out_dir: Path, views: list[str], frames: list[int],
                  export_ply: bool) -> list[Path]:
    """Every file a render of ``frames`` from ``views`` writes."""
    files = [out_dir / PREVIEW_FILE, out_dir / TIMING_FILE, out_dir / RENDER_INFO_FILE,
             *(_video_path(out_dir, view) for view in views),
             *(_png_path(out_dir, view, frame) for view in views for frame in frames)]
    if export_ply:
        files += [_ply_path(out_dir, frame) for frame in frames]
    return files


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
    ViewSpecError for bad input before anything is written, FolderTaken when a file the tools
    did not write is in the way, FolderBusy when another render writes the folder."""
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
        options.out or SimLayout(sim.root).renders_dir(options.fpgo), "--out", keep=False)
    scene = SceneGaussians.from_simulation(sim, options.device, options.settings)
    device = options.device
    views = [View(view.name, view.camera.to(device)) for view in views]
    colour = options.background or training_background(sim.scene)
    background = torch.full((3,), 1.0 if colour == "white" else 0.0, device=device)
    with folder_lock(out_dir, LOCK_FILE, "render.py", "render folder"):
        return _render_locked(options, sim, frames, views, preview, out_dir, scene, background,
                              log, progress, started)


def _render_locked(options: RenderOptions, sim: Simulation, frames: list[int], views: list[View],
                   preview: str, out_dir: Path, scene: SceneGaussians, background: torch.Tensor,
                   log: TextIO, progress: bool | None, started: float) -> RenderSummary:
    """:func:`render_simulation` once the output folder's lock is held."""
    from tqdm import tqdm

    device = options.device
    names = [view.name for view in views]
    files = _output_files(out_dir, names, frames, options.export_ply)
    manifest = replace_written(claim_folder(out_dir, KIND, files), files)
    for name in names:
        (out_dir / name).mkdir(parents=True, exist_ok=True)
    if options.export_ply:
        (out_dir / "ply").mkdir(parents=True, exist_ok=True)
    info = RenderInfo.of(sim, options.fpgo, frames=frames, views=names)
    write_render_info(out_dir, replace(info, complete=False))

    videos: dict[str, Mp4Writer] = {}
    preview_frames: list[np.ndarray] = []
    rows: list[dict[str, float]] = []
    loader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-loader")
    writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="png-writer")
    writes: list[Future] = []
    bar = tqdm(total=len(frames), unit="frame", desc=f"render {sim.scene.name}",
               disable=None if progress is None else not progress, dynamic_ncols=True)
    completed = False
    try:
        for view in views:
            videos[view.name] = Mp4Writer(_video_path(out_dir, view.name), view.camera.width,
                                          view.camera.height, options.fps)
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
                writes.append(writer.submit(write_png, _png_path(out_dir, view.name, frame_index),
                                            image))
                videos[view.name].write(image)
                if view.name == preview:
                    preview_frames.append(image)
            ply_ms = 0.0
            if options.export_ply:
                tick = time.perf_counter()
                gaussians.write_ply(_ply_path(out_dir, frame_index))
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
        write_gif(out_dir / PREVIEW_FILE, preview_frames, options.fps)
        write_text_atomic(out_dir / TIMING_FILE, _timing_csv(rows))
        write_render_info(out_dir, info)
        completed = True
    except SimulationError:   # a frame found damaged only now: nothing of this render stays
        loader.shutdown(wait=True, cancel_futures=True)
        writer.shutdown(wait=True)
        for video in videos.values():
            video.abort()
        manifest.remove_written()
        raise
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
