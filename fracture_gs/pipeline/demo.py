"""The demo: the whole pipeline in one call — a teapot dropped on a table shatters.

Stages (each skipped when its result exists; ``--force`` redoes them all):

1. ``data``     synthetic teapot and table datasets (Mitsuba 3), if missing;
2. ``train``    reconstruct both (train.py);
3. ``scene``    a scene YAML built from the trained objects (collision + porcelain + fragments);
4. ``simulate`` the scene with Collision-MPM, and again with ``contact.mode: mls`` (baseline);
5. ``render``   ours with FPGO, ours without FPGO, mls without FPGO (PNG + MP4 per view);
6. ``evaluate`` self-referenced PSNR / LPIPS / FID of the three (report.md, metrics.json).

``--quick`` uses smaller images, fewer views, iterations, particles and frames; ``--profile
tiny`` is the seconds-to-minutes version the test suite runs. Everything goes to
``<out>/`` (default ``output/demo`` or ``output/demo_<profile>``); the stage log with the time of
each stage is ``<out>/stages.json``.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml

from fracture_gs.io.atomic import write_text_atomic
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.manifest import Manifest, claim_folder
from fracture_gs.io.model_layout import PARTICLES_FILE
from fracture_gs.io.output_folder import prepare_output_folder
from fracture_gs.io.sim_layout import EVALUATION_DIR, SimLayout
from fracture_gs.pipeline.experiments.sim_eval import EvalOptions, EvaluationError, RunSpec
from fracture_gs.pipeline.render import TIMING_FILE
from fracture_gs.recon.pipeline import TrainConfig

STAGES = ("data", "train", "scene", "simulate", "render", "evaluate")
LOCK_FILE = ".demo.lock"
KIND = "demo"                 # the manifest kind of the demo's folder
OBJECTS = ("teapot", "table")


# The teapot: porcelain (configs/materials/porcelain.yaml: brittle, scaled so that the impact stress
# over the strength, rho c v / sigma_F, is the real material's), softened TEAPOT_SOFTENING times
# rather than the preset's 3000 so that it strains no more than about 3 % under the throw, white
# inside where it breaks, sampled hollow (TEAPOT_SHELL) as porcelain teapots are. The table: a rigid
# body (fracture_gs.mpm.rigid) as dense as stone: it neither bends nor sets the time step, so the
# teapot's wave speed alone does. Thrown down at TEAPOT_SPEED onto the rigid table, the teapot's
# rho c v / sigma_F is 3.3 whatever the softening (the preset's rule keeps it; the teapot dropped on
# the floor, configs/paper/teapot_ground_porcelain.yaml, has 2.2). docs/materials.md: the presets,
# the rule and its cost.
TEAPOT_SOFTENING = 300.0
TEAPOT_MATERIAL = {"part": 0, "preset": "porcelain", "softening": TEAPOT_SOFTENING,
                   "interior_colour": [0.96, 0.95, 0.92]}
TABLE_RIGID = True
TABLE_MATERIALS = [{"part": part, "model": "elastic", "E": 2.6e8, "nu": 0.25, "density": 2650}
                   for part in (0, 1)]
TEAPOT_SPEED = 10.0   # m/s, downwards
TEAPOT_SHELL = 0.06   # wall thickness over the teapot's length (train.py --shell)


@dataclass(frozen=True)
class Profile:
    """Sizes of one demo variant."""

    name: str
    image_size: int
    n_train: int
    n_test: int
    spp: int
    mesh_grid: int
    train: dict[str, int]        # TrainConfig sizes (the rest as train.py's defaults)
    teapot_train: dict[str, float]  # the teapot's own sizes over ``train``: hollow, finer particles
    grid: int
    frames: int
    views: int
    render_size: int
    window: int = 5
    frame_dt: float = 0.0167


PROFILES = {
    # Measured times of each profile: docs/results.md, The demo. The default grid (80 cells, 1.25 cm)
    # puts more than a cell across the hollow teapot's wall (about 1.8 cm).
    "default": Profile("default", 200, 60, 8, 16, 128,
                       {"sdf_res": 64, "sdf_iters": 200, "iterations": 800, "n_surface": 12000,
                        "nv": 8, "particle_res": 24},
                       {"particle_res": 32, "shell": TEAPOT_SHELL},
                       grid=80, frames=30, views=8, render_size=400),
    "quick": Profile("quick", 128, 24, 4, 4, 64,
                     {"sdf_res": 40, "sdf_iters": 60, "iterations": 200, "n_surface": 3000,
                      "nv": 4, "particle_res": 16, "sdf_rays": 512},
                     {"n_surface": 12000, "nv": 8, "particle_res": 32, "shell": TEAPOT_SHELL},
                     grid=64, frames=16, views=4, render_size=256),
    "tiny": Profile("tiny", 48, 6, 2, 1, 32,
                    {"sdf_res": 24, "sdf_iters": 16, "iterations": 24, "n_surface": 300,
                     "nv": 2, "particle_res": 10, "sdf_rays": 256},
                    {"n_surface": 1200, "nv": 4, "particle_res": 16, "shell": TEAPOT_SHELL},
                    grid=32, frames=8, views=2, render_size=64, window=3, frame_dt=0.008),
}


def _model_points(model: Path) -> np.ndarray:
    """Rest positions (model frame) of a trained model's particles.ply."""
    from fracture_gs.io.particles_ply import read_particles_ply

    path = model / PARTICLES_FILE
    if not path.is_file():
        raise EvaluationError(f"{path}: not found (train the object first)")
    columns = read_particles_ply(path)
    return np.stack([columns["x"], columns["y"], columns["z"]], axis=1).astype(np.float64)


def _placed(points: np.ndarray, scale: float, rotate_deg: tuple[float, float, float],
            centre_xy: tuple[float, float], bottom_z: float) -> list[float]:
    """The translation that puts the scaled, rotated points' box centre at ``centre_xy`` and
    their lowest point at ``bottom_z``."""
    from fracture_gs.mpm.scene import rotation_matrix_xyz

    moved = scale * points @ rotation_matrix_xyz(rotate_deg).T
    low, high = moved.min(axis=0), moved.max(axis=0)
    middle = 0.5 * (low + high)
    return [round(float(centre_xy[0] - middle[0]), 5), round(float(centre_xy[1] - middle[1]), 5),
            round(float(bottom_z - low[2]), 5)]


def demo_scene(teapot: Path, table: Path, grid: int, frames: int, mode: str = "collision",
               name: str = "demo_teapot_table", frame_dt: float = 0.0167) -> dict:
    """The demo's scene: the trained table standing on the ground, the trained teapot thrown
    down onto its top. Sizes and positions come from the trained particles' bounds (a coarse
    reconstruction is larger than the object), so the scene fits the unit domain."""
    ground = 4.0 / grid        # the box walls are 3 cells thick; the ground lies above them
    table_points, teapot_points = _model_points(table), _model_points(teapot)
    extent = table_points.max(axis=0) - table_points.min(axis=0)
    table_scale = float(min(0.6 / extent[0], 0.6 / extent[1], 0.45 / extent[2]))
    table_translate = _placed(table_points, table_scale, (0, 0, 0), (0.5, 0.5), ground + 0.005)
    top = table_scale * extent[2] + ground + 0.005
    teapot_rotation = (0.0, 0.0, 30.0)
    teapot_extent = np.ptp(teapot_points, axis=0)
    teapot_scale = float(0.3 / teapot_extent.max())
    teapot_translate = _placed(teapot_points, teapot_scale, teapot_rotation, (0.5, 0.5),
                               top + 0.03)
    return {
        "name": name if mode == "collision" else f"{name}_mls",
        "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": grid},
        "frames": frames, "frame_dt": frame_dt, "gravity": [0, 0, -9.8],
        # Ours opens cracks inside objects (contact.fragments), so the teapot's pieces come apart
        # instead of hanging together by the grid; the mls baseline (PhysGaussian / GIC style) has
        # no such thing.
        "contact": {"mode": mode, "impulse_scale": 1.0, "friction": 0.1, "fragments": mode == "collision"},
        "cfl": 0.3,
        "boundaries": [{"type": "ground", "height": ground, "friction": 0.5},
                       {"type": "box", "condition": "slip"}],
        "objects": [
            {"name": "teapot", "model": str(teapot.resolve()),
             "transform": {"scale": round(teapot_scale, 5), "rotate_deg": list(teapot_rotation),
                           "translate": teapot_translate},
             "velocity": [0, 0, -TEAPOT_SPEED], "materials": [TEAPOT_MATERIAL]},
            {"name": "table", "model": str(table.resolve()),
             "transform": {"scale": round(table_scale, 5), "translate": table_translate},
             "velocity": [0, 0, 0], "rigid": TABLE_RIGID, "materials": TABLE_MATERIALS},
        ],
    }


@dataclass
class Demo:
    """Paths and state of one demo run."""

    out: Path
    data: Path
    profile: Profile
    force: bool
    device: torch.device
    weights_dir: str | None
    workers: int
    log: dict = field(default_factory=dict)
    redone_from: str | None = None   # the first stage this call redoes

    @property
    def log_path(self) -> Path:
        return self.out / "stages.json"

    def model(self, name: str) -> Path:
        return self.out / "models" / name

    def scene_path(self, mode: str) -> Path:
        return self.out / "scenes" / f"teapot_table_{mode}.yaml"

    def sim(self, mode: str) -> Path:
        return self.out / "sims" / ("teapot_table" if mode == "collision" else "teapot_table_mls")

    def renders(self, mode: str, fpgo: bool) -> Path:
        return SimLayout(self.sim(mode)).renders_dir(fpgo)

    @property
    def evaluation(self) -> Path:
        return self.out / EVALUATION_DIR

    def save_log(self) -> None:
        self.record(self.log_path)
        write_text_atomic(self.log_path, json.dumps(self.log, indent=2) + "\n")

    def own_files(self) -> list[Path]:
        """The files the demo writes directly (its log and scenes)."""
        return [self.log_path, *(self.scene_path(mode) for mode in ("collision", "mls"))]

    def record(self, *paths: Path) -> None:
        """Record files the demo writes directly (its log and scenes) in its manifest."""
        manifest = Manifest.load(self.out)
        if any(path not in manifest for path in paths) or manifest.kind != KIND:
            manifest.kind = KIND
            manifest.add(*paths)
            manifest.save()


def _dataset_mismatch(folder: Path, profile: Profile) -> str:
    """'' when the dataset in ``folder`` was made with the profile's image size and view counts
    (its generator.json), else a note of how it differs: the demo's figures in docs/results.md are for
    datasets the demo made itself, and a larger one trains a different model."""
    from fracture_gs.data.synthetic.generator import GENERATOR_FILE

    try:
        made = json.loads((folder / GENERATOR_FILE).read_text())["settings"]
        found = (made["width"], made["height"], made["n_train"], made["n_test"])
    except (OSError, ValueError, KeyError, TypeError):
        return " (no generator.json: not made by the generator, so the results will differ from docs/results.md)"
    wanted = (profile.image_size, profile.image_size, profile.n_train, profile.n_test)
    if found == wanted:
        return ""
    return (f" (made at {found[0]}x{found[1]} with {found[2]} + {found[3]} views, not the profile's "
            f"{wanted[0]}x{wanted[1]} with {wanted[2]} + {wanted[3]}: the results will differ from "
            f"docs/results.md; --data DIR or --force makes the profile's)")


def stage_data(demo: Demo) -> None:
    from fracture_gs.data.synthetic.generator import GeneratorSettings, generate_dataset

    p = demo.profile
    settings = GeneratorSettings(p.image_size, p.image_size, p.n_train, p.n_test, p.spp,
                                 resolution=p.mesh_grid)
    for name in OBJECTS:
        folder = demo.data / name
        if (folder / "transforms_train.json").is_file() and not demo.force:
            print(f"[demo] data: {folder} exists, kept{_dataset_mismatch(folder, p)}")
            continue
        try:
            generate_dataset(name, str(folder), settings, overwrite=demo.force and folder.exists())
        except (OSError, ValueError, RuntimeError) as exc:
            raise EvaluationError(f"generating the {name} dataset: {exc}") from None
        print(f"[demo] data: wrote {folder}")


def train_sizes(profile: Profile, name: str) -> dict[str, float]:
    """The TrainConfig sizes of one object: the profile's, and for the teapot its own over them."""
    return {**profile.train, **(profile.teapot_train if name == "teapot" else {})}


def train_config(demo: Demo, name: str) -> TrainConfig:
    """The train.py configuration of one object (the profile's sizes, white background, no
    intermediate checkpoints)."""
    return TrainConfig(source_path=str(demo.data / name), model_path=str(demo.model(name)),
                       white_background=True, checkpoint_every=0, **train_sizes(demo.profile, name))


def stage_train(demo: Demo) -> None:
    from fracture_gs.pipeline.train import TRAIN_INPUT_ERRORS, train_model

    for name in OBJECTS:
        options = " ".join(f"--{key.replace('_', '-')} {value}"
                           for key, value in train_sizes(demo.profile, name).items())
        print(f"[demo] train.py -s {demo.data / name} -m {demo.model(name)} -w {options} "
              "--checkpoint_every 0", flush=True)
        try:
            train_model(train_config(demo, name))
        except TRAIN_INPUT_ERRORS as exc:
            raise EvaluationError(f"training the {name}: {exc}") from None


def stage_scene(demo: Demo) -> None:
    for mode in ("collision", "mls"):
        scene = demo_scene(demo.model("teapot"), demo.model("table"), demo.profile.grid,
                           demo.profile.frames, mode, frame_dt=demo.profile.frame_dt)
        path = demo.scene_path(mode)
        path.parent.mkdir(parents=True, exist_ok=True)
        demo.record(path)
        write_text_atomic(path, "# written by demo.py: the trained teapot dropped on the "
                          "trained table\n" + yaml.safe_dump(scene, sort_keys=False))
        print(f"[demo] scene: {path}")


def stage_simulate(demo: Demo) -> None:
    from fracture_gs.config.scene import load_scene
    from fracture_gs.pipeline.experiments.runner import SimJob, run_jobs

    jobs = [SimJob.of(load_scene(demo.scene_path(mode)), demo.sim(mode))
            for mode in ("collision", "mls")]

    def done(result) -> None:
        print(f"[demo] simulate {result.name}: {result.seconds:.0f} s -> {result.out_dir}")
        print(result.log.rstrip())

    # a run that is complete for the same scene is kept, unless an earlier stage was redone
    # (new models under the same paths) or --force
    stale = demo.force or demo.redone_from != "simulate"
    print(f"[demo] simulating {', '.join(job.name for job in jobs)}: {demo.profile.frames} frames each"
          + (f", {demo.workers} at a time" if demo.workers > 1 else ""), flush=True)
    run_jobs(jobs, workers=demo.workers, force=stale, on_done=done, progress=None)


def stage_render(demo: Demo) -> None:
    from fracture_gs.pipeline.render import RenderOptions, render_simulation

    size = demo.profile.render_size
    for mode, fpgo in (("collision", True), ("collision", False), ("mls", False)):
        render_simulation(RenderOptions(sim=demo.sim(mode), views=f"orbit:{demo.profile.views}",
                                        fpgo=fpgo, resolution=(size, size), device=demo.device))


def evaluation_specs(demo: Demo) -> list[RunSpec]:
    return [RunSpec("ours (collision + FPGO)", demo.sim("collision"), True,
                    demo.renders("collision", True)),
            RunSpec("collision, no FPGO", demo.sim("collision"), False,
                    demo.renders("collision", False)),
            RunSpec("mls, no FPGO (PhysGaussian / GIC)", demo.sim("mls"), False,
                    demo.renders("mls", False))]


def stage_evaluate(demo: Demo) -> None:
    from fracture_gs.metrics.protocol import MetricNetworks
    from fracture_gs.pipeline.experiments.sim_report import (evaluate_and_report,
                                                             evaluation_folder, report_files)

    size = demo.profile.render_size
    options = EvalOptions(views=f"orbit:{demo.profile.views}", resolution=(size, size),
                          window=demo.profile.window, device=demo.device)
    networks = MetricNetworks.load(demo.device, demo.weights_dir)
    specs = evaluation_specs(demo)
    with evaluation_folder(demo.evaluation, report_files(specs, demo.evaluation)) as before_writing:
        evaluate_and_report(specs, options, networks, demo.evaluation,
                            "Demo: teapot dropped on a table", with_paper=True,
                            before_writing=before_writing)


STAGE_FUNCTIONS = {"data": stage_data, "train": stage_train, "scene": stage_scene,
                   "simulate": stage_simulate, "render": stage_render, "evaluate": stage_evaluate}


def stage_outputs(demo: Demo, stage: str) -> list[Path]:
    """Files whose presence shows that ``stage`` finished."""
    if stage == "data":
        return [demo.data / o / "transforms_train.json" for o in OBJECTS]
    if stage == "train":
        return [demo.model(o) / PARTICLES_FILE for o in OBJECTS]
    if stage == "scene":
        return [demo.scene_path(m) for m in ("collision", "mls")]
    if stage == "simulate":
        return [SimLayout(demo.sim(m)).frame_path(demo.profile.frames)
                for m in ("collision", "mls")]
    if stage == "render":
        return [demo.renders(m, f) / TIMING_FILE
                for m, f in (("collision", True), ("collision", False), ("mls", False))]
    return [demo.evaluation / "report.md"]


def stage_settings(demo: Demo, stage: str) -> dict | None:
    """What the demo's own code decides about a stage beyond the profile's name (None: nothing):
    the training sizes of each object and the scene's materials and throw. The stage log keeps
    them, so a folder made by an earlier version of these settings is redone, not reused."""
    if stage == "train":
        return {name: train_sizes(demo.profile, name) for name in OBJECTS}
    if stage == "scene":
        return {"teapot": TEAPOT_MATERIAL, "table": TABLE_MATERIALS, "table_rigid": TABLE_RIGID, "speed": TEAPOT_SPEED,
                "grid": demo.profile.grid, "frames": demo.profile.frames, "frame_dt": demo.profile.frame_dt}
    return None


def stage_is_current(logged: dict | None, settings: dict | None, outputs_exist: bool) -> bool:
    """True when a stage's logged run (None: never run) finished with the same settings (compared
    as JSON, as the log stores them) and its outputs are still there."""
    if logged is None or not outputs_exist:
        return False
    return logged.get("settings") == json.loads(json.dumps(settings))


def run_demo(demo: Demo) -> dict:
    """Run (or skip) every stage, then print the comparison and where the results are (one
    demo at a time per folder; FolderTaken when its log or scenes are files the tools did not
    write there)."""
    prepare_output_folder(demo.out, "--out")
    with folder_lock(demo.out, LOCK_FILE, "demo.py", "demo folder"):
        claim_folder(demo.out, KIND, demo.own_files())
        return _run_demo_locked(demo)


def _run_demo_locked(demo: Demo) -> dict:
    """:func:`run_demo` once the demo folder's lock is held."""
    from fracture_gs.pipeline.experiments.sim_report import print_comparison

    if demo.log_path.is_file() and not demo.force:
        demo.log = json.loads(demo.log_path.read_text())
    if demo.log.get("profile", demo.profile.name) != demo.profile.name:
        print(f"[demo] {demo.out} holds a '{demo.log['profile']}' run: redoing every stage "
              f"for '{demo.profile.name}'")
        demo.log = {}
    demo.log.setdefault("profile", demo.profile.name)
    stages = demo.log.setdefault("stages", {})
    redo_from = None
    for stage in STAGES:
        settings = stage_settings(demo, stage)
        outputs_exist = all(p.is_file() for p in stage_outputs(demo, stage))
        reusable = not demo.force and redo_from is None   # nothing asks for this stage anew
        if reusable and stage_is_current(stages.get(stage), settings, outputs_exist):
            print(f"[demo] {stage}: done earlier ({stages[stage]['seconds']:.0f} s), skipped")
            continue
        if reusable and stage in stages and outputs_exist:
            print(f"[demo] {stage}: made with other settings than this version's, redone")
        redo_from = redo_from or stage   # a redone stage makes every later one stale
        demo.redone_from = redo_from
        print(f"[demo] {stage} ...", flush=True)
        started = time.perf_counter()
        STAGE_FUNCTIONS[stage](demo)
        stages[stage] = {"seconds": time.perf_counter() - started,
                         "finished": time.strftime("%Y-%m-%dT%H:%M:%S"), "settings": settings}
        demo.save_log()
    metrics = json.loads((demo.evaluation / "metrics.json").read_text())
    print()
    print(print_comparison(metrics, with_paper=True))
    print()
    total = sum(s["seconds"] for s in stages.values())
    for stage in STAGES:
        print(f"  {stage:<9} {stages[stage]['seconds']:8.1f} s")
    print(f"  {'total':<9} {total:8.1f} s  (profile {demo.profile.name})")
    video = demo.renders("collision", True) / "video_orbit_00.mp4"
    print(f"[demo] video:  {video}")
    print(f"[demo] report: {demo.evaluation / 'report.md'}")
    return metrics
