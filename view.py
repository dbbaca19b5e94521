#!/usr/bin/env python3
"""Look at a simulation in the browser: ``python view.py output/sims/<name>`` (or ``-m <model>``).

A local viser server (default http://127.0.0.1:8080) shows the frames as Gaussian splats. See
``fracture_gs.cli.view`` (options, lifetime, exit codes).
"""
import sys

from fracture_gs.cli.view import main

if __name__ == "__main__":
    sys.exit(main())
