#!/usr/bin/env python3
"""Render a simulation with Gaussian splatting and FPGO: ``python render.py --sim output/sims/<name>``.

``-m <model>`` renders a trained model instead. See ``fracture_gs.cli.render`` (options, exit
codes) and docs/rendering.md.
"""
import sys

from fracture_gs.cli.render import main

if __name__ == "__main__":
    sys.exit(main())
