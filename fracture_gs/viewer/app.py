"""The viewer: a local viser server that shows a :class:`~fracture_gs.viewer.sources.FrameSource`
as Gaussian splats, with a frame slider, play / pause and speed, FPGO on/off, per-object
visibility, a fractured-particle highlight, a colour per fragment (connected piece) and the
current frame's diagnostics.

Threads (all ended by :meth:`Viewer.stop`; the test checks that none is left):

* viser's server thread (websocket + HTTP for the bundled web client) and its callback pool;
* ``viewer-loop``: shows the frame the GUI asks for (the newest request wins; stale ones are
  skipped), advances the frame while playing, and applies the disconnect policy;
* ``viewer-frames``: prepares frames for :class:`~fracture_gs.viewer.cache.FrameCache`.

Lifetime policy: the viewer runs until Ctrl-C, or — unless ``keep_alive`` — until the last
browser tab has been gone for ``grace_seconds`` (a page reload within that time keeps it
running). Before the first browser connects it waits indefinitely.
"""
from __future__ import annotations

import errno
import math
import socket
import threading
import time
from concurrent.futures import CancelledError
from dataclasses import dataclass
from typing import Any

import numpy as np

from fracture_gs.render.views import ORBIT_FOV_DEG, bounds_sphere, orbit_views
from fracture_gs.viewer.cache import FrameCache
from fracture_gs.viewer.sources import FrameSource
from fracture_gs.viewer.splats import SplatFrame

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
PLAY_FPS_RANGE = (1, 60)
PREFETCH_AHEAD = 4           # frames prepared ahead of the one shown while playing
THREAD_JOIN_SECONDS = 5.0


class PortInUseError(OSError):
    """The requested port cannot be bound (the message is one line naming host and port)."""


@dataclass
class ViewerOptions:
    """How the viewer serves (the parsed command line)."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    keep_alive: bool = False
    grace_seconds: float = 10.0
    play_fps: float = 10.0
    cache_frames: int = 32
    fpgo: bool = True
    start_frame: int | None = None
    zoom: float = 1.0            # initial camera this many times closer than render.py's orbit


def check_port_free(host: str, port: int) -> None:
    """Raise :class:`PortInUseError` when ``host:port`` cannot be bound (``port`` 0 always can).

    viser itself silently moves on to the next free port; a user who typed ``--port`` (or opened
    the default URL) would then look at another viewer, so we refuse instead.
    """
    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise PortInUseError(f"--host {host}: cannot resolve the address ({exc.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as the server binds
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise PortInUseError(f"--port {port}: {host}:{port} is already in use (another "
                                     "viewer?); pick a free one with --port N") from None
            raise PortInUseError(f"--host {host} --port {port}: cannot listen there "
                                 f"({exc.strerror})") from None


class Viewer:
    """A running viewer of ``source`` (see the module docstring). Use :meth:`start`, then
    :meth:`run` (blocks) or drive it from code (tests) and call :meth:`stop`."""

    def __init__(self, source: FrameSource, options: ViewerOptions | None = None) -> None:
        self.source = source
        self.options = options if options is not None else ViewerOptions()
        if self.options.cache_frames < 1:
            raise ValueError(f"cache_frames must be >= 1, got {self.options.cache_frames}")
        self.cache: FrameCache[tuple[int, bool], SplatFrame] = FrameCache(
            source.prepare, self.options.cache_frames)
        self._condition = threading.Condition()
        self._stop = threading.Event()
        self.stop_requested = threading.Event()   # set by the disconnect policy
        self._shown: tuple[int, bool, bool, bool, bool] | None = None   # (frame, fpgo, highlight, pieces, damage)
        self._shown_frame: SplatFrame | None = None
        self._dirty = True
        self._playing = False
        self._next_tick = 0.0
        self._clients = 0
        self._ever_connected = False
        self._gone_since: float | None = None
        self._threads_before: set[threading.Thread] = set()
        self._loop: threading.Thread | None = None
        self._nodes: list[Any] = []
        self.server: Any = None
        self.gui: dict[str, Any] = {}
        self.last_error: str | None = None
        self.send_started = 0.0          # perf_counter when the last frame began to be sent
        self.url = ""

    # ------------------------------------------------------------------ start / stop

    def start(self) -> str:
        """Bind the port, build the GUI, start the loop; returns the URL to open."""
        import viser

        options = self.options
        check_port_free(options.host, options.port)
        self._threads_before = set(threading.enumerate())
        server = viser.ViserServer(host=options.host, port=options.port, verbose=False)
        if options.port != 0 and server.get_port() != options.port:   # lost a race for it
            server.stop()
            raise PortInUseError(f"--port {options.port}: {options.host}:{options.port} is "
                                 "already in use; pick a free one with --port N")
        self.server = server
        try:
            server.gui.configure_theme(control_width="medium", show_share_button=False)
            self._set_up_camera()
            self._build_gui()
            server.on_client_connect(self._on_connect)
            server.on_client_disconnect(self._on_disconnect)
            self._loop = threading.Thread(target=self._run_loop, name="viewer-loop", daemon=True)
            self._loop.start()
        except BaseException:
            self.stop()
            raise
        host = "127.0.0.1" if options.host in ("0.0.0.0", "") else options.host
        self.url = f"http://{host}:{server.get_port()}"
        return self.url

    def run(self) -> str:
        """Block until Ctrl-C or the disconnect policy ends the viewer; then stop it. Returns
        why it ended ("interrupted" or "browser gone")."""
        reason = "browser gone"
        try:
            while not self.stop_requested.wait(0.2):
                pass
        except KeyboardInterrupt:
            reason = "interrupted"
        finally:
            self.stop()
        return reason

    def stop(self) -> None:
        """Stop playing, the loop, the frame worker and the server, then wait (5 s at most in
        all) for every thread started since :meth:`start` — viser's callback pool winds down
        only after its ``stop()`` returns."""
        if self._stop.is_set():
            return
        self._stop.set()
        with self._condition:
            self._condition.notify_all()
        if self._loop is not None:
            self._loop.join(THREAD_JOIN_SECONDS)
        self.cache.close()
        if self.server is not None:
            self.server.stop()
        deadline = time.monotonic() + THREAD_JOIN_SECONDS
        current = threading.current_thread()
        for thread in threading.enumerate():
            if thread not in self._threads_before and thread is not current:
                thread.join(max(0.0, deadline - time.monotonic()))

    # ------------------------------------------------------------------ GUI

    def _set_up_camera(self) -> None:
        bounds = self.source.bounds
        up = bounds.up / np.linalg.norm(bounds.up)
        axis = int(np.argmax(np.abs(up)))
        if abs(up[axis]) > 0.999:
            self.server.scene.set_up_direction(("+" if up[axis] > 0 else "-") + "xyz"[axis])
        centre, radius = bounds_sphere(np.stack([bounds.lower, bounds.upper]))
        # render.py's orbit:12 camera 2 (60° round from orbit_00, 20° up): objects that collide
        # along a horizontal axis are seen almost side by side, with some depth
        camera = orbit_views(12, centre, max(radius, 1e-3), 1, 1, up=up)[2].camera
        position = camera.center.double().cpu().numpy()
        position = centre + (position - centre) / max(self.options.zoom, 1e-3)
        initial = self.server.initial_camera
        initial.position = tuple(position)
        initial.look_at = tuple(centre)
        initial.up = tuple(up)
        initial.fov = math.radians(ORBIT_FOV_DEG)
        initial.near = max(1e-4, 0.01 * radius)
        initial.far = 100.0 * (radius + float(np.linalg.norm(position - centre)))

    def _build_gui(self) -> None:
        gui, source, options = self.server.gui, self.source, self.options
        frames = source.frames
        start = options.start_frame if options.start_frame is not None else frames[0]
        with gui.add_folder("Playback"):
            slider = gui.add_slider("frame", min=frames[0], max=max(frames[-1], frames[0] + 1),
                                    step=1, initial_value=start, disabled=len(frames) < 2)
            play = gui.add_button("Play", disabled=len(frames) < 2)
            pause = gui.add_button("Pause", visible=False)
            speed = gui.add_slider("speed (frames/s)", min=PLAY_FPS_RANGE[0],
                                   max=PLAY_FPS_RANGE[1], step=1,
                                   initial_value=int(np.clip(round(options.play_fps),
                                                             *PLAY_FPS_RANGE)))
            loop = gui.add_checkbox("loop", initial_value=True)
        with gui.add_folder("Display"):
            fpgo = gui.add_checkbox("FPGO (fracture surfaces)", initial_value=options.fpgo,
                                    visible=source.has_fracture)
            highlight = gui.add_checkbox("highlight fractured", initial_value=False,
                                         visible=source.has_fracture)
            pieces = gui.add_checkbox("colour by piece", initial_value=False,
                                      visible=source.has_pieces,
                                      hint="each fragment (connected piece, frames' fragment_id) in "
                                           "its own colour, largest first; pieces below 1 % grey")
            damage = gui.add_checkbox("colour by damage", initial_value=False,
                                      visible=source.has_damage,
                                      hint="brittle damage from black (intact) to yellow (cracked through)")
        with gui.add_folder("Objects"):
            visible = [gui.add_checkbox(name, initial_value=True) for name in source.object_names]
        with gui.add_folder("Frame"):
            numbers = {name: gui.add_number(label, 0, disabled=True, step=step)
                       for name, label, step in (("gaussians", "Gaussians", 1),
                                                 ("fpgo_gaussians", "FPGO Gaussians", 1),
                                                 ("fractured_particles", "fractured particles", 1),
                                                 ("prepare_ms", "prepare (ms)", 0.1))}
            status = gui.add_text("status", "starting", disabled=True)
        diagnostics = {}
        if source.diagnostics(frames[0]):
            with gui.add_folder("Diagnostics"):
                for name, label in (("time", "time (s)"), ("momentum", "|p|"), ("px", "p_x"),
                                    ("py", "p_y"), ("pz", "p_z"), ("kinetic", "kinetic energy"),
                                    ("elastic", "elastic energy"),
                                    ("gravitational", "gravitational energy"),
                                    ("total_energy", "total energy")):
                    diagnostics[name] = gui.add_number(label, 0.0, disabled=True, step=1e-6)
        self.gui = {"frame": slider, "play": play, "pause": pause, "speed": speed, "loop": loop,
                    "fpgo": fpgo, "highlight": highlight, "pieces": pieces, "damage": damage, "objects": visible,
                    "numbers": numbers,
                    "status": status, "diagnostics": diagnostics}
        slider.on_update(lambda _: self._mark_dirty())
        fpgo.on_update(lambda _: self._mark_dirty())
        highlight.on_update(lambda _: self._mark_dirty())
        pieces.on_update(lambda _: self._mark_dirty())
        damage.on_update(lambda _: self._mark_dirty())
        for checkbox in visible:
            checkbox.on_update(lambda _: self._apply_visibility())
        play.on_click(lambda _: self.set_playing(True))
        pause.on_click(lambda _: self.set_playing(False))

    def set_playing(self, playing: bool) -> None:
        """Start or pause playback (what the Play / Pause buttons do); playing from the last
        frame starts over."""
        frames = self.source.frames
        if playing and self._shown is not None and self._shown[0] == frames[-1]:
            self.gui["frame"].value = frames[0]
        with self._condition:
            self._playing = playing
            self._next_tick = time.monotonic()
            self._condition.notify_all()
        self.gui["play"].visible = not playing
        self.gui["pause"].visible = playing

    def _mark_dirty(self) -> None:
        with self._condition:
            self._dirty = True
            self._condition.notify_all()

    def _wanted(self) -> tuple[int, bool, bool, bool, bool]:
        frame = int(self.gui["frame"].value)
        if frame not in self.source.frames:   # the slider may span a gap: nearest frame
            frame = min(self.source.frames, key=lambda f: abs(f - frame))
        return frame, bool(self.gui["fpgo"].value) and self.source.has_fracture, \
            bool(self.gui["highlight"].value), bool(self.gui["pieces"].value), bool(self.gui["damage"].value)

    # ------------------------------------------------------------------ clients

    def _on_connect(self, _client: Any) -> None:
        with self._condition:
            self._clients += 1
            self._ever_connected = True
            self._gone_since = None

    def _on_disconnect(self, _client: Any) -> None:
        with self._condition:
            self._clients = max(0, self._clients - 1)
            if self._clients == 0:
                self._gone_since = time.monotonic()
            self._condition.notify_all()

    @property
    def client_count(self) -> int:
        with self._condition:
            return self._clients

    # ------------------------------------------------------------------ the loop

    def _run_loop(self) -> None:
        while not self._stop.is_set():
            with self._condition:
                timeout = 0.25
                if self._playing:
                    timeout = min(timeout, max(0.0, self._next_tick - time.monotonic()))
                if not self._dirty and not self._stop.is_set():
                    self._condition.wait(timeout)
                dirty, self._dirty = self._dirty, False
                playing = self._playing
                gone = self._gone_since
            if self._stop.is_set():
                break
            if not self.options.keep_alive and self._ever_connected and gone is not None and \
                    time.monotonic() - gone >= self.options.grace_seconds:
                self.stop_requested.set()
            if playing and time.monotonic() >= self._next_tick:
                self._advance()
                dirty = True
            if dirty:
                self._show_wanted()

    def _advance(self) -> None:
        frames = self.source.frames
        current = self._shown[0] if self._shown is not None else frames[0]
        position = frames.index(current) if current in frames else 0
        if position + 1 >= len(frames) and not self.gui["loop"].value:
            self.set_playing(False)
            return
        following = frames[(position + 1) % len(frames)]
        self._next_tick = time.monotonic() + 1.0 / max(float(self.gui["speed"].value), 1e-3)
        self.gui["frame"].value = following   # its callback marks the view dirty

    def _show_wanted(self) -> None:
        key = self._wanted()
        if key == self._shown:   # e.g. the slider callback of a frame the loop already showed
            return
        frame_key = key[:2]
        try:
            future = self.cache.request(frame_key)
        except RuntimeError:   # closed while stopping
            return
        frames = self.source.frames
        position = frames.index(key[0])
        ahead = PREFETCH_AHEAD if self._playing else 1   # scrubbing: the next frame is likely
        self.cache.prefetch((frames[(position + k) % len(frames)], key[1])
                            for k in range(1, min(ahead, len(frames) - 1) + 1))
        while not self._stop.is_set():
            try:
                prepared = future.result(timeout=0.1)
                break
            except TimeoutError:
                if self._wanted() != key:   # the user moved on; show the newest request
                    self._mark_dirty()
                    return
            except CancelledError:
                self._mark_dirty()
                return
            except Exception as exc:   # a broken frame file: report it in the GUI, keep serving
                self.last_error = f"frame {key[0]}: {exc}"
                print(f"viewer: {self.last_error}", flush=True)
                self.gui["status"].value = self.last_error
                self._shown = key
                self._notify_shown()
                return
        else:
            return
        self._send(prepared, highlight=key[2], pieces=key[3], damage=key[4])
        self.gui["status"].value = f"frame {key[0]} shown"
        self._shown, self._shown_frame = key, prepared
        self._notify_shown()

    def _notify_shown(self) -> None:
        with self._condition:
            self._condition.notify_all()

    def _send(self, prepared: SplatFrame, highlight: bool, pieces: bool = False, damage: bool = False) -> None:
        server = self.server
        self.send_started = time.perf_counter()
        with server.atomic():
            for index, splats in enumerate(prepared.objects):
                if len(splats) == 0:
                    if index < len(self._nodes):
                        self._nodes[index].visible = False
                    continue
                if index >= len(self._nodes) or self._nodes[index] is None:
                    rgba = splats.rgba
                    node = server.scene.add_gaussian_splats(
                        f"/objects/{index}", centers=splats.centers,
                        covariances=splats.covariances, rgbs=rgba[:, :3], opacities=rgba[:, 3:],
                        scale=1.0 / prepared.unit_scale)
                    self._nodes.extend([None] * (index + 1 - len(self._nodes)))
                    self._nodes[index] = node
                self._nodes[index].buffer = splats.packed(highlight, pieces, damage)
            self._apply_visibility(prepared)
            self._update_numbers(prepared)
        server.flush()

    def _apply_visibility(self, prepared: SplatFrame | None = None) -> None:
        prepared = prepared if prepared is not None else self._shown_frame
        if prepared is None:
            return
        for index, node in enumerate(self._nodes):
            if node is not None:
                node.visible = bool(self.gui["objects"][index].value) and \
                    len(prepared.objects[index]) > 0

    def _update_numbers(self, prepared: SplatFrame) -> None:
        numbers = self.gui["numbers"]
        numbers["gaussians"].value = prepared.gaussians
        numbers["fpgo_gaussians"].value = prepared.fpgo_gaussians
        numbers["fractured_particles"].value = prepared.fractured_particles
        numbers["prepare_ms"].value = round(prepared.prepare_ms, 1)
        values = self.source.diagnostics(prepared.index)
        for name, handle in self.gui["diagnostics"].items():
            if name in values and math.isfinite(values[name]):
                handle.value = values[name]

    # ------------------------------------------------------------------ for tests and benchmarks

    @property
    def shown(self) -> tuple[int, bool, bool, bool] | None:
        """(frame, fpgo, highlight, pieces, damage) currently sent to the browsers, or None before the
        first."""
        with self._condition:
            return self._shown

    def wait_until_shown(self, frame: int, timeout: float, fpgo: bool | None = None) -> bool:
        """Wait until ``frame`` (with FPGO ``fpgo`` if given) has been sent; True if it was."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while True:
                shown = self._shown
                if shown is not None and shown[0] == frame and (fpgo is None or shown[1] == fpgo):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._condition.wait(left)


__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "PortInUseError", "Viewer", "ViewerOptions",
           "check_port_free"]
