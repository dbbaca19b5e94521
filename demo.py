#!/usr/bin/env python
"""The one-command demo: teapot and table photos -> trained objects -> a shattering collision, video and metrics (see fracture_gs.cli.demo)."""
import sys

from fracture_gs.cli.demo import main

if __name__ == "__main__":
    sys.exit(main())
