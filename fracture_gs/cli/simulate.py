"""``simulate.py``: run a scene through the Collision-MPM solver (docs/formulas.md §2–§10).

Exit status: 0 on success, 2 on invalid input (one ``error: <key path or file>: <problem>``
line on stderr, nothing simulated: bad scene keys, unreadable files, a grid too large for the
memory, an ``--out`` that is a file, a damaged run for ``--resume``), 1 when the run fails
(blow-up, out of memory, a write error; the frames written so far stay valid and
``--resume``-able), 130 when interrupted.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch

from fracture_gs.cli.output_folder import OutputFolderError, os_error_line, prepare_output_folder
from fracture_gs.config.scene import SceneConfig, SceneError, load_scene
from fracture_gs.mpm.memory import check_scene_memory
from fracture_gs.mpm.output import (CHECKPOINT_FILE, OutputError, SimulationOutput,
                                    diagnostics_row, load_frame, particle_arrays, read_npz)
from fracture_gs.mpm.scene import BuiltScene, build_scene
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
    fracture_energy: float = 0.0  # energy brittle damage took by the last frame


class InvalidInput(ValueError):
    """Bad command-line input; ``key`` names the argument."""

    def __init__(self, key: str, problem: str) -> None:
        self.key = key
        super().__init__(f"{key}: {problem}")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="simulate.py", description="Run a Collision-MPM fracture simulation of a scene.")
    parser.add_argument("--scene", required=True, help="scene YAML (docs/scenes.md)")
    parser.add_argument("--out", default=None,
                        help="output folder (default: output/sims/<scene name>)")
    parser.add_argument("--frames", type=int, default=None,
                        help="number of frames after frame 0 (overrides the scene)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default=None,
                        help="default: cuda when available, else cpu")
    parser.add_argument("--backend", choices=("auto", "cpp", "reference"), default="auto",
                        help="compiled kernels (cpp), PyTorch reference, or auto")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in the output folder from its last frame")
    return parser.parse_args(argv)


def resolve_device(name: str | None) -> torch.device:
    if name is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InvalidInput("--device", "cuda was requested but no CUDA device is available")
    return torch.device(name)


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
                        object_names=built.object_names, backend=backend, device=device, seed=built.seed)


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
    if summary.fracture_energy > 0:
        balance = summary.energy_end + summary.fracture_energy - summary.energy_start
        lines.append(f"  fracture energy {summary.fracture_energy:.4g} taken by damage (energy + fracture energy: "
                     f"{balance:+.4g}, {balance / abs(summary.energy_start) if summary.energy_start else float('nan'):+.2%})")
    lines += [
        f"  fractured      {summary.fractured / max(summary.particles, 1):.2%} "
        f"({summary.fractured} of {summary.particles} particles)",
        f"  clamped        {summary.clamped} particle clamps into the domain (summed over frames)",
    ]
    print("\n".join(lines), file=stream)


def _open_run(config: SceneConfig, built: BuiltScene, output: SimulationOutput, solver: Any,
              resume: bool) -> int:
    """Start a fresh output folder (frame 0) or restore the checkpoint; returns the last
    complete frame."""
    if not resume:
        output.start(config.to_dict(), built.particles)
        row = diagnostics_row(0, solver.state.time, 0, float("nan"), solver.diagnostics())
        output.write_frame(0, solver.state_in_input_order(), row, solver.state_dict(),
                           fragment_id=solver.fragment_ids(), damage=solver.damage_in_input_order())
        return 0
    output.remove_temporaries()
    try:
        checkpoint = output.load_checkpoint()
        output.check_frames(checkpoint.frame)
    except OutputError as exc:
        raise _resume_error(exc) from None
    try:
        solver.load_state_dict(checkpoint.solver_state)
    except (KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise _resume_error(OutputError(f"{output.checkpoint_path}: does not hold this scene's "
                                        f"solver state ({exc})")) from None
    output.write_scene(config.to_dict())
    if not output.frame_complete(checkpoint.frame):  # killed between checkpoint and frame
        output.write_frame(checkpoint.frame, solver.state_in_input_order(), checkpoint.rows[-1],
                           solver.state_dict(), fragment_id=solver.fragment_ids(), damage=solver.damage_in_input_order())
    return checkpoint.frame


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
        fracture_energy=float(col["fracture_energy"][-1]) if "fracture_energy" in col else 0.0)


def run_simulation(config: SceneConfig, out_dir: str | Path, *, device: torch.device,
                   backend: str = "auto", resume: bool = False, progress: bool | None = None,
                   log: TextIO | None = None) -> RunSummary:
    """Build the scene, write the output folder and advance up to ``config.frames`` frames.

    Raises :class:`SceneError` / :class:`InvalidInput` for invalid input (before anything is
    simulated or written) and :class:`SimulationBlowUp` (message naming the frame and time)
    when the run fails; the frames already written, the CSV, the plot and the checkpoint then
    stay valid. ``progress=None`` shows the tqdm bar only on a terminal.
    """
    from tqdm import tqdm

    log = log if log is not None else sys.stdout
    check_output_folder(Path(out_dir))
    check_backend(device, backend)
    check_scene_memory(config, device)
    built = build_scene(config, device)
    for warning in built.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    output = SimulationOutput(out_dir, built.object_names)
    if resume:
        check_resumable(output, config, built)
    solver = create_solver(built, device, backend)
    done = _open_run(config, built, output, solver, resume)

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
            try:
                stats = solver.advance(config.frame_dt)
            except SimulationBlowUp as exc:
                raise SimulationBlowUp(
                    f"simulation blew up while computing frame {frame} "
                    f"(t = {t_start:.5g} .. {t_start + config.frame_dt:.5g} s): {exc}; "
                    f"frames 0..{frame - 1} in {output.root} are valid") from exc
            elapsed = time.perf_counter() - tick
            clamped += int(stats.clamped)
            row = diagnostics_row(frame, solver.state.time, stats.steps, stats.dt_min,
                                  solver.diagnostics())
            output.write_frame(frame, solver.state_in_input_order(), row, solver.state_dict(),
                               fragment_id=solver.fragment_ids(), damage=solver.damage_in_input_order())
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


def _interrupted_message(out_dir: Path | None) -> str:
    if out_dir is not None and (out_dir / CHECKPOINT_FILE).exists():
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
        config = load_scene(args.scene)
        if args.frames is not None:
            config = replace(config, frames=args.frames)
        device = resolve_device(args.device)
        out_dir = out_dir if out_dir is not None else DEFAULT_OUTPUT_ROOT / config.name
        run_simulation(config, out_dir, device=device, backend=args.backend,
                       resume=args.resume)
    except (SceneError, InvalidInput, OutputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except SimulationBlowUp as exc:
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
