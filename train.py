#!/usr/bin/env python3
"""Reconstruct an object from multi-view images: ``python train.py -s data/teapot``.

See ``fracture_gs.cli.train`` (options, exit codes) and docs/training.md.
"""
import sys

from fracture_gs.cli.train import main

if __name__ == "__main__":
    sys.exit(main())
