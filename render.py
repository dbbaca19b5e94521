#!/usr/bin/env python3
"""Render a trained model: ``python render.py -m output/teapot [--skip_train] [--skip_test]``.

(Static renders of a train.py model; see ``fracture_gs.cli.render_model``.)
"""
import sys

from fracture_gs.cli.render_model import main

if __name__ == "__main__":
    sys.exit(main())
