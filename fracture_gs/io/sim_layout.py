"""The layout of a simulation folder (``simulate.py --out``, default ``output/sims/<name>/``).

::

    scene.yaml               the resolved scene (defaults filled in)
    particles.npz            constant per-particle data (PARTICLE_ARRAYS and more)
    frames/frame_00000.npz   FRAME_ARRAYS (+ OPTIONAL_FRAME_ARRAYS) of one frame; 0 = start
    diagnostics.csv          one row per frame
    diagnostics.png          momentum and energies over time
    checkpoint.npz           the solver's full state after the last complete frame
    run.json                 the run's id, its models' digests and each frame's digest
    renders/, renders_nofpgo/   render.py's images and videos (with and without FPGO)
    evaluation/              evaluate.py --sim's metrics and report
    .simulate.lock           held while a simulate.py run writes the folder
    .written.json            the files the tools wrote (fracture_gs.io.manifest)

Every other module takes these names from here.
"""
from __future__ import annotations

import re
from pathlib import Path

SCENE_FILE = "scene.yaml"
PARTICLES_FILE = "particles.npz"
FRAMES_DIR = "frames"
CHECKPOINT_FILE = "checkpoint.npz"
DIAGNOSTICS_CSV = "diagnostics.csv"
DIAGNOSTICS_PNG = "diagnostics.png"
RENDERS_DIR = "renders"
RENDERS_NOFPGO_DIR = "renders_nofpgo"
EVALUATION_DIR = "evaluation"
RUN_FILE = "run.json"
LOCK_FILE = ".simulate.lock"

# particles.npz: the arrays a reader needs (the writer stores more: mass, part_id, ...)
PARTICLE_ARRAYS = ("rest_x", "obj_id", "is_surface", "gaussian_index", "rest_volume")
# frames/frame_NNNNN.npz: every frame holds FRAME_ARRAYS; the renderer reads RENDER_ARRAYS of
# them; runs of older versions lack the OPTIONAL_FRAME_ARRAYS
FRAME_ARRAYS = ("x", "v", "F_E", "alpha", "fractured")
RENDER_ARRAYS = ("x", "F_E", "fractured")
OPTIONAL_FRAME_ARRAYS = ("fragment_id", "damage")

_FRAME_PATTERN = re.compile(r"^frame_(\d+)\.npz$")


def frame_file_name(frame: int) -> str:
    """File name of frame ``frame`` in the frames folder."""
    return f"frame_{frame:05d}.npz"


def frame_number(name: str) -> int | None:
    """The frame a file name of the frames folder holds, or None for any other name."""
    match = _FRAME_PATTERN.match(name)
    return int(match.group(1)) if match else None


def is_simulation_folder(path: Path) -> bool:
    """Whether ``path`` holds a simulation (its scene file)."""
    return (path / SCENE_FILE).is_file()


def renders_dir_name(fpgo: bool) -> str:
    """render.py's default output folder inside the simulation folder."""
    return RENDERS_DIR if fpgo else RENDERS_NOFPGO_DIR


class SimLayout:
    """The paths of one simulation folder."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def scene_path(self) -> Path:
        return self.root / SCENE_FILE

    @property
    def particles_path(self) -> Path:
        return self.root / PARTICLES_FILE

    @property
    def frames_dir(self) -> Path:
        return self.root / FRAMES_DIR

    @property
    def checkpoint_path(self) -> Path:
        return self.root / CHECKPOINT_FILE

    @property
    def csv_path(self) -> Path:
        return self.root / DIAGNOSTICS_CSV

    @property
    def png_path(self) -> Path:
        return self.root / DIAGNOSTICS_PNG

    @property
    def run_path(self) -> Path:
        return self.root / RUN_FILE

    @property
    def evaluation_dir(self) -> Path:
        return self.root / EVALUATION_DIR

    def frame_path(self, frame: int) -> Path:
        """Path of frame ``frame``'s file."""
        return self.frames_dir / frame_file_name(frame)

    def renders_dir(self, fpgo: bool) -> Path:
        """render.py's default output folder (with or without FPGO)."""
        return self.root / renders_dir_name(fpgo)

    def output_files(self) -> list[Path]:
        """The files of a run other than its frames."""
        return [self.scene_path, self.particles_path, self.checkpoint_path, self.csv_path,
                self.png_path, self.run_path]

    def frames_on_disk(self) -> list[int]:
        """The frame numbers of the frame files present, ascending."""
        if not self.frames_dir.is_dir():
            return []
        numbers = (frame_number(path.name) for path in self.frames_dir.iterdir())
        return sorted(n for n in numbers if n is not None)
