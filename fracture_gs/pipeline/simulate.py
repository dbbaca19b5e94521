"""The simulate stage: a scene through the Collision-MPM solver into a simulation folder
(layout :mod:`fracture_gs.io.sim_layout`).

The folder is locked while a run writes it (a second run into it stops with
:class:`~fracture_gs.io.lock.FolderBusy`). A fresh run writes only where no file is in the way
that the tools did not write in this folder (:func:`~fracture_gs.io.manifest.claim_folder`), never
over its own scene file, and first removes the files the tools wrote for an earlier run (frames,
renders, evaluation), keeping every other file.
"""
from __future__ import annotations

import os
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch

from fracture_gs._backend import KernelBoundError
from fracture_gs.config.scene import SceneConfig, SceneError
from fracture_gs.folders.run_record import RunRecord, model_change, model_identity, new_run_id
from fracture_gs.folders.sim_reader import OutputError, load_frame, read_npz
from fracture_gs.folders.sim_writer import SimulationOutput, diagnostics_row
from fracture_gs.io.lock import folder_lock
from fracture_gs.io.output_folder import OutputFolderError, prepare_output_folder
from fracture_gs.io.sim_layout import LOCK_FILE
from fracture_gs.mpm.memory import check_scene_memory
from fracture_gs.mpm.scene import BuiltScene, build_scene
from fracture_gs.mpm.snapshot import frame_arrays, particle_arrays
from fracture_gs.mpm.substeps import check_substeps
from fracture_gs.mpm.types import SimulationBlowUp

DEFAULT_OUTPUT_ROOT = Path("output") / "sims"


@dataclass
class RunSummary:
    """What a call of :func:`run_simulation` did (also printed as the final summary)."""

    out_dir: Path
    first_frame: int             # first frame computed by this call
    last_frame: int              # last complete frame in the folder
    steps: int                   # substeps of all frames 0..last_frame
    dt_min: float                # smallest CFL substep (frame-end remainders excluded)
    mean_dt: float               # simulated time / substeps
    wall_time: float             # seconds spent in this call's frames
    momentum_drift: float        # |p(last) - p(0)|
    momentum_scale: float        # Σ m |v| at frame 0 (reference for the drift)
    momentum_balance: float      # |p(last) - p(0) - J|, J the impulse of gravity and boundaries
    external_impulse: float      # |J| at the last frame
    energy_start: float
    energy_end: float
    fractured: int
    particles: int
    clamped: int                 # particles clamped into the domain, summed over frames
    dissipated_energy: float = 0.0  # energy the material updates (brittle damage) dissipated by the last frame


class InvalidInput(ValueError):
    """Bad command-line input; ``key`` names the argument."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        super().__init__(f"{key}: {problem}")


def check_backend(device: torch.device, backend: str) -> None:
    """InvalidInput when ``--backend cpp`` is asked for but the kernels are not built."""
    from fracture_gs._backend import use_compiled

    try:
        use_compiled(device, backend)
    except RuntimeError as exc:
        raise InvalidInput("--backend", str(exc)) from None


def create_solver(built: BuiltScene, device: torch.device, backend: str) -> Any:
    """A ``CollisionMPM`` for the built scene (imported here: the solver is the heavy part)."""
    from fracture_gs.mpm.solver import CollisionMPM

    return CollisionMPM(built.particles, built.materials, built.domain, contact=built.contact,
                        boundaries=built.boundaries, gravity=built.gravity, cfl=built.cfl,
                        object_names=built.object_names, backend=backend, device=device, seed=built.seed,
                        rigid_objects=built.rigid_objects)


def first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """Key path of the first place two plain YAML values differ, or None if equal."""
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for key in list(a) + [k for k in b if k not in a]:
            sub = f"{path}.{key}" if path else str(key)
            if key not in a or key not in b:
                return sub
            found = first_difference(a[key], b[key], sub)
            if found is not None:
                return found
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return path or "<scene>"
        for i, (x, y) in enumerate(zip(a, b)):
            found = first_difference(x, y, f"{path}[{i}]")
            if found is not None:
                return found
        return None
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and \
            not isinstance(a, bool) and not isinstance(b, bool):
        return None if float(a) == float(b) else (path or "<scene>")
    return None if a == b else (path or "<scene>")


def check_output_folder(out_dir: Path) -> None:
    """InvalidInput unless ``out_dir`` is a folder that files can be written into, or can be
    created as one (checked before anything is built, so a bad ``--out`` costs nothing; the
    check leaves no folder behind)."""
    try:
        prepare_output_folder(out_dir, "--out", keep=False)
    except OutputFolderError as exc:
        raise InvalidInput(exc.option, exc.problem) from None


def _resume_error(exc: OutputError) -> SceneError:
    return SceneError("--resume", f"{exc}; start the run again without --resume")


def check_resumable(output: SimulationOutput, config: SceneConfig, built: BuiltScene) -> None:
    """SceneError unless the folder holds a run of the same scene and particles whose files
    can be read."""
    if not output.checkpoint_path.exists() or not output.scene_path.exists():
        raise SceneError("--resume", f"{output.root} holds no run to resume "
                         f"(no {output.checkpoint_path.name})")
    stored = output.read_scene()
    current = config.to_dict()
    if isinstance(stored, dict):
        stored = {k: v for k, v in stored.items() if k != "frames"}
    current.pop("frames")
    diff = first_difference(stored, current)
    if diff is not None:
        raise SceneError("--resume", f"the scene differs from {output.scene_path} at '{diff}'")
    try:
        saved = read_npz(output.particles_path)
    except OutputError as exc:
        raise _resume_error(exc) from None
    now = particle_arrays(built.particles)
    same = all(k in saved and saved[k].shape == now[k].shape and np.array_equal(saved[k], now[k])
               for k in ("rest_x", "mass", "obj_id"))
    if not same:
        raise SceneError("--resume", f"the particles differ from {output.particles_path} "
                         "(model files changed?)")


def scene_models(config: SceneConfig) -> dict[str, dict[str, Any]]:
    """:func:`model_identity` of each object's model, by object name (InvalidInput naming the
    object when a model file cannot be read)."""
    models = {}
    for index, obj in enumerate(config.objects):
        if obj.model is not None:
            try:
                models[obj.name] = model_identity(obj.model)
            except OSError as exc:
                raise InvalidInput(f"objects[{index}].model",
                                   f"{exc.filename or obj.model}: cannot be read "
                                   f"({exc.strerror or exc})") from None
    return models


def check_models_unchanged(record: RunRecord, config: SceneConfig) -> None:
    """SceneError (``--resume``) when a model changed since the run in the folder started."""
    for index, obj in enumerate(config.objects):
        recorded = record.models.get(obj.name)
        if obj.model is not None and recorded is not None:
            change = model_change(obj.name, recorded, obj.model)
            if change is not None:
                raise SceneError("--resume", f"objects[{index}].model: {change}; start the run "
                                 "again without --resume")


def check_scene_not_overwritten(config: SceneConfig, output: SimulationOutput) -> None:
    """InvalidInput when the scene file the run was given is the folder's own scene.yaml, which
    the run would write over."""
    source = config.source
    if source is not None and output.scene_path.exists() and source.exists() and \
            os.path.samefile(source, output.scene_path):
        raise InvalidInput("--out", f"{output.root} holds the scene file {source} itself, which "
                           "the run would write over; copy the scene elsewhere or choose "
                           "another --out")


def _print_summary(summary: RunSummary, stream: TextIO) -> None:
    rel = summary.momentum_drift / summary.momentum_scale if summary.momentum_scale > 0 \
        else float("nan")
    balance_rel = summary.momentum_balance / max(summary.momentum_scale, summary.external_impulse, 1e-30)
    d_energy = summary.energy_end - summary.energy_start
    rel_e = d_energy / abs(summary.energy_start) if summary.energy_start != 0 else float("nan")
    frames_done = summary.last_frame - summary.first_frame + 1
    rate = frames_done / summary.wall_time if summary.wall_time > 0 else float("nan")
    lines = [
        f"done: frames {summary.first_frame}..{summary.last_frame} in {summary.out_dir}",
        f"  steps          {summary.steps} (mean dt {summary.mean_dt:.3g} s, smallest "
        f"CFL step {summary.dt_min:.3g} s)",
        f"  wall time      {summary.wall_time:.2f} s ({rate:.2f} frames/s)",
        f"  momentum drift |p_end - p_0| = {summary.momentum_drift:.4g} "
        f"({rel:.3g} of sum m|v| at frame 0; gravity and boundaries change it legitimately)",
        f"  momentum balance |p_end - p_0 - J| = {summary.momentum_balance:.4g} "
        f"(J = impulse of gravity and boundaries, |J| = {summary.external_impulse:.4g}; "
        f"{balance_rel:.3g} relative)",
        f"  energy change  {summary.energy_start:.6g} -> {summary.energy_end:.6g} "
        f"({d_energy:+.4g}, {rel_e:+.2%})",
    ]
    if summary.dissipated_energy > 0:
        balance = summary.energy_end + summary.dissipated_energy - summary.energy_start
        lines.append(f"  dissipated     {summary.dissipated_energy:.4g} taken by damage (energy + dissipated: "
                     f"{balance:+.4g}, {balance / abs(summary.energy_start) if summary.energy_start else float('nan'):+.2%})")
    lines += [
        f"  fractured      {summary.fractured / max(summary.particles, 1):.2%} "
        f"({summary.fractured} of {summary.particles} particles)",
        f"  clamped        {summary.clamped} particle clamps into the domain (summed over frames)",
    ]
    print("\n".join(lines), file=stream)


def _open_run(config: SceneConfig, built: BuiltScene, output: SimulationOutput, solver: Any,
              resume: bool, log: TextIO) -> int:
    """Start a fresh output folder (frame 0) or restore the checkpoint; returns the last
    complete frame."""
    models = scene_models(config)
    if not resume:
        removed = output.clear_earlier_run()
        if removed:
            print(f"{output.root}: replacing the earlier run (removed the {removed} files the tools "
                  "wrote for it; other files are kept)", file=log)
        output.start(config.to_dict(), particle_arrays(built.particles),
                     RunRecord(run=new_run_id(), models=models))
        row = diagnostics_row(0, solver.state.time, 0, float("nan"), solver.diagnostics())
        output.write_frame(0, _frame_arrays(solver), row, solver.state_dict())
        return 0
    output.remove_temporaries()
    try:
        checkpoint = output.load_checkpoint()
        output.check_frames(checkpoint.frame)
        output.resume_record(checkpoint, models)
    except OutputError as exc:
        raise _resume_error(exc) from None
    check_models_unchanged(output.record, config)
    output.adopt_frames(checkpoint.frame)
    try:
        solver.load_state_dict(checkpoint.solver_state)
    except (KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise _resume_error(OutputError(f"{output.checkpoint_path}: does not hold this scene's "
                                        f"solver state ({exc})")) from None
    stored = output.read_scene()
    if config.frames > int(stored.get("frames", 0) if isinstance(stored, dict) else 0):
        check_scene_not_overwritten(config, output)   # the run grows: the scene says so
        output.write_scene(config.to_dict())
    if not output.frame_recorded(checkpoint.frame):  # killed between checkpoint and record
        output.write_frame(checkpoint.frame, _frame_arrays(solver), checkpoint.rows[-1],
                           solver.state_dict())
    return checkpoint.frame


def _frame_arrays(solver: Any) -> dict[str, np.ndarray]:
    """The arrays of the solver's current frame, in the particles' input order."""
    return frame_arrays(solver.state_in_input_order(), solver.fragment_ids(),
                        solver.frame_fields_in_input_order())


def _summarise(output: SimulationOutput, n_particles: int, first: int, done: int,
               wall: float, clamped: int) -> RunSummary:
    """Summary numbers from the diagnostics rows of frames 0..done."""
    rows = np.asarray(output.rows, dtype=np.float64)
    col = {name: rows[:, i] for i, name in enumerate(output.columns)}
    p0 = np.array([col["px"][0], col["py"][0], col["pz"][0]])
    p1 = np.array([col["px"][-1], col["py"][-1], col["pz"][-1]])
    impulse = np.array([col[f"impulse_{a}"][-1] for a in "xyz"])
    start = load_frame(output.frame_path(0))
    mass = read_npz(output.particles_path)["mass"].astype(np.float64)
    scale = float(np.sum(mass * np.linalg.norm(start["v"].astype(np.float64), axis=1)))
    steps, dts = col["steps"][1:], col["dt_min"][1:]
    return RunSummary(
        out_dir=output.root, first_frame=min(first, done), last_frame=done,
        steps=int(steps.sum()), dt_min=float(np.nanmin(dts)) if dts.size else float("nan"),
        mean_dt=float(col["time"][-1] / steps.sum()) if steps.sum() > 0 else float("nan"),
        wall_time=wall, momentum_drift=float(np.linalg.norm(p1 - p0)), momentum_scale=scale,
        momentum_balance=float(np.linalg.norm(p1 - p0 - impulse)),
        external_impulse=float(np.linalg.norm(impulse)),
        energy_start=float(col["total_energy"][0]), energy_end=float(col["total_energy"][-1]),
        fractured=int(col["fractured"][-1]), particles=n_particles, clamped=clamped,
        dissipated_energy=float(col["dissipated_energy"][-1]) if "dissipated_energy" in col else 0.0)


def run_simulation(config: SceneConfig, out_dir: str | Path, *, device: torch.device,
                   backend: str = "auto", resume: bool = False, progress: bool | None = None,
                   log: TextIO | None = None) -> RunSummary:
    """Build the scene, write the output folder and advance up to ``config.frames`` frames.

    Raises :class:`SceneError` / :class:`InvalidInput` for invalid input (before anything is
    simulated or written), :class:`~fracture_gs.io.lock.FolderBusy` when another run writes the
    folder, :class:`~fracture_gs.io.manifest.FolderTaken` when a file the tools did not write is
    in the way, and :class:`SimulationBlowUp` (message naming the frame and time) when the run
    fails; the frames already written, the CSV, the plot and the checkpoint then stay valid.
    ``progress=None`` shows the tqdm bar only on a terminal.
    """
    log = log if log is not None else sys.stdout
    check_output_folder(Path(out_dir))
    check_backend(device, backend)
    check_scene_memory(config, device)
    built = build_scene(config, device)
    check_substeps(config, built)
    for warning in built.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    with folder_lock(out_dir, LOCK_FILE, "simulate.py", "simulation folder"):
        return _run_locked(config, built, out_dir, device, backend, resume, progress, log)


def _run_locked(config: SceneConfig, built: BuiltScene, out_dir: str | Path, device: torch.device,
                backend: str, resume: bool, progress: bool | None, log: TextIO) -> RunSummary:
    """:func:`run_simulation` once the folder's lock is held."""
    from tqdm import tqdm

    output = SimulationOutput(out_dir, built.object_names)
    if resume:
        check_resumable(output, config, built)
    else:
        check_scene_not_overwritten(config, output)
        output.claim(config.frames)
    solver = create_solver(built, device, backend)
    done = _open_run(config, built, output, solver, resume, log)

    first = done + 1
    if first > config.frames:
        print(f"{output.root} already holds frames 0..{done}; nothing to simulate", file=log)
    clamped = 0
    started = time.perf_counter()
    bar = tqdm(total=config.frames, initial=min(done, config.frames), unit="frame",
               desc=config.name, disable=None if progress is None else not progress,
               dynamic_ncols=True)
    try:
        for frame in range(first, config.frames + 1):
            t_start = solver.state.time
            tick = time.perf_counter()
            span = (f"frame {frame} (t = {t_start:.5g} .. {t_start + config.frame_dt:.5g} s)")
            try:
                stats = solver.advance(config.frame_dt)
            except SimulationBlowUp as exc:
                raise SimulationBlowUp(
                    f"simulation blew up while computing {span}: {exc}; "
                    f"frames 0..{frame - 1} in {output.root} are valid") from exc
            except KernelBoundError as exc:
                raise SimulationBlowUp(
                    f"a kernel refused its input while computing {span}: {exc}; "
                    f"frames 0..{frame - 1} in {output.root} are valid") from exc
            elapsed = time.perf_counter() - tick
            clamped += int(stats.clamped)
            row = diagnostics_row(frame, solver.state.time, stats.steps, stats.dt_min,
                                  solver.diagnostics())
            output.write_frame(frame, _frame_arrays(solver), row, solver.state_dict())
            done = frame
            bar.update(1)
            bar.set_postfix(substeps_s=f"{stats.steps / max(elapsed, 1e-9):.0f}",
                            dt=f"{config.frame_dt / max(stats.steps, 1):.2e}")
    finally:
        bar.close()
        output.write_plot()
    summary = _summarise(output, len(built.particles), first, done,
                         time.perf_counter() - started, clamped)
    _print_summary(summary, log)
    return summary
