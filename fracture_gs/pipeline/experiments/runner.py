"""Running independent simulations of a sweep: one after another, in ``workers`` local
processes, or on an existing Ray cluster (``ray_address``; Ray is an optional extra).

A job is a resolved scene (``SceneConfig.to_dict()``: plain data with absolute model paths, so
it travels to another process or machine) and the folder to write. A job whose folder already
holds every frame of the same scene is skipped (``force`` re-runs it from scratch: the files the
tools wrote for the earlier run are replaced, other files in the folder stay).
"""
from __future__ import annotations

import io
import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from fracture_gs.config.scene import SceneConfig, parse_scene, read_yaml
from fracture_gs.io.manifest import FolderTaken
from fracture_gs.io.sim_layout import SimLayout


class RunFailed(RuntimeError):
    """A simulation of a sweep failed (blow-up, bad scene); the message names the job."""


@dataclass(frozen=True)
class SimJob:
    """One simulation to run: the resolved scene as plain data and its output folder."""

    scene: dict
    out_dir: str

    @classmethod
    def of(cls, config: SceneConfig, out_dir: Path) -> "SimJob":
        return cls(config.to_dict(), str(out_dir))

    @property
    def name(self) -> str:
        return str(self.scene["name"])


@dataclass(frozen=True)
class JobResult:
    """What a job did: ``skipped`` when the folder already held the complete run."""

    name: str
    out_dir: str
    seconds: float
    skipped: bool
    log: str


def is_complete(job: SimJob) -> bool:
    """The folder holds the same scene and every frame of it."""
    out_dir = Path(job.out_dir)
    layout = SimLayout(out_dir)
    scene_path = layout.scene_path
    if not scene_path.is_file():
        return False
    try:
        written = parse_scene(read_yaml(scene_path), base_dir=out_dir).to_dict()
    except Exception:  # an unreadable folder is simply not complete
        return False
    last = layout.frame_path(int(job.scene["frames"]))
    return written == parse_scene(job.scene).to_dict() and last.is_file()


def run_job(job: SimJob, force: bool = False, threads: int | None = None,
            progress: bool | None = False) -> JobResult:
    """Run one job in this process (the function local workers and Ray tasks call);
    ``progress``: the solver's progress bar (None: only on a terminal)."""
    import torch

    from fracture_gs.pipeline.simulate import run_simulation

    if threads is not None:
        torch.set_num_threads(threads)
    started = time.perf_counter()
    out_dir = Path(job.out_dir)
    if not force and is_complete(job):
        return JobResult(job.name, job.out_dir, 0.0, True, f"{out_dir}: complete, skipped")
    log = io.StringIO()
    try:
        run_simulation(parse_scene(job.scene), out_dir, device=torch.device("cpu"),
                       progress=progress, log=log)
    except FolderTaken:
        raise   # bad input (a file in the way), not a failed simulation
    except Exception as exc:
        raise RunFailed(f"simulation '{job.name}' ({out_dir}): {exc}") from None
    return JobResult(job.name, job.out_dir, time.perf_counter() - started, False, log.getvalue())


def _threads_per_worker(workers: int) -> int:
    return max(1, (os.cpu_count() or 1) // workers)


def run_jobs(jobs: Sequence[SimJob], workers: int = 1, ray_address: str | None = None,
             force: bool = False, on_done: Callable[[JobResult], None] | None = None,
             progress: bool | None = False) -> list[JobResult]:
    """Run every job and return the results in job order (RunFailed on the first failure);
    ``progress``: each local run's progress bar (None: only on a terminal; Ray runs show none)."""
    names = [job.out_dir for job in jobs]
    if len(set(names)) != len(names):
        raise RunFailed("two jobs write the same folder")
    if ray_address is not None:
        results = _run_on_ray(jobs, ray_address, force)
        for result in results:
            if on_done:
                on_done(result)
        return results
    if workers <= 1 or len(jobs) <= 1:
        results = []
        for job in jobs:
            results.append(run_job(job, force, progress=progress))
            if on_done:
                on_done(results[-1])
        return results
    threads = _threads_per_worker(workers)
    by_dir: dict[str, JobResult] = {}
    context = multiprocessing.get_context("spawn")  # no fork of an OpenMP / torch process
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        futures = {pool.submit(run_job, job, force, threads, progress): job for job in jobs}
        for future in as_completed(futures):
            result = future.result()
            by_dir[result.out_dir] = result
            if on_done:
                on_done(result)
    return [by_dir[job.out_dir] for job in jobs]


def _run_on_ray(jobs: Sequence[SimJob], address: str, force: bool) -> list[JobResult]:
    """Each job as one Ray task on the cluster at ``address`` (``local`` starts a local one)."""
    try:
        import ray
    except ImportError:
        raise RunFailed("--ray: Ray is not installed (pip install ray)") from None
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=None if address == "local" else address, ignore_reinit_error=True,
                 log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(run_job)
        return list(ray.get([remote.remote(job, force, 1) for job in jobs]))
    except ray.exceptions.RayTaskError as exc:
        cause = exc.as_instanceof_cause()
        raise RunFailed(str(cause).splitlines()[-1] if str(cause) else str(exc)) from None
    finally:
        if started_here:
            ray.shutdown()
