"""Wall-clock and process CPU time per pipeline stage.

The process CPU time (``time.process_time``: all threads of this process) is reported next
to the wall time because the machines this runs on are often shared: wall time alone
mixes our work with other processes'.
"""
from __future__ import annotations

import contextlib
import time
from typing import Iterator


class StageTimer:
    """Accumulates ``{stage: {"wall_s": ..., "cpu_s": ...}}`` in order of first use."""

    def __init__(self, previous: dict[str, dict[str, float]] | None = None) -> None:
        self.stages: dict[str, dict[str, float]] = dict(previous or {})

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            entry = self.stages.setdefault(name, {"wall_s": 0.0, "cpu_s": 0.0})
            entry["wall_s"] += time.perf_counter() - wall
            entry["cpu_s"] += time.process_time() - cpu

    def total(self) -> dict[str, float]:
        return {"wall_s": sum(e["wall_s"] for e in self.stages.values()),
                "cpu_s": sum(e["cpu_s"] for e in self.stages.values())}

    def as_dict(self) -> dict[str, dict[str, float]]:
        rounded = {name: {k: round(v, 2) for k, v in entry.items()}
                   for name, entry in self.stages.items()}
        rounded["total"] = {k: round(v, 2) for k, v in self.total().items()}
        return rounded
