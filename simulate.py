#!/usr/bin/env python3
"""Run a Collision-MPM fracture simulation: ``python simulate.py --scene configs/two_spheres.yaml``.

See ``fracture_gs.cli.simulate`` (options, exit codes) and SPEC §5.
"""
import sys

from fracture_gs.cli.simulate import main

if __name__ == "__main__":
    sys.exit(main())
