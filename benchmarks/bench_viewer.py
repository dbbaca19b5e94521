"""How long a 200k-Gaussian frame takes to reach the browser in ``view.py`` (≤ 1 s).

Scene: a model folder whose ``--gaussians`` particles (default 200k, a lattice ball) each own an
isotropic Gaussian (SH degree 3), and a simulation folder with ``--frames`` frames in which the
ball moves, shears and a growing half of it is fractured (so FPGO runs).

Two sessions, each with a fresh viewer (empty cache): ``probe_only`` — one websocket client
(``WebsocketProbe`` of fracture_gs/testing/headless_browser.py, a minimal viser client in Python) — and
``with_browser`` — the probe plus headless Chromium (system chromium + chromium-driver, WebGL on
SwiftShader). Every second frame (2, 4, ...; showing a frame prefetches its successor) is shown
for the first time (cold: prepared on demand), then again (warm: from the LRU cache). From the moment the frame slider is set:

* ``prepare_ms``: the frame's Gaussians (SceneGaussians.frame + FPGO, render.py's code path)
  and their conversion to packed splats, in the background thread;
* ``sent_ms``: until the splats are handed to the websocket (server.flush());
* ``delivered_ms``: until the whole splat message (32 bytes per Gaussian), sent after
  ``send_started``, has arrived at the websocket client — what "reaches the browser" means
  for the server and the wire;
* ``browser_echo_ms`` (with the browser): until the browser echoes a camera move queued right
  after the splats (:class:`CameraEcho`); messages are handled in order, so by then the browser
  has received and decoded the splats. An upper bound that includes one browser round trip,
  ``echo_only_ms`` (the same echo with nothing in front of it), which on this CPU is dominated
  by SwiftShader drawing 200k splats in software. Reading pixels back (``get_render``) is no
  measure here: it takes seconds per read-back.

Medians over the frames. The machine is shared (2 cores, several engineers): numbers are
disturbed and reported as such. Usage:
``PYTHONPATH=. python benchmarks/bench_viewer.py [--gaussians 200000] [--frames 7] [--no-browser]``
Prints one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import torch
import yaml

from fracture_gs.gaussians import GaussianModel
from fracture_gs.folders.model_folder import write_model_folder
from fracture_gs.viewer.app import Viewer, ViewerOptions
from fracture_gs.viewer.sources import SimulationSource

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root
from fracture_gs.testing.headless_browser import HeadlessBrowser, WebsocketProbe, find_chromium, wait_for  # noqa: E402

TARGET_MS = 1000.0
WINDOW_SIZE = (480, 360)


def ball(count: int) -> tuple[np.ndarray, float]:
    """About ``count`` lattice points in a ball of radius 0.2 around (0.5, 0.5, 0.5)."""
    spacing = 0.2 * (4.0 / 3.0 * math.pi / count) ** (1.0 / 3.0)
    axis = np.arange(-0.2, 0.2 + 1e-9, spacing)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    return grid[np.linalg.norm(grid, axis=1) <= 0.2] + 0.5, spacing


def write_scene(root: Path, count: int, frames: int) -> tuple[Path, int]:
    """Model + simulation folders (see the module docstring); returns the sim folder and N."""
    points, spacing = ball(count)
    n = points.shape[0]
    rng = np.random.default_rng(0)
    colours = torch.tensor(0.2 + 0.6 * (points - points.min(0)) / np.ptp(points, 0),
                           dtype=torch.float32)
    model = GaussianModel.from_points(torch.tensor(points - 0.5, dtype=torch.float32), colours,
                                      sh_degree=3, isotropic=True, initial_opacity=0.9)
    with torch.no_grad():
        model.log_scales.fill_(float(np.log(0.7 * spacing)))
    write_model_folder(root / "model", points - 0.5, np.full(n, spacing ** 3, np.float32),
                       np.ones(n, bool), np.arange(n), model, spacing=spacing)
    sim = root / "sim"
    (sim / "frames").mkdir(parents=True)
    scene = {"name": "bench_viewer", "domain": {"min": [0, 0, 0], "max": [1, 1, 1], "grid": 32},
             "frames": frames, "frame_dt": 0.01, "gravity": [0, 0, -9.8],
             "objects": [{"name": "ball", "model": str(root / "model"),
                          "transform": {"translate": [0.5, 0.5, 0.5]},
                          "materials": [{"part": 0, "model": "elastic", "E": 1e4, "nu": 0.3,
                                         "density": 1}]}]}
    (sim / "scene.yaml").write_text(yaml.safe_dump(scene, sort_keys=False))
    np.savez(sim / "particles.npz", rest_x=points.astype(np.float32),
             obj_id=np.zeros(n, np.int32), is_surface=np.ones(n, bool),
             gaussian_index=np.arange(n), rest_volume=np.full(n, spacing ** 3, np.float32),
             mass=np.ones(n, np.float32), part_id=np.zeros(n, np.int32))
    for frame in range(frames):
        strain = 0.02 * frame * rng.normal(size=(n, 3, 3))
        fractured = points[:, 0] > 0.5 + 0.2 * (1.0 - frame / max(frames - 1, 1)) - 1e-9
        x = points + [0.0, 0.0, -0.01 * frame] + np.where(fractured[:, None], 0.3 * spacing *
                                                         rng.normal(size=(n, 3)), 0.0)
        np.savez(sim / "frames" / f"frame_{frame:05d}.npz", x=x.astype(np.float32),
                 v=np.zeros((n, 3), np.float32),
                 F_E=(np.eye(3) + strain).astype(np.float32), alpha=np.zeros(n, np.float32),
                 fractured=fractured if frame else np.zeros(n, bool))
    return sim, n


class CameraEcho:
    """A browser round trip that needs no read-back of pixels: move the client's camera a
    little and wait until the browser reports the new camera. Messages are handled in order, so
    the echo of a camera set right after a frame arrives after the browser decoded that frame."""

    def __init__(self, client) -> None:
        self.client = client
        self._target: np.ndarray | None = None
        self._event = threading.Event()
        self._sign = 1.0
        client.camera.on_update(self._on_camera)

    def _on_camera(self, camera) -> None:
        target = self._target
        if target is not None and np.allclose(camera.position, target, atol=1e-4):
            self._event.set()

    def __call__(self, timeout: float = 120.0) -> None:
        self._sign = -self._sign
        self._event.clear()
        self._target = np.asarray(self.client.camera.position) + [0.0, 0.0, 1e-3 * self._sign]
        self.client.camera.position = self._target
        if not self._event.wait(timeout):
            raise RuntimeError("the browser did not echo the camera")


def measure(viewer: Viewer, probe: WebsocketProbe, echo: CameraEcho | None,
            frame: int) -> dict[str, float]:
    """Set the slider to ``frame`` and time it (see the module docstring)."""
    viewer.cache.wait_idle(120)      # the previous frame's prefetch of its successor is done
    started = time.perf_counter()
    viewer.gui["frame"].value = frame
    if not viewer.wait_until_shown(frame, timeout=120):
        raise RuntimeError(f"frame {frame} was not shown within 120 s")
    sent = time.perf_counter()
    prepared = viewer.cache.request((frame, True)).result()
    delivered = probe.wait_for_message(int(0.9 * 32 * prepared.gaussians), viewer.send_started,
                                       120)
    if delivered is None:
        raise RuntimeError(f"frame {frame} never reached the websocket client")
    row = {"frame": frame, "gaussians": prepared.gaussians, "prepare_ms": prepared.prepare_ms,
           "sent_ms": (sent - started) * 1e3, "delivered_ms": (delivered - started) * 1e3}
    if echo is not None:
        echo()
        row["browser_echo_ms"] = (time.perf_counter() - started) * 1e3
        tick = time.perf_counter()
        echo()
        row["echo_only_ms"] = (time.perf_counter() - tick) * 1e3
    return row


def session(source: SimulationSource, browser: bool) -> dict[str, list[dict[str, float]]]:
    """A fresh viewer (empty cache) with a websocket probe and, with ``browser``, headless
    Chromium: every frame after 0 shown cold, then warm."""
    viewer = Viewer(source, ViewerOptions(port=0, keep_alive=True))
    url = viewer.start()
    probe = WebsocketProbe(int(url.rsplit(":", 1)[1]))
    chromium = None
    try:
        echo = None
        if browser:
            chromium = HeadlessBrowser(*WINDOW_SIZE)
            chromium.open(url)
            if not wait_for(lambda: viewer.client_count > 1, 120):
                raise RuntimeError("the browser did not connect")
        if not viewer.wait_until_shown(0, timeout=120):
            raise RuntimeError("frame 0 was not shown")
        if browser:
            clients = viewer.server.get_clients()
            echo = CameraEcho(clients[max(clients)])   # the browser connected after the probe
            echo()
        frames = source.frames[2::2]   # each shown frame prefetches its successor: skip those
        cold = [measure(viewer, probe, echo, frame) for frame in frames]
        warm = []
        for frame in frames:
            viewer.gui["frame"].value = source.frames[0]   # away from it first (cached)
            viewer.wait_until_shown(source.frames[0], timeout=120)
            warm.append(measure(viewer, probe, echo, frame))
        return {"cold": cold, "warm": warm}
    finally:
        if chromium is not None:
            chromium.close()
        probe.close()
        viewer.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gaussians", type=int, default=200_000)
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--no-browser", action="store_true", help="websocket probe only")
    args = parser.parse_args()
    browser = not args.no_browser
    if browser and find_chromium() is None:
        print(json.dumps({"error": "no system chromium / chromedriver (or --no-browser)"}))
        return 2
    with tempfile.TemporaryDirectory() as scratch:
        sim, count = write_scene(Path(scratch), args.gaussians, args.frames)
        source = SimulationSource(sim, torch.device("cpu"))
        runs = {"probe_only": session(source, browser=False)}
        if browser:
            runs["with_browser"] = session(source, browser=True)

    def summary(rows: list[dict[str, float]]) -> dict[str, float]:
        return {key: round(statistics.median(row[key] for row in rows), 1)
                for key in rows[0] if key not in ("frame", "gaussians")}

    result = {
        "particles": count,
        "gaussians_per_frame": int(statistics.median(r["gaussians"]
                                                     for r in runs["probe_only"]["cold"])),
        "payload_mb": round(32 * count / 1e6, 2), "frames_measured": len(runs["probe_only"]["cold"]),
        "target_ms": TARGET_MS,
        **{name: {temperature: summary(rows) for temperature, rows in run.items()}
           for name, run in runs.items()},
        "cold_delivered_within_target":
            statistics.median(r["delivered_ms"] for r in runs["probe_only"]["cold"]) <= TARGET_MS,
        "torch_threads": torch.get_num_threads(),
        "load_average": [round(v, 2) for v in os.getloadavg()],
        "note": "shared 2-core machine (load average above), browser on SwiftShader: timings "
                "are disturbed",
        "rows": runs,
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
