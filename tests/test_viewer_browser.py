"""view.py in a real browser: a tiny two-sphere collision, simulated here, served by the viewer and
opened in headless Chromium (system chromium + chromium-driver, WebGL on SwiftShader). Asserts
on screenshots: the objects cover >= 1 % of the pixels, and moving the frame slider through
viser's Python handle changes the picture. Closing the browser ends the viewer after the grace
period, with no thread left behind. Skipped only when Chromium or its driver is absent."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from fracture_gs.config.scene import read_yaml
from fracture_gs.render.frame_gaussians import FLAT_PALETTE
from fracture_gs.viewer.app import Viewer, ViewerOptions
from fracture_gs.testing.headless_browser import HeadlessBrowser, colour_coverage, find_chromium, wait_for
from fracture_gs.viewer.sources import SimulationSource
from render_scenes import simulate_quietly

pytestmark = pytest.mark.skipif(find_chromium() is None,
                                reason="no system Chromium / chromedriver (apt-get install "
                                "chromium chromium-driver)")

REPO = Path(__file__).resolve().parents[1]
MIN_COVERAGE = 0.01        # acceptance: the objects cover >= 1 % of the pixels
MIN_CHANGED = 0.005        # pixels that change when the slider moves two frames


def tiny_collision() -> dict:
    """The demo (configs/two_spheres.yaml) made tiny: a 16³ grid, coarse spheres, two frames in
    which they approach by 8 cm."""
    scene = read_yaml(REPO / "configs" / "two_spheres.yaml")
    scene.update(name="tiny_view", frames=2, frame_dt=0.01)
    scene["domain"]["grid"] = 16
    for obj, x, vx in zip(scene["objects"], (0.33, 0.67), (4.0, -4.0)):
        obj["primitive"].update(radius=0.12, particles_per_cell=4)
        obj["transform"]["translate"][0] = x
        obj["velocity"] = [vx, 0.0, 0.0]
    return scene


@pytest.fixture(scope="module")
def tiny_sim(tmp_path_factory) -> Path:
    return simulate_quietly(tmp_path_factory.mktemp("viewer_browser") / "sim", tiny_collision())


def _canvas(browser: HeadlessBrowser) -> np.ndarray:
    image = browser.screenshot()
    box = browser.canvas_box()
    if box is None:
        return image
    left, top, right, bottom = box
    return image[max(top, 0):bottom, max(left, 0):right]


def test_viewer_in_headless_chromium(tiny_sim: Path):
    before = {t for t in threading.enumerate() if t.is_alive()}
    viewer = Viewer(SimulationSource(tiny_sim, torch.device("cpu")),
                    ViewerOptions(port=0, grace_seconds=1.0))
    url = viewer.start()
    colours = np.asarray(FLAT_PALETTE[:2])   # primitives are drawn in the flat palette
    try:
        with HeadlessBrowser(800, 600) as browser:
            browser.open(url)
            assert wait_for(lambda: viewer.client_count > 0, 60), "the page never connected"
            assert viewer.wait_until_shown(0, timeout=60)
            assert wait_for(lambda: colour_coverage(_canvas(browser), colours) >= MIN_COVERAGE,
                            60, interval=0.5), \
                f"splats cover {colour_coverage(_canvas(browser), colours):.4f} of the canvas"
            time.sleep(1.0)   # let the splat sort settle before the reference picture
            first = _canvas(browser)
            coverage = colour_coverage(first, colours)
            assert coverage >= MIN_COVERAGE

            viewer.gui["frame"].value = 2
            assert viewer.wait_until_shown(2, timeout=60)

            def changed() -> float:
                now = _canvas(browser)
                if now.shape != first.shape:
                    return 1.0
                return float((np.abs(now.astype(np.int32) - first).sum(-1) > 30).mean())

            assert wait_for(lambda: changed() >= MIN_CHANGED, 60, interval=0.5), \
                f"moving the slider changed {changed():.4f} of the pixels"
            print(f"objects cover {coverage:.4f} of the canvas; frame 0 -> 2 changed "
                  f"{changed():.4f} of its pixels")
        # the browser is gone: the viewer asks to stop after the grace period
        assert viewer.stop_requested.wait(30), "the viewer kept running after the browser left"
    finally:
        viewer.stop()
    assert wait_for(lambda: not ({t for t in threading.enumerate() if t.is_alive()} - before), 10)
