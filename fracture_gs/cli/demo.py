"""``demo.py``: the whole pipeline in one command — a teapot dropped on a table shatters.

Stages (each skipped when its result exists; ``--force`` redoes them all):

1. ``data``     synthetic teapot and table datasets (Mitsuba 3), if missing;
2. ``train``    reconstruct both (train.py);
3. ``scene``    a scene YAML built from the trained objects (collision + NACC + fragments);
4. ``simulate`` the scene with Collision-MPM, and again with ``contact.mode: mls`` (baseline);
5. ``render``   ours with FPGO, ours without FPGO, mls without FPGO (PNG + MP4 per view);
6. ``evaluate`` self-referenced PSNR / LPIPS / FID of the three (report.md, metrics.json).

``--quick`` uses smaller images, fewer views, iterations, particles and frames; ``--profile
tiny`` is the seconds-to-minutes version the test suite runs. Everything goes to
``<out>/`` (default ``output/demo`` or ``output/demo_<profile>``); the stage log with the time of
each stage is ``<out>/stages.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import yaml

from fracture_gs.cli.output_folder import prepare_output_folder
from fracture_gs.experiments.sim_eval import EvalOptions, EvaluationError, RunSpec
from fracture_gs.mpm.output import write_text_atomic

STAGES = ("data", "train", "scene", "simulate", "render", "evaluate")
OBJECTS = ("teapot", "table")


@dataclass(frozen=True)
class Profile:
    """Sizes of one demo variant."""

    name: str
    image_size: int
    n_train: int
    n_test: int
    spp: int
    mesh_grid: int
    train_args: tuple[str, ...]
    grid: int
    frames: int
    views: int
    render_size: int
    window: int = 5
    frame_dt: float = 0.0167


PROFILES = {
    # Measured times of each profile: docs/results.md, The demo.
    "default": Profile("default", 200, 60, 8, 16, 128,
                       ("--sdf-res", "64", "--sdf-iters", "200", "--iterations", "800",
                        "--n-surface", "12000", "--nv", "8", "--particle-res", "24"),
                       grid=64, frames=40, views=8, render_size=400),
    "quick": Profile("quick", 128, 24, 4, 4, 64,
                     ("--sdf-res", "40", "--sdf-iters", "60", "--iterations", "200",
                      "--n-surface", "3000", "--nv", "4", "--particle-res", "16",
                      "--sdf-rays", "512"),
                     grid=48, frames=16, views=4, render_size=256),
    "tiny": Profile("tiny", 48, 6, 2, 1, 32,
                    ("--sdf-res", "24", "--sdf-iters", "16", "--iterations", "24",
                     "--n-surface", "300", "--nv", "2", "--particle-res", "10",
                     "--sdf-rays", "256"),
                    grid=32, frames=6, views=2, render_size=64, window=3, frame_dt=0.008),
}

# Table 1 of the paper (teapot, table top, legs) as printed: E, nu, density, NACC (Jp0, beta, xi, M).
# The wave speeds sqrt(E / density) of these values (316, 122 and 316 units/s) set how stiff each
# part is against the 4 m/s impact; the scenes in configs/ keep the older, softened set
# (densities x100, table top E x10, elastic legs E 2e6), which simulates ~7x faster but lets the
# table top stretch like a hammock and the legs bend.
TEAPOT_MATERIAL = {"part": 0, "model": "nacc", "E": 5.0e5, "nu": 0.46, "density": 5,
                   "Jp0": 0.98, "beta": 0.5, "xi": 1.0, "M": 2.36}
TABLE_MATERIALS = [
    {"part": 0, "model": "nacc", "E": 1.5e4, "nu": 0.39, "density": 1, "Jp0": 0.99,
     "beta": 0.5, "xi": 1.0, "M": 2.36},
    {"part": 1, "model": "nacc", "E": 1.0e8, "nu": 0.39, "density": 1000, "Jp0": 0.94,
     "beta": 2.0, "xi": 3.0, "M": 2.36},
]


def _model_points(model: Path) -> np.ndarray:
    """Rest positions (model frame) of a trained model's particles.ply."""
    from fracture_gs.recon.model_io import PARTICLES_FILE, read_particles_ply

    path = model / PARTICLES_FILE
    if not path.is_file():
        raise EvaluationError(f"{path}: not found (train the object first)")
    columns = read_particles_ply(str(path))
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
        # Ours opens cracks inside objects, so the torn table top comes apart instead of
        # hanging together by the grid; the mls baseline (PhysGaussian / GIC style) has no such thing.
        "contact": {"mode": mode, "strength": 1.0, "friction": 0.1, "fragments": mode == "collision"},
        "cfl": 0.3,
        "boundaries": [{"type": "ground", "height": ground, "friction": 0.5},
                       {"type": "box", "condition": "slip"}],
        "objects": [
            {"name": "teapot", "model": str(teapot.resolve()),
             "transform": {"scale": round(teapot_scale, 5), "rotate_deg": list(teapot_rotation),
                           "translate": teapot_translate},
             "velocity": [0, 0, -4], "materials": [TEAPOT_MATERIAL]},
            {"name": "table", "model": str(table.resolve()),
             "transform": {"scale": round(table_scale, 5), "translate": table_translate},
             "velocity": [0, 0, 0], "materials": TABLE_MATERIALS},
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
        return self.sim(mode) / ("renders" if fpgo else "renders_nofpgo")

    def save_log(self) -> None:
        write_text_atomic(self.log_path, json.dumps(self.log, indent=2) + "\n")


def _require_success(function: Callable[[], int], what: str) -> None:
    """Run a command-line main(); its stdout goes to the console, a non-zero status stops."""
    status = function()
    if status != 0:
        raise EvaluationError(f"{what} failed with exit status {status} (see above)")


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
    from fracture_gs.data.synthetic.__main__ import main as synthetic_main

    p = demo.profile
    for name in OBJECTS:
        folder = demo.data / name
        if (folder / "transforms_train.json").is_file() and not demo.force:
            print(f"[demo] data: {folder} exists, kept{_dataset_mismatch(folder, p)}")
            continue
        argv = ["--object", name, "--out", str(folder), "--width", str(p.image_size),
                "--height", str(p.image_size), "--n-train", str(p.n_train), "--n-test",
                str(p.n_test), "--spp", str(p.spp), "--grid", str(p.mesh_grid)]
        if demo.force and folder.exists():
            argv.append("--force")
        _require_success(lambda: synthetic_main(argv), f"generating the {name} dataset")


def stage_train(demo: Demo) -> None:
    from fracture_gs.cli.train import main as train_main

    for name in OBJECTS:
        argv = ["-s", str(demo.data / name), "-m", str(demo.model(name)), "-w",
                *demo.profile.train_args, "--checkpoint_every", "0"]
        print(f"[demo] train.py {' '.join(argv)}", flush=True)
        _require_success(lambda: train_main(argv), f"training the {name}")


def stage_scene(demo: Demo) -> None:
    for mode in ("collision", "mls"):
        scene = demo_scene(demo.model("teapot"), demo.model("table"), demo.profile.grid,
                           demo.profile.frames, mode, frame_dt=demo.profile.frame_dt)
        path = demo.scene_path(mode)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, "# written by demo.py: the trained teapot dropped on the "
                          "trained table\n" + yaml.safe_dump(scene, sort_keys=False))
        print(f"[demo] scene: {path}")


def stage_simulate(demo: Demo) -> None:
    from fracture_gs.config.scene import load_scene
    from fracture_gs.experiments.runner import SimJob, run_jobs

    jobs = [SimJob.of(load_scene(demo.scene_path(mode)), demo.sim(mode))
            for mode in ("collision", "mls")]

    def done(result) -> None:
        print(f"[demo] simulate {result.name}: {result.seconds:.0f} s -> {result.out_dir}")
        print(result.log.rstrip())

    run_jobs(jobs, workers=demo.workers, force=True, on_done=done)


def stage_render(demo: Demo) -> None:
    from fracture_gs.cli.render import RenderOptions, render_simulation

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
    from fracture_gs.report.sim_report import evaluate_and_report

    size = demo.profile.render_size
    options = EvalOptions(views=f"orbit:{demo.profile.views}", resolution=(size, size),
                          window=demo.profile.window, device=demo.device)
    networks = MetricNetworks.load(demo.device, demo.weights_dir)
    evaluate_and_report(evaluation_specs(demo), options, networks, demo.out / "evaluation",
                        "Demo: teapot dropped on a table", with_paper=True)


STAGE_FUNCTIONS = {"data": stage_data, "train": stage_train, "scene": stage_scene,
                   "simulate": stage_simulate, "render": stage_render, "evaluate": stage_evaluate}


def stage_outputs(demo: Demo, stage: str) -> list[Path]:
    """Files whose presence shows that ``stage`` finished."""
    if stage == "data":
        return [demo.data / o / "transforms_train.json" for o in OBJECTS]
    if stage == "train":
        return [demo.model(o) / "particles.ply" for o in OBJECTS]
    if stage == "scene":
        return [demo.scene_path(m) for m in ("collision", "mls")]
    if stage == "simulate":
        return [demo.sim(m) / "frames" / f"frame_{demo.profile.frames:05d}.npz"
                for m in ("collision", "mls")]
    if stage == "render":
        return [demo.renders(m, f) / "timing.csv"
                for m, f in (("collision", True), ("collision", False), ("mls", False))]
    return [demo.out / "evaluation" / "report.md"]


def run_demo(demo: Demo) -> dict:
    """Run (or skip) every stage, then print the comparison and where the results are."""
    from fracture_gs.report.sim_report import print_comparison

    prepare_output_folder(demo.out, "--out")
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
        finished = stage in stages and all(p.is_file() for p in stage_outputs(demo, stage))
        if finished and not demo.force and redo_from is None:
            print(f"[demo] {stage}: done earlier ({stages[stage]['seconds']:.0f} s), skipped")
            continue
        redo_from = redo_from or stage   # a redone stage makes every later one stale
        print(f"[demo] {stage} ...", flush=True)
        started = time.perf_counter()
        STAGE_FUNCTIONS[stage](demo)
        stages[stage] = {"seconds": time.perf_counter() - started,
                         "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
        demo.save_log()
    metrics = json.loads((demo.out / "evaluation" / "metrics.json").read_text())
    print()
    print(print_comparison(metrics, with_paper=True))
    print()
    total = sum(s["seconds"] for s in stages.values())
    for stage in STAGES:
        print(f"  {stage:<9} {stages[stage]['seconds']:8.1f} s")
    print(f"  {'total':<9} {total:8.1f} s  (profile {demo.profile.name})")
    video = demo.renders("collision", True) / "video_orbit_00.mp4"
    print(f"[demo] video:  {video}")
    print(f"[demo] report: {demo.out / 'evaluation' / 'report.md'}")
    return metrics


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="demo.py", description="Train a teapot and a table from synthetic photos, drop the "
        "teapot on the table, render it with and without FPGO, simulate the MLS-MPM baseline "
        "and compare them (PSNR / LPIPS / FID).")
    parser.add_argument("--quick", action="store_true", help="the small version (profile quick)")
    parser.add_argument("--profile", choices=sorted(PROFILES), default=None,
                        help="default | quick | tiny (tiny: the test suite's version)")
    parser.add_argument("--out", default=None, help="output folder (default output/demo, "
                        "output/demo_<profile>)")
    parser.add_argument("--data", default=None, help="dataset folder holding teapot/ and table/ "
                        "(default data/ for the default profile, <out>/data otherwise)")
    parser.add_argument("--force", action="store_true", help="redo every stage")
    parser.add_argument("--weights-dir", default=None,
                        help="folder with alexnet.ckpt and default_1.pt (LPIPS / FID weights)")
    parser.add_argument("--workers", type=int, default=1,
                        help="run the two simulations in parallel processes (default 1)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    from fracture_gs.cli.evaluate import device_from_option
    from fracture_gs.cli.exit_codes import run_guarded

    args = build_parser().parse_args(argv)
    profile = PROFILES["quick" if args.quick else (args.profile or "default")]
    out = Path(args.out) if args.out else Path("output") / (
        "demo" if profile.name == "default" else f"demo_{profile.name}")
    data = Path(args.data) if args.data else (Path("data") if profile.name == "default"
                                               else out / "data")

    def run() -> None:
        if args.quick and args.profile not in (None, "quick"):
            raise EvaluationError(f"--quick and --profile {args.profile} contradict each other")
        if args.workers < 1:
            raise EvaluationError(f"--workers {args.workers}: must be >= 1")
        if out.exists() and not out.is_dir():
            raise EvaluationError(f"--out {out}: exists and is not a folder")
        run_demo(Demo(out=out, data=data, profile=profile, force=args.force,
                      device=device_from_option(args.device), weights_dir=args.weights_dir,
                      workers=args.workers))

    return run_guarded(run, f"interrupted; finished stages are kept in {out / 'stages.json'} "
                       "and skipped next time")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
