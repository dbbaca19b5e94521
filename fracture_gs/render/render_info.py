"""What a ``render.py --sim`` output folder holds: its ``render.json``.

``render.py`` writes the file before the first image and again when the last is written: the
simulation it rendered (folder, scene name, contact mode, :meth:`Simulation.fingerprint` and the
id of the run that wrote the frames), whether FPGO was on, the frames and views it renders and
whether it finished. Tools that read the images (``evaluate.py --renders``) take the run's label
from it and refuse the folder when it belongs to another simulation or run, was rendered otherwise
than they were asked to score, or was interrupted; they read only its frames and views::

    {"format": "fracture_gs/render-info-v1", "sim": "/abs/output/sims/two_spheres",
     "simulation": "<sha256>", "scene": "two_spheres", "contact_mode": "collision",
     "fpgo": true, "run": "<run id>", "frames": [0, 1, 2], "views": ["orbit_00"],
     "complete": true}

Files of older versions lack the last four keys (their run, frames and views are unknown).

Problems reading the file raise :class:`RenderInfoError` with one line naming the folder or file.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.folders.sim_reader import Simulation

RENDER_INFO_FILE = "render.json"
RENDER_INFO_FORMAT = "fracture_gs/render-info-v1"


class RenderInfoError(ValueError):
    """A render folder whose ``render.json`` is missing or unusable (one line naming it)."""


@dataclass(frozen=True)
class RenderInfo:
    """The simulation a render folder shows and how it was rendered."""

    sim: str                # the simulation folder, absolute, as it was when rendered
    simulation: str         # Simulation.fingerprint() of that folder
    scene: str              # the scene's name
    contact_mode: str       # the scene's contact.mode
    fpgo: bool              # fracture-surface Gaussians on
    run: str | None = None            # Simulation.run_id() (None: unknown)
    frames: list[int] | None = None   # the frames rendered (None: unknown)
    views: list[str] | None = None    # the views rendered (None: unknown)
    complete: bool = True             # every image written (False while rendering)

    @classmethod
    def of(cls, sim: Simulation, fpgo: bool, frames: list[int] | None = None,
           views: list[str] | None = None) -> "RenderInfo":
        """The record of rendering ``frames`` of ``sim`` from ``views``, with or without FPGO."""
        return cls(sim=str(sim.root.resolve()), simulation=sim.fingerprint(),
                   scene=sim.scene.name, contact_mode=sim.scene.contact.mode, fpgo=fpgo,
                   run=sim.run_id(), frames=frames, views=views)

    @property
    def fpgo_text(self) -> str:
        """'with FPGO' or 'without FPGO'."""
        return "with FPGO" if self.fpgo else "without FPGO"


def write_render_info(folder: Path, info: RenderInfo) -> None:
    """Write ``folder/render.json`` (atomically)."""
    text = json.dumps({"format": RENDER_INFO_FORMAT, **asdict(info)}, indent=2) + "\n"
    write_text_atomic(Path(folder) / RENDER_INFO_FILE, text)


def read_render_info(folder: Path) -> RenderInfo:
    """The :class:`RenderInfo` of a render folder; RenderInfoError when the folder or its
    ``render.json`` is missing (a folder from an older render.py) or malformed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RenderInfoError(f"{folder}: no such render folder")
    path = folder / RENDER_INFO_FILE
    try:
        content: Any = json.loads(path.read_text())
    except FileNotFoundError:
        raise RenderInfoError(f"{path}: file not found, so what the images show is unknown "
                              "(render the simulation again with render.py --sim)") from None
    except (OSError, ValueError) as exc:
        raise RenderInfoError(f"{path}: not a readable JSON file ({type(exc).__name__})") \
            from None
    if not isinstance(content, dict) or content.get("format") != RENDER_INFO_FORMAT:
        raise RenderInfoError(f"{path}: not written by render.py (format is not "
                              f"{RENDER_INFO_FORMAT})")
    try:
        info = RenderInfo(sim=str(content["sim"]), simulation=str(content["simulation"]),
                          scene=str(content["scene"]), contact_mode=str(content["contact_mode"]),
                          fpgo=content["fpgo"], run=content.get("run"),
                          frames=content.get("frames"), views=content.get("views"),
                          complete=content.get("complete", True))
    except KeyError as exc:
        raise RenderInfoError(f"{path}: missing key {exc}") from None
    if not isinstance(info.fpgo, bool) or not isinstance(info.complete, bool):
        raise RenderInfoError(f"{path}: 'fpgo' and 'complete' must be true or false")
    if not (info.run is None or isinstance(info.run, str)) or \
            not (info.frames is None or (isinstance(info.frames, list) and
                                         all(type(f) is int for f in info.frames))) or \
            not (info.views is None or (isinstance(info.views, list) and
                                        all(isinstance(v, str) for v in info.views))):
        raise RenderInfoError(f"{path}: 'run', 'frames' or 'views' is malformed")
    return info
