"""train.py's pipeline: dataset → SDF → mesh → particles → Gaussians → model folder.

:func:`train` runs the stages in order, timing each (wall and process CPU seconds), and
writes the model folder described in :mod:`fracture_gs.folders.model_folder`. Inputs are checked
before the folder is created; a problem found later (an empty mesh, a parts file that names
no particle) removes what the run wrote. The Gaussian stage writes a checkpoint every
``checkpoint_every`` iterations (the newest one is kept), from which ``start_checkpoint``
continues.
"""
from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, TextIO

import numpy as np
import torch
import trimesh
from tqdm import tqdm

from fracture_gs.bounds import SEED_MAX
from fracture_gs.data import Dataset, DatasetError, load_dataset
from fracture_gs.data.loading import has_test_split
from fracture_gs.data.up import camera_up, level_residual_deg
from fracture_gs.data.parts import PartSpec, assign_part_ids, load_part_spec, single_part_spec
from fracture_gs.folders import model_folder
from fracture_gs.gaussians import GaussianModel, PlyFormatError, write_ply
from fracture_gs.gaussians.model import PARAMETER_NAMES
from fracture_gs.io import model_layout
from fracture_gs.io.atomic import atomic_path
from fracture_gs.io.device import DeviceError, resolve_device
from fracture_gs.io.object_frame import measure_object, write_object_frame
from fracture_gs.io.particles_ply import write_particles_ply
from fracture_gs.recon.carving import carve_hull
from fracture_gs.recon.errors import ReconstructionError
from fracture_gs.recon.gaussian_fit import (FitSettings, FitState, evaluate_views,
                                            fit_gaussians, make_optimizer, new_fit_state)
from fracture_gs.recon.grid import VoxelGrid
from fracture_gs.recon.hull import visual_hull
from fracture_gs.recon.imported import (bind_to_nearest, iteration_of, opacity_field_sdf,
                                        read_imported, unbound_warning)
from fracture_gs.recon.meshing import extract_mesh
from fracture_gs.recon.particles import ParticleSet, sample_particles
from fracture_gs.recon.sdf_refine import RefineSettings, refine_sdf
from fracture_gs.recon.support import cut_sdf, support_cut
from fracture_gs.recon.timing import StageTimer
from fracture_gs.render.camera import cameras_json_entry

ITERATIONS_DEFAULT = 3000
# Learning rates of the Gaussian stage: 3DGS's (FitSettings' defaults, for 30k iterations) and
# the default preset's, raised 4x, 2x, 2x to converge in ~10x fewer iterations.
LEARNING_RATES_3DGS = {name: getattr(FitSettings, name) for name in ("feature_lr", "opacity_lr", "scaling_lr")}
LEARNING_RATES_DEFAULT = {"feature_lr": 1e-2, "opacity_lr": 5e-2, "scaling_lr": 1e-2}
PRESETS: dict[str, dict[str, Any]] = {
    # Sized so that one 400x400, 100-view object finishes in <= 15 minutes on a 2-core CPU.
    "default": {"resolution": 1, "iterations": ITERATIONS_DEFAULT, "sdf_res": 160, "sdf_iters": 300,
                "n_surface": 40_000, "nv": 8, "particle_res": 48, "n_interior": None,
                **LEARNING_RATES_DEFAULT},
    # The paper's sizes (App. A.2): 200k surface and 100k interior particles, full images,
    # 3DGS's schedule and learning rates.
    "paper": {"resolution": 1, "iterations": 30_000, "sdf_res": 256, "sdf_iters": 20_000,
              "n_surface": 200_000, "nv": 8, "particle_res": None, "n_interior": 100_000,
              **LEARNING_RATES_3DGS},
}
NO_MASKS_HINT = ("add a masks/ folder beside images/ (same file names, white = object), or "
                 "start from a trained 3DGS model with --from-ply <point_cloud.ply> --bbox "
                 "XMIN YMIN ZMIN XMAX YMAX ZMAX to build the SDF from its opacity field")


@dataclass
class TrainConfig:
    """Resolved options of one train.py run (3DGS names where 3DGS has the option)."""

    source_path: str
    model_path: str
    resolution: int = 1
    white_background: bool = False
    iterations: int = ITERATIONS_DEFAULT
    sdf_res: int = 160
    sdf_iters: int = 300
    n_surface: int = 40_000
    nv: int = 8
    particle_res: int | None = 48
    n_interior: int | None = None
    shell: float = 0.0               # wall thickness of a hollow body / longest side (0: solid)
    holdout_every: int = 0           # COLMAP / DTU: views 0, k, 2k, ... are the test split
    up: list[float] | None = None    # the object's up in dataset coordinates (None: from the cameras)
    keep_underside: bool = False     # keep what no camera sees below the object (no support cut)
    parts: str | None = None
    sh_degree: int = 3
    device: str = "cpu"
    seed: int = 0
    preset: str = "default"
    min_component: float = 0.005
    max_offset: float = 1.0
    from_ply: str | None = None
    from_sdf: str | None = None
    bbox: list[float] | None = None
    start_checkpoint: str | None = None
    checkpoint_every: int = 1000
    save_iterations: list[int] = field(default_factory=list)
    sdf_rays: int = 1024
    feature_lr: float = LEARNING_RATES_DEFAULT["feature_lr"]
    opacity_lr: float = LEARNING_RATES_DEFAULT["opacity_lr"]
    scaling_lr: float = LEARNING_RATES_DEFAULT["scaling_lr"]
    quiet: bool = False

    def cfg_args(self) -> dict[str, Any]:
        """What cfg_args records: 3DGS's keys first, then ours."""
        options = {"sh_degree": self.sh_degree, "source_path": os.path.abspath(self.source_path),
                   "model_path": self.model_path, "images": "images",
                   "resolution": self.resolution, "white_background": self.white_background,
                   "data_device": self.device, "eval": self.holdout_every > 0 or
                   _has_test_split(self.source_path, 0)}
        options.update({f.name: getattr(self, f.name) for f in fields(self)
                        if f.name not in options and f.name not in ("source_path", "model_path",
                                                                     "quiet")})
        return options


@dataclass
class Inputs:
    """Everything read and validated before the model folder is touched."""

    train: Dataset
    test: Dataset | None
    parts: PartSpec
    parts_source: str
    imported: GaussianModel | None
    checkpoint: dict[str, Any] | None
    geometry: tuple[VoxelGrid, torch.Tensor, torch.Tensor] | None = None


def _has_test_split(source_path: str, holdout_every: int) -> bool:
    try:
        return has_test_split(source_path, holdout_every)
    except DatasetError:
        return False


def read_inputs(config: TrainConfig) -> Inputs:
    """Load and check the dataset, part spec, imported PLY and checkpoint (one-line errors)."""
    train = load_dataset(config.source_path, "train", config.resolution, config.white_background,
                         config.holdout_every)
    test = None
    if _has_test_split(config.source_path, config.holdout_every):
        test = load_dataset(config.source_path, "test", config.resolution,
                            config.white_background, config.holdout_every)
    imported = None
    if config.from_ply is not None:
        imported = read_imported(config.from_ply)
    if train.masks is None and config.from_sdf is None and not (imported is not None
                                                                and config.bbox is not None):
        where = os.path.dirname(train.image_paths[0])
        if imported is not None:
            raise ReconstructionError(f"{where}: the images have no alpha channel and there "
                                      f"are no masks, so --from-ply needs --bbox XMIN YMIN ZMIN "
                                      f"XMAX YMAX ZMAX (the object's box in model coordinates)")
        raise ReconstructionError(f"{where}: the images have no alpha channel and the dataset "
                                  f"has no masks; {NO_MASKS_HINT}")
    if config.parts is not None:
        parts_source = config.parts
        parts = load_part_spec(config.parts)
    elif os.path.isfile(os.path.join(config.source_path, "parts.json")):
        parts_source = os.path.join(config.source_path, "parts.json")
        parts = load_part_spec(parts_source)
    else:
        parts_source, parts = "(one part)", single_part_spec()
    checkpoint = None
    if config.start_checkpoint is not None:
        checkpoint = load_checkpoint(config.start_checkpoint)
    geometry = None
    if config.from_sdf is not None:
        try:
            geometry = load_sdf(config.from_sdf)
        except ReconstructionError as error:
            raise ReconstructionError(f"--from-sdf: {error}") from None
    return Inputs(train, test, parts, parts_source, imported, checkpoint, geometry)


def load_sdf(path: str) -> tuple[VoxelGrid, torch.Tensor, torch.Tensor]:
    """Grid, SDF and hull SDF of an ``sdf.npz`` from an earlier run (``--from-sdf``); a missing or
    unreadable file is a ReconstructionError naming it."""
    if not os.path.isfile(path):
        raise ReconstructionError(f"{path}: file not found")
    try:
        sdf, hull_sdf, origin, voxel = model_folder.read_sdf(path)
    except ValueError as error:
        raise ReconstructionError(f"{path}: {error}") from None
    grid = VoxelGrid(origin, voxel, tuple(int(n) for n in sdf.shape))
    return grid, torch.from_numpy(sdf), torch.from_numpy(hull_sdf)


def check_config(config: TrainConfig) -> None:
    """Range checks of the numeric options; errors name the flag."""
    checks = [("--iterations", config.iterations >= 0, "must be >= 0"),
              ("--sdf-res", config.sdf_res >= 8, "must be >= 8"),
              ("--sdf-iters", config.sdf_iters >= 0, "must be >= 0"),
              ("--n-surface", config.n_surface >= 1, "must be >= 1"),
              ("--nv", config.nv >= 0, "must be >= 0"),
              ("--particle-res", config.particle_res is None or config.particle_res >= 2,
               "must be >= 2"),
              ("--n-interior", config.n_interior is None or config.n_interior >= 1,
               "must be >= 1"),
              ("--shell", 0.0 <= config.shell < 0.5, "must be in [0, 0.5)"),
              ("--holdout-every", config.holdout_every == 0 or config.holdout_every >= 2,
               "must be 0 (no test split) or >= 2"),
              ("--sh-degree", 0 <= config.sh_degree <= 3, "must be 0..3"),
              ("--max-offset", config.max_offset >= 0, "must be >= 0"),
              ("--min-component", 0 <= config.min_component <= 1, "must be in [0, 1]"),
              ("-r", config.resolution == -1 or config.resolution >= 1, "must be >= 1 or -1"),
              ("--feature_lr", config.feature_lr > 0, "must be > 0"),
              ("--opacity_lr", config.opacity_lr > 0, "must be > 0"),
              ("--scaling_lr", config.scaling_lr > 0, "must be > 0"),
              ("--seed", 0 <= config.seed <= SEED_MAX, f"must be within [0, {SEED_MAX}]")]
    for flag, ok, problem in checks:
        if not ok:
            raise ReconstructionError(f"{flag}: {getattr(config, _attribute(flag))} {problem}")
    if config.up is not None and not (len(config.up) == 3 and np.all(np.isfinite(config.up))
                                      and np.linalg.norm(config.up) > 0):
        raise ReconstructionError(f"--up: {config.up} is not a non-zero direction X Y Z")
    if config.bbox is not None:
        lower, upper = np.asarray(config.bbox[:3]), np.asarray(config.bbox[3:])
        if len(config.bbox) != 6 or not np.all(upper > lower):
            raise ReconstructionError(f"--bbox: {config.bbox} is not XMIN YMIN ZMIN XMAX YMAX "
                                      f"ZMAX with max > min")
    try:
        resolve_device(config.device)
    except DeviceError as error:
        raise ReconstructionError(str(error)) from None


def _attribute(flag: str) -> str:
    return {"-r": "resolution"}.get(flag, flag.lstrip("-").replace("-", "_"))


# ----------------------------------------------------------------------------- checkpoints


def load_checkpoint(path: str) -> dict[str, Any]:
    if not os.path.isfile(path):
        raise ReconstructionError(f"{path}: checkpoint not found")
    try:
        content = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # torch raises many types for corrupt files
        raise ReconstructionError(f"{path}: not a readable checkpoint ({type(error).__name__})") \
            from None
    if not isinstance(content, dict) or content.get("format") != "fracture_gs/train-checkpoint-v1":
        raise ReconstructionError(f"{path}: not a train.py checkpoint")
    return content


def save_checkpoint(path: str, state: FitState, particles: ParticleSet, part_id: np.ndarray,
                    timer: StageTimer, log_rows: list[dict], rng: np.random.Generator,
                    summary: dict[str, Any]) -> None:
    content = {"format": "fracture_gs/train-checkpoint-v1", "iteration": state.iteration,
               "gaussians": {k: v.cpu() for k, v in state.model.raw_tensors().items()},
               "optimizer": state.optimizer.state_dict(), "anchors": state.anchors.cpu(),
               "view_order": list(state.view_order),
               "particles": asdict(particles), "part_id": part_id,
               "timings": timer.stages, "log": log_rows, "rng": rng.bit_generator.state,
               "summary": summary}
    with atomic_path(path) as temporary:
        torch.save(content, temporary)


# ----------------------------------------------------------------------------- stages


def _interior_resolution(config: TrainConfig, mesh: trimesh.Trimesh) -> int:
    """Particle lattice resolution: ``particle_res``, or the one that gives about
    ``n_interior`` interior particles at ``nv`` per voxel."""
    if config.n_interior is None or config.nv == 0:
        return int(config.particle_res or 48)
    voxel = (mesh.volume * config.nv / config.n_interior) ** (1.0 / 3.0)
    return max(2, int(round(float(np.max(mesh.extents)) / voxel)))


def surface_colors(dataset: Dataset, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Initial colour of surface points: the pixel colour in the training view that looks
    at each point most head-on (the view is in front of the surface, so it sees the point
    unless another part of the object is in the way)."""
    centres = dataset.camera_centers().double().numpy()
    colors = np.empty((len(points), 3))
    chunk = 1 << 15
    images = dataset.images.cpu().numpy()
    for start in range(0, len(points), chunk):
        p, n = points[start:start + chunk], normals[start:start + chunk]
        towards = centres[None, :, :] - p[:, None, :]
        towards /= np.linalg.norm(towards, axis=-1, keepdims=True)
        best = np.einsum("pvk,pk->pv", towards, n).argmax(axis=1)
        for view in np.unique(best):
            chosen = np.nonzero(best == view)[0]
            camera = dataset.cameras[view]
            uv, _ = camera.project(torch.from_numpy(p[chosen]).float())
            column = uv[:, 0].long().clamp(0, dataset.width - 1).numpy()
            row = uv[:, 1].long().clamp(0, dataset.height - 1).numpy()
            colors[start + chosen] = images[view, row, column]
    return colors


def check_parts(part_id: np.ndarray, spec: PartSpec, source: str, mesh: trimesh.Trimesh) -> None:
    counts = np.bincount(part_id, minlength=spec.num_parts)
    for index, name in enumerate(spec.part_names):
        if counts[index] == 0:
            lower, upper = (np.round(b, 3).tolist() for b in mesh.bounds)
            raise ReconstructionError(
                f"{source}: part {index} ({name!r}) contains no particle of the object "
                f"(its box is {lower} .. {upper} in dataset coordinates); check the rules")


def _progress(total: int, initial: int, desc: str, quiet: bool) -> tqdm:
    return tqdm(total=total, initial=initial, desc=desc, unit="it", disable=quiet,
                dynamic_ncols=True, leave=False, file=sys.stderr)


def build_geometry(config: TrainConfig, inputs: Inputs, timer: StageTimer,
                   device: torch.device, log_rows: list[dict],
                   summary: dict[str, Any]) -> tuple[VoxelGrid, torch.Tensor, torch.Tensor]:
    """Visual hull (or opacity field), stereo carving and the NeuS-style refinement (or the
    SDF of ``--from-sdf``); returns the grid, the final SDF and the hull SDF."""
    if inputs.geometry is not None:
        summary["from_sdf"] = os.path.abspath(config.from_sdf or "")
        return inputs.geometry
    if inputs.train.masks is None:
        assert inputs.imported is not None and config.bbox is not None
        with timer.stage("opacity_field"):
            grid, sdf = opacity_field_sdf(inputs.imported, np.asarray(config.bbox[:3]),
                                          np.asarray(config.bbox[3:]), config.sdf_res,
                                          config.from_ply or "")
        return grid, sdf, sdf
    with timer.stage("visual_hull"):
        hull = visual_hull(inputs.train.to(device), config.sdf_res, device)
    if config.sdf_iters == 0:
        return hull.grid, hull.sdf, hull.sdf
    with timer.stage("stereo_carving"):
        carved, count = carve_hull(inputs.train, hull.grid, hull.sdf)
    summary["carved_nodes"] = count
    settings = RefineSettings(iterations=config.sdf_iters, rays=config.sdf_rays, seed=config.seed)
    bar = _progress(config.sdf_iters, 0, "SDF", config.quiet)

    def progress(row: dict) -> None:
        bar.update(1)
        if row["iteration"] % 10 == 0:
            bar.set_postfix(loss=f"{row['loss']:.4f}", ncc=f"{1 - row['photo']:.3f}")

    with timer.stage("sdf_refinement"):
        try:
            refined = refine_sdf(inputs.train, hull.grid, carved.to(device), settings, device,
                                 progress)
        finally:
            bar.close()
    log_rows.extend(refined.log.rows)
    return hull.grid, refined.sdf, hull.sdf


def train(config: TrainConfig, out: TextIO | None = None) -> dict[str, Any]:
    """Run train.py's pipeline; returns the summary also written to ``timings.json``. The
    summary line goes to ``out`` (the current ``sys.stdout`` when None)."""
    out = out if out is not None else sys.stdout
    check_config(config)
    inputs = read_inputs(config)
    if inputs.imported is not None:  # the model folder holds the imported Gaussians' degree
        config = replace(config, sh_degree=inputs.imported.sh_degree)
    device = resolve_device(config.device)
    folder = model_folder.OutputFolder(config.model_path)
    with model_folder.run_lock(config.model_path):
        try:
            return _train_into(config, inputs, folder, device, out)
        except (ReconstructionError, DatasetError, PlyFormatError):
            folder.discard()
            raise


def _train_into(config: TrainConfig, inputs: Inputs, folder: model_folder.OutputFolder,
                device: torch.device, out: TextIO) -> dict[str, Any]:
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    checkpoint = inputs.checkpoint
    timer = StageTimer(checkpoint["timings"] if checkpoint else None)
    log_rows: list[dict] = list(checkpoint["log"]) if checkpoint else []
    os.makedirs(config.model_path, exist_ok=True)
    model_folder.write_cfg_args(folder.file(model_layout.CFG_ARGS_FILE), config.cfg_args())
    views = [(os.path.splitext(os.path.basename(p))[0], c) for dataset in
             ([inputs.test] if inputs.test is not None else []) + [inputs.train]
             for p, c in zip(dataset.image_paths, dataset.cameras)]
    model_folder.write_json(folder.file(model_layout.CAMERAS_FILE),
                            [cameras_json_entry(index, name, camera)
                             for index, (name, camera) in enumerate(views)])
    summary: dict[str, Any] = dict(checkpoint["summary"]) if checkpoint else {}
    up, up_source = _object_up(config, inputs)
    if checkpoint is None:
        grid, sdf, hull_sdf = build_geometry(config, inputs, timer, device, log_rows, summary)
        if inputs.train.masks is not None and not config.keep_underside:
            with timer.stage("underside"):
                sdf = _cut_unseen_underside(config, inputs, grid, sdf, up, summary, out)
        sdf_path = folder.file(model_layout.SDF_FILE)
        model_folder.write_sdf(sdf_path, sdf, hull_sdf, grid.origin, grid.voxel)
        with timer.stage("marching_cubes"):
            mesh = extract_mesh(sdf, grid, config.min_component,
                                source=f"{sdf_path} (--sdf-res {config.sdf_res})")
            if inputs.train.masks is not None or inputs.geometry is not None:
                summary["hull_volume"] = float(extract_mesh(hull_sdf, grid, config.min_component,
                                                            "visual hull").volume)
        model_folder.write_mesh(folder.file(model_layout.MESH_FILE), mesh)
        summary["mesh_volume"] = float(mesh.volume)
        with timer.stage("particles"):
            particles = sample_particles(mesh, sdf.to(device), grid, config.n_surface, config.nv,
                                         _interior_resolution(config, mesh), rng,
                                         shell=config.shell * float(np.max(mesh.extents)))
            part_id = assign_part_ids(particles.position, inputs.parts)
        check_parts(part_id, inputs.parts, inputs.parts_source, mesh)
    else:
        particles = ParticleSet(**checkpoint["particles"])
        part_id = np.asarray(checkpoint["part_id"])
        rng.bit_generator.state = checkpoint["rng"]
    surface = particles.is_surface
    gaussian_index = np.full(len(particles.position), -1, dtype=np.int64)
    if inputs.imported is not None:
        iteration = iteration_of(config.from_ply or "")
        gaussians = inputs.imported
        gaussian_index[surface] = bind_to_nearest(particles.position[surface],
                                                  gaussians.means.detach().cpu().numpy())
        referenced = np.unique(gaussian_index[surface])
        summary["unbound_gaussians"] = int(gaussians.num_gaussians - len(referenced))
        warning = unbound_warning(gaussian_index[surface], gaussians.num_gaussians)
        if warning is not None:
            print(f"warning: {warning}", file=sys.stderr)
    else:
        gaussians, iteration = _fit(config, inputs, folder, particles, part_id, timer, log_rows,
                                    rng, summary, device, checkpoint)
        particles.position[surface] = gaussians.means.detach().cpu().double().numpy()
        gaussian_index[surface] = np.arange(int(surface.sum()))
    write_ply(folder.file(*model_layout.point_cloud_path(config.model_path, iteration)
                          .split(os.sep)[-3:]), gaussians)
    _write_particles(folder, particles, part_id, gaussian_index, config)
    where = measure_object(particles.position, up, up_source)
    write_object_frame(folder.file(model_layout.OBJECT_FILE), where)
    model_folder.remove_earlier_runs(config.model_path, {iteration, *config.save_iterations})
    with timer.stage("evaluation"):
        summary["train"] = evaluate_views(gaussians, inputs.train, device)
        if inputs.test is not None:
            summary["test"] = evaluate_views(gaussians, inputs.test, device)
    summary.update({"iteration": iteration, "n_surface": particles.num_surface,
                    "n_interior": particles.num_interior,
                    "total_rest_volume": float(particles.volume.sum()),
                    "surface_spacing": particles.surface_spacing,
                    "timings": timer.as_dict()})
    model_folder.write_log_csv(folder.file(model_layout.TRAIN_LOG_FILE), log_rows)
    model_folder.write_json(folder.file(model_layout.TIMINGS_FILE), summary)
    test_text = (f", test PSNR {summary['test']['psnr']:.2f} dB (SSIM {summary['test']['ssim']:.3f},"
                 f" {summary['test']['views']} views)" if "test" in summary else "")
    print(f"[train] {config.model_path}: train PSNR {summary['train']['psnr']:.2f} dB{test_text}; "
          f"{particles.num_surface} surface + {particles.num_interior} interior particles; "
          f"{timer.total()['wall_s']:.0f} s", file=out)
    print(f"[train] object in model coordinates: {where.summary()}", file=out)
    return summary


def _object_up(config: TrainConfig, inputs: Inputs) -> tuple[np.ndarray, str]:
    """The object's up direction and where it came from: ``--up``, else the training cameras
    (:mod:`fracture_gs.data.up`)."""
    if config.up is not None:
        up = np.asarray(config.up, dtype=np.float64)
        return up / np.linalg.norm(up), "--up"
    up, method = camera_up(inputs.train.cameras)
    return up, f"{method}, {level_residual_deg(inputs.train.cameras, up):.1f} deg rms tilt"


def _cut_unseen_underside(config: TrainConfig, inputs: Inputs, grid: VoxelGrid,
                          sdf: torch.Tensor, up: np.ndarray, summary: dict[str, Any],
                          out: TextIO) -> torch.Tensor:
    """``sdf`` cut below the lowest part of the object the training cameras see
    (:mod:`fracture_gs.recon.support`); records and prints the cut when there is one."""
    mesh = extract_mesh(sdf, grid, config.min_component, source="the refined SDF")
    cut = support_cut(mesh, inputs.train.cameras, up, grid.voxel)
    if cut is None:
        return sdf
    summary["underside_cut"] = asdict(cut)
    print(f"[train] no camera sees below {cut.height:.4g} along up: the underside hanging "
          f"{cut.depth:.3g} below it (the silhouettes' keel) is cut flat there "
          f"(--keep-underside keeps it)", file=out)
    return cut_sdf(sdf, grid, cut)


def _fit(config: TrainConfig, inputs: Inputs, folder: model_folder.OutputFolder,
         particles: ParticleSet, part_id: np.ndarray, timer: StageTimer, log_rows: list[dict],
         rng: np.random.Generator, summary: dict[str, Any], device: torch.device,
         checkpoint: dict[str, Any] | None) -> tuple[GaussianModel, int]:
    """The Gaussian stage with periodic checkpoints; returns the model and its iteration."""
    surface = particles.is_surface
    settings = FitSettings(iterations=config.iterations, sh_degree=config.sh_degree,
                           max_offset=config.max_offset, seed=config.seed,
                           feature_lr=config.feature_lr, opacity_lr=config.opacity_lr,
                           scaling_lr=config.scaling_lr,
                           sh_interval=max(1, min(1000, config.iterations // (2 * max(
                               config.sh_degree, 1)))))
    spatial_scale = inputs.train.scene_bounds()[1]
    if checkpoint is None:
        colors = surface_colors(inputs.train, particles.position[surface],
                                particles.normal[surface])
        state = new_fit_state(particles.position[surface], colors, settings, spatial_scale,
                              device)
        model_folder.write_input_ply(folder.file(model_layout.INPUT_PLY), particles.position[surface],
                                 particles.normal[surface], colors)
    else:
        state = _restore_fit(checkpoint, settings, spatial_scale, device)
    bar = _progress(config.iterations, state.iteration, "Gaussians", config.quiet)
    previous = [c for c in model_layout.checkpoints(config.model_path)]

    def on_step(current: FitState, row: dict) -> None:
        bar.update(1)
        if current.iteration % 10 == 0 or current.iteration == config.iterations:
            bar.set_postfix(loss=f"{row['loss']:.4f}", psnr=f"{row['psnr']:.2f}")
            log_rows.append(row)
        if current.iteration in config.save_iterations and current.iteration != config.iterations:
            write_ply(folder.file(*model_layout.point_cloud_path(config.model_path, current.iteration)
                                  .split(os.sep)[-3:]), current.model)
        if config.checkpoint_every > 0 and current.iteration % config.checkpoint_every == 0 \
                and current.iteration < config.iterations:
            path = folder.file(f"chkpnt{current.iteration}.pth")
            save_checkpoint(path, current, particles, part_id, timer, log_rows, rng, summary)
            for _, old in previous:
                if os.path.exists(old) and old != path:
                    os.remove(old)
            previous[:] = [(current.iteration, path)]

    try:
        with timer.stage("gaussians"):
            fit_gaussians(state, inputs.train, settings, particles.surface_spacing, rng, on_step)
    finally:
        bar.close()
    for _, old in previous:  # the finished model replaces the intermediate checkpoints
        if os.path.exists(old):
            os.remove(old)
    return state.model, state.iteration


def _restore_fit(checkpoint: dict[str, Any], settings: FitSettings, spatial_scale: float,
                 device: torch.device) -> FitState:
    tensors = checkpoint["gaussians"]
    model = GaussianModel(*(tensors[name] for name in PARAMETER_NAMES)).to(device)
    if model.sh_degree != settings.sh_degree:
        raise ReconstructionError(f"--sh-degree: the checkpoint was trained with SH degree "
                                  f"{model.sh_degree}, not {settings.sh_degree}")
    optimizer = make_optimizer(model, settings, spatial_scale)
    optimizer.load_state_dict(checkpoint["optimizer"])
    return FitState(model, optimizer, checkpoint["anchors"].to(device),
                    int(checkpoint["iteration"]), list(checkpoint["view_order"]))


def _write_particles(folder: model_folder.OutputFolder, particles: ParticleSet, part_id: np.ndarray,
                     gaussian_index: np.ndarray, config: TrainConfig) -> None:
    comments = {"surface_spacing": particles.surface_spacing,
                "interior_voxel": particles.interior_voxel}
    write_particles_ply(folder.file(model_layout.PARTICLES_FILE), particles.position,
                                 particles.volume, particles.is_surface, part_id, gaussian_index,
                                 comments)
    model_folder.write_json(folder.file(model_layout.PARTICLES_JSON), {
        "frame": "model coordinates = the dataset's world coordinates",
        "surface_spacing": particles.surface_spacing,
        "interior_voxel": particles.interior_voxel,
        "interior_particle_size": particles.interior_voxel / max(config.nv, 1) ** (1.0 / 3.0),
        "nv": config.nv, "shell": config.shell, "n_surface": particles.num_surface,
        "n_interior": particles.num_interior,
        "total_volume": float(particles.volume.sum()),
        "note": "surface_spacing: Poisson-disk radius of the surface particles; "
                "interior_particle_size: voxel / nv^(1/3), the mean spacing of interior "
                "samples (a size for the Gaussians of fractured interior particles)"})
