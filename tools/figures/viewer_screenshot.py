"""A screenshot of ``view.py`` for the docs: the viewer serves a simulation, headless Chromium
(system chromium + chromium-driver, WebGL on SwiftShader) opens it at one frame and the page is
saved as a PNG (GUI panel included).

Usage: python tools/figures/viewer_screenshot.py --sim output/sims/two_spheres \
           --frame 10 --out docs/viewer.png [--size 1280 800] [--zoom 1.5] [--highlight] \
           [--pieces] [--no-fpgo]
Prints one JSON line (what it wrote).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the package

import numpy as np
import torch

from fracture_gs.viewer.app import Viewer, ViewerOptions
from fracture_gs.testing.headless_browser import HeadlessBrowser, find_chromium, wait_for
from fracture_gs.viewer.sources import SimulationSource


def drawn_fraction(browser: HeadlessBrowser) -> float:
    """Share of canvas pixels that are not the white background (0 while the page is too busy
    drawing in software to answer)."""
    from selenium.common.exceptions import TimeoutException

    try:
        image = browser.screenshot()
    except TimeoutException:
        return 0.0
    box = browser.canvas_box()
    if box is not None:
        image = image[box[1]:box[3], box[0]:box[2]]
    return float((image.astype(np.int32).sum(-1) < 3 * 235).mean())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sim", required=True)
    parser.add_argument("--frame", type=int, default=None, help="default: the last frame")
    parser.add_argument("--out", default="docs/viewer.png")
    parser.add_argument("--size", type=int, nargs=2, default=(1280, 800), metavar=("W", "H"))
    parser.add_argument("--highlight", action="store_true", help="fractured particles in magenta")
    parser.add_argument("--pieces", action="store_true",
                        help="colour by piece (frames with fragment_id, any recent simulate.py run)")
    parser.add_argument("--no-fpgo", dest="fpgo", action="store_false")
    parser.add_argument("--zoom", type=float, default=1.0,
                        help="move the camera this many times closer than the initial view")
    parser.add_argument("--settle", type=float, default=5.0,
                        help="seconds to let the browser sort and draw the splats")
    args = parser.parse_args()
    if find_chromium() is None:
        print("error: no system chromium / chromedriver (apt-get install chromium "
              "chromium-driver)", file=sys.stderr)
        return 2
    source = SimulationSource(args.sim, torch.device("cpu"))
    if args.pieces and not source.has_pieces:
        print(f"error: --pieces: the frames of {args.sim} have no fragment_id", file=sys.stderr)
        return 2
    frame = args.frame if args.frame is not None else source.frames[-1]
    viewer = Viewer(source, ViewerOptions(port=0, keep_alive=True, fpgo=args.fpgo,
                                          start_frame=frame, zoom=args.zoom))
    url = viewer.start()
    try:
        viewer.gui["highlight"].value = args.highlight
        viewer.gui["pieces"].value = args.pieces
        with HeadlessBrowser(*args.size) as browser:
            browser.open(url)
            if not wait_for(lambda: viewer.client_count > 0, 120) or \
                    not viewer.wait_until_shown(frame, timeout=120):
                print("error: the browser did not connect or the frame was not shown",
                      file=sys.stderr)
                return 1
            wait_for(lambda: drawn_fraction(browser) > 0.01, 120, interval=1.0)
            time.sleep(args.settle)
            browser.dismiss_notifications()
            time.sleep(1.0)
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            browser.save_screenshot(args.out)
            covered = drawn_fraction(browser)
    finally:
        viewer.stop()
    print(json.dumps({"out": args.out, "sim": str(args.sim), "frame": frame, "fpgo": args.fpgo,
                      "highlight": args.highlight, "pieces": args.pieces, "drawn_fraction": round(covered, 4)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
