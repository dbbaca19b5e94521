"""Self-referenced fracture metrics of simulations (docs/formulas.md §14, paper App. A.3).

For one *run* (a simulation folder rendered with or without FPGO): find the fracture onset
(``metrics.onset``), render the reference frame and the window frames from every view with the
project's one implementation of "the Gaussians of frame t" (:class:`SceneGaussians`), or read
them from a ``render.py`` output folder, and hand them to ``metrics.protocol``.

```python
networks = MetricNetworks.load(torch.device("cpu"))
result = evaluate_run(RunSpec("ours", Path("output/sims/teapot_table"), fpgo=True),
                      EvalOptions(), networks)
result.metrics.to_json()
```
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from fracture_gs.folders.sim_reader import Simulation, SimulationError
from fracture_gs.fracture.fpgo import FPGOSettings
from fracture_gs.metrics.onset import DEFAULT_WINDOW, FractureWindow, fracture_window_from_simulation
from fracture_gs.metrics.protocol import MetricNetworks, SelfReferencedMetrics, self_referenced_metrics
from fracture_gs.pipeline.background import training_background
from fracture_gs.io.sim_layout import PARTICLES_FILE, SCENE_FILE
from fracture_gs.render.frame_gaussians import SceneGaussians
from fracture_gs.render.render_info import (RENDER_INFO_FILE, RenderInfo, RenderInfoError,
                                            read_render_info)
from fracture_gs.render.video import to_uint8
from fracture_gs.render.views import View

DEFAULT_RESOLUTION = (400, 400)
_PNG_NAME = re.compile(r"^(\d{5,})\.png$")


class EvaluationError(ValueError):
    """Input that cannot be evaluated (one line naming the folder, file or option)."""


@dataclass(frozen=True)
class RunSpec:
    """One evaluated variant: a simulation folder rendered with or without FPGO.

    ``renders``: a ``render.py --sim`` output folder (``<view>/<frame:05d>.png``) to read the
    images from instead of rendering them; its ``render.json`` must name this simulation and
    this ``fpgo``. ``contact``: the contact mode the label claims (the simulation's scene must
    have it), or None for any."""

    label: str
    sim: Path
    fpgo: bool = True
    renders: Path | None = None
    contact: str | None = None


@dataclass(frozen=True)
class EvalOptions:
    """How runs are rendered and compared (the evaluate.py options)."""

    views: str = "orbit:8"
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    window: int = DEFAULT_WINDOW
    background: str | None = None     # white | black; None: the objects' training background
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    backend: str = "auto"
    batch_size: int = 8
    settings: FPGOSettings = field(default_factory=FPGOSettings)


@dataclass
class RunResult:
    """Metrics of one run plus what the report shows of it."""

    spec: RunSpec
    window: FractureWindow
    view_names: list[str]
    metrics: SelfReferencedMetrics | None
    strip: list[np.ndarray]          # first view: reference frame, then the window frames (uint8)
    strip_frames: list[int]

    def to_json(self) -> dict:
        """Plain JSON for ``metrics.json``."""
        return {"label": self.spec.label, "sim": str(self.spec.sim), "fpgo": self.spec.fpgo,
                "renders": str(self.spec.renders) if self.spec.renders else None,
                "window": self.window.to_json(), "views": self.view_names,
                "metrics": self.metrics.to_json() if self.metrics is not None else None}


def open_simulation(path: Path) -> Simulation:
    """:meth:`Simulation.open` with its error turned into an :class:`EvaluationError`."""
    try:
        return Simulation.open(path)
    except SimulationError as exc:
        raise EvaluationError(str(exc)) from None


def _render_info(renders: Path) -> RenderInfo:
    try:
        return read_render_info(renders)
    except RenderInfoError as exc:
        raise EvaluationError(str(exc)) from None


def run_of_renders(sim: Path, renders: Path, fpgo: bool | None = None) -> RunSpec:
    """The run a ``render.py`` output folder holds, labelled from its ``render.json`` ('FPGO' or
    'no FPGO'); ``fpgo`` (when not None) is what the caller asked for, and a folder rendered
    otherwise is refused by :func:`check_run`."""
    info = _render_info(renders)
    claimed = info.fpgo if fpgo is None else fpgo
    return RunSpec("FPGO" if claimed else "no FPGO", sim, claimed, renders)


def check_run(spec: RunSpec) -> Simulation:
    """Open the run's simulation and check that it is what ``spec`` says: the contact mode it
    claims, and renders of this simulation with FPGO as claimed. EvaluationError (one line
    naming the folder) otherwise."""
    sim = open_simulation(spec.sim)
    mode = sim.scene.contact.mode
    if spec.contact is not None and mode != spec.contact:
        raise EvaluationError(f"{spec.sim}: simulated with contact mode '{mode}' (its "
                              f"{SCENE_FILE}), but the run '{spec.label}' needs contact mode "
                              f"'{spec.contact}'")
    if spec.renders is not None:
        info = _render_info(spec.renders)
        if info.simulation != sim.fingerprint():
            if info.sim == str(sim.root.resolve()):
                raise EvaluationError(f"{spec.renders}: renders of an earlier state of {spec.sim} "
                                      f"(its {SCENE_FILE} or {PARTICLES_FILE} changed since); "
                                      "render the simulation again")
            raise EvaluationError(f"{spec.renders}: renders of the simulation {info.sim} (scene "
                                  f"'{info.scene}'), not of {spec.sim}")
        if info.run is not None and info.run != sim.run_id():
            raise EvaluationError(f"{spec.renders}: renders of an earlier run in {spec.sim} (the "
                                  f"run id in its {RENDER_INFO_FILE} is not the simulation's); "
                                  "render the simulation again")
        if not info.complete:
            raise EvaluationError(f"{spec.renders}: the render was interrupted (its "
                                  f"{RENDER_INFO_FILE}); render the simulation again")
        if info.fpgo != spec.fpgo:
            wanted = "with FPGO" if spec.fpgo else "without FPGO"
            raise EvaluationError(f"{spec.renders}: rendered {info.fpgo_text} (its "
                                  f"{RENDER_INFO_FILE}), but the run '{spec.label}' is {wanted}")
    return sim


def check_same_scene(baseline: Simulation, reference: Simulation, option: str = "--mls") -> None:
    """EvaluationError unless ``baseline`` simulates the scene of ``reference`` (every key but
    the name and the contact settings, and the same particles)."""
    from fracture_gs.pipeline.simulate import first_difference

    ignored = ("name", "contact")
    mine = {k: v for k, v in baseline.scene.to_dict().items() if k not in ignored}
    theirs = {k: v for k, v in reference.scene.to_dict().items() if k not in ignored}
    diff = first_difference(mine, theirs)
    if diff is not None:
        raise EvaluationError(f"{option} {baseline.root}: not the scene of {reference.root} (its "
                              f"{SCENE_FILE} differs at '{diff}'); simulate the same scene with "
                              "contact mode mls")
    a, b = baseline.particles, reference.particles
    if a.rest_x.shape != b.rest_x.shape or not np.array_equal(a.rest_x, b.rest_x) or \
            not np.array_equal(a.obj_id, b.obj_id):
        raise EvaluationError(f"{option} {baseline.root}: its particles ({PARTICLES_FILE}) are not "
                              f"those of {reference.root}; simulate the same scene with contact "
                              "mode mls")


def evaluation_views(sim: Simulation, spec: str, resolution: tuple[int, int]) -> list[View]:
    """The cameras of ``spec`` (``orbit:N`` / ``train`` / ``test`` / cameras.json), framed as
    ``render.py`` frames them for the whole run."""
    from fracture_gs.pipeline.views import resolve_views
    from fracture_gs.render.views import ViewSpecError

    try:
        return resolve_views(spec, sim, sim.frames, resolution)
    except ViewSpecError as exc:
        raise EvaluationError(str(exc)) from None


def render_frames(sim: Simulation, views: list[View], frames: list[int], fpgo: bool,
                  options: EvalOptions, progress: bool = False) -> np.ndarray:
    """``(frames, views, H, W, 3)`` uint8 renders of ``frames`` (the render.py pipeline:
    :class:`SceneGaussians` + the rasterizer, FPGO on or off)."""
    from tqdm import tqdm

    device = options.device
    scene = SceneGaussians.from_simulation(sim, device, options.settings)
    cameras = [view.camera.to(device) for view in views]
    colour = options.background or training_background(sim.scene)
    background = torch.full((3,), 1.0 if colour == "white" else 0.0, device=device)
    images = []
    with torch.no_grad():
        for index in tqdm(frames, desc=f"render {sim.scene.name}", unit="frame",
                          disable=not progress, leave=False):
            gaussians = scene.frame(sim.load_frame(index, device), fpgo=fpgo,
                                    backend=options.backend)
            images.append([to_uint8(gaussians.rasterize(camera, background, options.backend)["rgb"])
                           for camera in cameras])
    return np.asarray(images, dtype=np.uint8)


def rendered_view_names(folder: Path) -> list[str]:
    """The views of a ``render.py`` output folder: those its ``render.json`` names, or (a folder
    of an older version) the sub-folders holding numbered PNGs."""
    if not folder.is_dir():
        raise EvaluationError(f"{folder}: no such render folder")
    views = _render_info(folder).views
    if views is not None:
        return list(views)
    names = sorted(d.name for d in folder.iterdir()
                   if d.is_dir() and any(_PNG_NAME.match(f.name) for f in d.iterdir()))
    if not names:
        raise EvaluationError(f"{folder}: no <view>/<frame>.png images (not a render.py --sim "
                              "output folder)")
    return names


def read_rendered_frames(folder: Path, view_names: list[str], frames: list[int]) -> np.ndarray:
    """``(frames, views, H, W, 3)`` uint8 images read from a render.py output folder (only
    frames its ``render.json`` says it rendered)."""
    rendered = _render_info(folder).frames
    outside = [index for index in frames if rendered is not None and index not in rendered]
    if outside:
        raise EvaluationError(f"{folder}: frame {outside[0]} was not rendered (its "
                              f"{RENDER_INFO_FILE} holds frames {_frame_span(rendered)}); render "
                              f"frame {outside[0]} of every view first")
    images = []
    for index in frames:
        row = []
        for name in view_names:
            path = folder / name / f"{index:05d}.png"
            image = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
            if image is None:
                raise EvaluationError(f"{path}: missing or unreadable (render frame {index} "
                                      "of every view first)")
            row.append(image[..., ::-1])
        if len({im.shape for im in row}) != 1:
            raise EvaluationError(f"{folder}: views of frame {index} differ in size")
        images.append(row)
    return np.ascontiguousarray(np.asarray(images, dtype=np.uint8))


def _frame_span(frames: list[int]) -> str:
    return f"{frames[0]}..{frames[-1]}" if frames else "none"


def evaluate_run(spec: RunSpec, options: EvalOptions, networks: MetricNetworks,
                 progress: bool = False) -> RunResult:
    """Onset, window and self-referenced PSNR / LPIPS / FID of one run (module docstring)."""
    sim = check_run(spec)
    try:
        window = fracture_window_from_simulation(spec.sim, options.window)
    except (FileNotFoundError, ValueError) as exc:
        raise EvaluationError(str(exc)) from None
    if spec.renders is not None:
        view_names = rendered_view_names(spec.renders)
    else:
        views = evaluation_views(sim, options.views, options.resolution)
        view_names = [view.name for view in views]
    if not window.usable:
        return RunResult(spec, window, view_names, None, [], [])
    frames = [window.reference_frame, *window.window_frames]
    if spec.renders is not None:
        images = read_rendered_frames(spec.renders, view_names, frames)
    else:
        images = render_frames(sim, views, frames, spec.fpgo, options, progress)
    as_float = torch.from_numpy(images).float() / 255.0          # (F, V, H, W, 3)
    reference = as_float[0]
    window_images = as_float[1:].permute(1, 0, 2, 3, 4).contiguous()   # (V, T, H, W, 3)
    metrics = self_referenced_metrics(reference, window_images, networks, options.batch_size)
    return RunResult(spec, window, view_names, metrics, [images[i, 0] for i in range(len(frames))],
                     frames)
