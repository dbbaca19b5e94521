"""``python -m fracture_gs.data.synthetic --object teapot --out data/teapot``.

Exit status: 0 on success, 2 on invalid input (one ``error: ...`` line naming the option or the
folder: a setting out of range, an ``--out`` that may not be replaced or cannot be made), 1 when
the run fails (a write error such as a full disk, naming the file; nothing half-written is left),
130 when interrupted.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

from fracture_gs.data.synthetic.generator import (GeneratorSettings, check_output_folder,
                                                  generate_dataset)
from fracture_gs.data.synthetic.objects import OBJECT_NAMES
from fracture_gs.io.output_folder import os_error_line


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m fracture_gs.data.synthetic",
        description="Render a synthetic multi-view dataset (NeRF-synthetic layout) of a "
                    "procedural object with parts. Needs Mitsuba 3 (pip install mitsuba).")
    parser.add_argument("--object", required=True, choices=OBJECT_NAMES + ("all",),
                        help="object to generate; 'all' makes one sub-folder per object")
    parser.add_argument("--out", required=True,
                        help="output folder (for --object all: the parent folder)")
    parser.add_argument("--width", type=int, default=400)
    parser.add_argument("--height", type=int, default=400)
    parser.add_argument("--n-train", type=int, default=100)
    parser.add_argument("--n-test", type=int, default=20)
    parser.add_argument("--spp", type=int, default=16,
                        help="samples per pixel (multi-jittered; a square like 16 or 25 is exact)")
    parser.add_argument("--seed", type=int, default=0, help="0 to 2^64 - 1 (default 0)")
    parser.add_argument("--grid", type=int, default=256,
                        help="marching-cubes cells along the object's longest side")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing dataset that this generator wrote (a folder "
                             "with generator.json); other folders are never replaced")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    settings = GeneratorSettings(args.width, args.height, args.n_train, args.n_test, args.spp,
                                 args.seed, args.grid)
    names = OBJECT_NAMES if args.object == "all" else (args.object,)
    outs = [os.path.join(args.out, name) if args.object == "all" else args.out for name in names]
    try:
        settings.validate()
        for out in outs:  # refuse before rendering anything
            check_output_folder(out, args.force)
        for name, out in zip(names, outs):
            summary = generate_dataset(name, out, settings, overwrite=args.force,
                                       progress=not args.quiet)
            print(f"{name}: wrote {out} " + json.dumps(
                {k: summary[k] for k in ("faces", "mesh_seconds", "render_seconds",
                                         "seconds_per_view", "total_seconds")}))
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except FileExistsError as error:  # an --out that this run may not replace
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # writing the dataset failed (disk full, folder removed, ...)
        print(f"error: {os_error_line(error)}", file=sys.stderr)
        return 1
    except (ValueError, RuntimeError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
