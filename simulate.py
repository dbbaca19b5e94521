#!/usr/bin/env python3
"""Run a Collision-MPM fracture simulation: ``python simulate.py --scene configs/two_spheres.yaml``.

See ``fracture_gs.cli.simulate`` (options, exit codes) and docs/simulation.md.
"""
import sys

if __name__ == "__main__":
    try:
        from fracture_gs.cli.simulate import main  # imports torch: a second or two
    except KeyboardInterrupt:
        print("interrupted before the first frame was written", file=sys.stderr)
        sys.exit(130)
    sys.exit(main())
