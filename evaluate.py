#!/usr/bin/env python
"""Evaluate simulations, trained models and the paper's experiments (see fracture_gs.cli.evaluate)."""
import sys

from fracture_gs.cli.evaluate import main

if __name__ == "__main__":
    sys.exit(main())
