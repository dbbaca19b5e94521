"""Clients of the viewer for tests, the latency benchmark and ``docs/viewer.png``: a headless
Chromium (the system's, via selenium) that opens the viewer and takes screenshots, and
:class:`WebsocketProbe`, a minimal viser client in Python that records what arrives.

WebGL runs on the CPU through SwiftShader (``--use-angle=swiftshader``), so no GPU is needed.
Nothing is downloaded: the browser and its driver are Debian's ``chromium`` and
``chromium-driver`` (``apt-get install chromium chromium-driver``).
"""
from __future__ import annotations

import asyncio
import io
import shutil
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")
DRIVER_NAMES = ("chromedriver",)
SWIFTSHADER_FLAGS = ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                     "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                     "--ignore-gpu-blocklist", "--hide-scrollbars", "--mute-audio")


def find_chromium() -> tuple[str, str] | None:
    """Paths of the Chromium binary and its chromedriver, or None when either is missing."""
    browser = next((path for name in CHROMIUM_NAMES if (path := shutil.which(name))), None)
    driver = next((path for name in DRIVER_NAMES if (path := shutil.which(name))), None)
    if browser is None or driver is None:
        return None
    return browser, driver


class HeadlessBrowser:
    """One headless Chromium window of ``width`` × ``height`` CSS pixels (context manager)."""

    def __init__(self, width: int = 960, height: int = 720) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service

        found = find_chromium()
        if found is None:
            raise RuntimeError("no system Chromium / chromedriver (apt-get install chromium "
                               "chromium-driver)")
        browser, driver = found
        options = Options()
        options.binary_location = browser
        for flag in SWIFTSHADER_FLAGS:
            options.add_argument(flag)
        options.add_argument(f"--window-size={width},{height}")
        self.driver: Any = webdriver.Chrome(options=options, service=Service(driver))
        self.driver.set_window_size(width, height)

    def __enter__(self) -> "HeadlessBrowser":
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def open(self, url: str) -> None:
        self.driver.get(url)

    def dismiss_notifications(self) -> None:
        """Close viser's toasts (e.g. "Software WebGL rendering detected" under SwiftShader)."""
        from selenium.webdriver.common.by import By

        for button in self.driver.find_elements(By.CSS_SELECTOR,
                                                ".mantine-Notification-closeButton"):
            try:
                button.click()
            except Exception:   # a toast that closed itself meanwhile
                pass

    def screenshot(self) -> np.ndarray:
        """The page as RGB uint8 (H, W, 3)."""
        from PIL import Image

        png = self.driver.get_screenshot_as_png()
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def save_screenshot(self, path: str | Path) -> None:
        from PIL import Image

        Image.fromarray(self.screenshot()).save(str(path))

    def canvas_box(self) -> tuple[int, int, int, int] | None:
        """(left, top, right, bottom) of the WebGL canvas in screenshot pixels, or None."""
        from selenium.webdriver.common.by import By

        canvases = self.driver.find_elements(By.TAG_NAME, "canvas")
        if not canvases:
            return None
        canvas = max(canvases, key=lambda c: c.size["width"] * c.size["height"])
        ratio = float(self.driver.execute_script("return window.devicePixelRatio || 1"))
        left, top = canvas.location["x"] * ratio, canvas.location["y"] * ratio
        return (int(left), int(top), int(left + canvas.size["width"] * ratio),
                int(top + canvas.size["height"] * ratio))

    def close(self) -> None:
        if self.driver is not None:
            self.driver.quit()
            self.driver = None


def wait_for(predicate, timeout: float, interval: float = 0.25) -> bool:
    """Poll ``predicate()`` until it is true (True) or ``timeout`` seconds pass (False)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


def colour_coverage(image: np.ndarray, colours: np.ndarray, tolerance: float = 40.0) -> float:
    """Fraction of pixels within ``tolerance`` (0..255 RGB distance) of any of ``colours``
    (K,3 in 0..1)."""
    pixels = image.reshape(-1, 1, 3).astype(np.float32)
    targets = np.asarray(colours, np.float32).reshape(1, -1, 3) * 255.0
    distance = np.linalg.norm(pixels - targets, axis=2).min(axis=1)
    return float((distance <= tolerance).mean())


class WebsocketProbe:
    """A minimal viser client on its own thread: connects to ``ws://host:port``, reports a camera
    (viser counts a client as connected from its first camera message, as the web client sends
    right away) and records the arrival time (``time.perf_counter``) and size of every message
    until :meth:`close`."""

    CAMERA = {"type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0],
              "position": [0.0, 0.0, 3.0], "fov": 1.0, "near": 0.01, "far": 100.0,
              "image_height": 480, "image_width": 640, "look_at": [0.0, 0.0, 0.0],
              "up_direction": [0.0, 0.0, 1.0]}

    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = 30.0) -> None:
        self.arrivals: list[tuple[float, int]] = []
        self._condition = threading.Condition()
        self._connected = threading.Event()
        self._closing: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run(host, port)),
                                        name="websocket-probe", daemon=True)
        self._thread.start()
        if not self._connected.wait(timeout):
            self.close()
            raise RuntimeError(f"could not connect to ws://{host}:{port}: {self._error}")

    async def _run(self, host: str, port: int) -> None:
        import msgspec
        import viser
        import websockets

        self._loop = asyncio.get_running_loop()
        self._closing = asyncio.Event()
        try:
            async with websockets.connect(f"ws://{host}:{port}", max_size=None,
                                          subprotocols=[f"viser-v{viser.__version__}"]) as ws:
                await ws.send(msgspec.msgpack.encode(self.CAMERA))
                self._connected.set()
                closing = asyncio.ensure_future(self._closing.wait())
                while not self._closing.is_set():
                    receive = asyncio.ensure_future(ws.recv())
                    done, _ = await asyncio.wait({receive, closing},
                                                 return_when=asyncio.FIRST_COMPLETED)
                    if receive not in done:
                        receive.cancel()
                        break
                    message = receive.result()
                    with self._condition:
                        self.arrivals.append((time.perf_counter(), len(message)))
                        self._condition.notify_all()
        except Exception as exc:   # reported by the constructor or ignored after close
            self._error = exc

    def wait_for_message(self, min_bytes: int, after: float, timeout: float) -> float | None:
        """Arrival time of the first message of at least ``min_bytes`` that arrived after
        ``after`` (perf_counter), or None after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self._condition:
            while True:
                for arrived, size in self.arrivals:
                    if arrived >= after and size >= min_bytes:
                        return arrived
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._condition.wait(left)

    def close(self) -> None:
        """Disconnect and end the thread."""
        if self._loop is not None and self._closing is not None:
            try:
                self._loop.call_soon_threadsafe(self._closing.set)
            except RuntimeError:   # the loop already ended
                pass
        self._thread.join(10)


__all__ = ["HeadlessBrowser", "WebsocketProbe", "SWIFTSHADER_FLAGS", "colour_coverage", "find_chromium", "wait_for"]
