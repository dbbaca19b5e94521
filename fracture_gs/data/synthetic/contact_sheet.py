"""Contact sheet of generated datasets: a few train views per object on one PNG.

``python -m fracture_gs.data.synthetic.contact_sheet data/teapot data/bowl --out docs/objects.png``
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from PIL import Image, ImageDraw


def _composite_on_white(path: str, size: int) -> np.ndarray:
    image = Image.open(path).convert("RGBA").resize((size, size), Image.LANCZOS)
    rgba = np.asarray(image, dtype=np.float32) / 255.0
    rgb = rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])
    return np.round(rgb * 255).astype(np.uint8)


def contact_sheet(dataset_dirs: list[str], views: int = 4, tile: int = 200) -> Image.Image:
    """One row per dataset: ``views`` train images spread over the train set, on white, with
    the object name written in the first tile."""
    rows = []
    for folder in dataset_dirs:
        transforms = os.path.join(folder, "transforms_train.json")
        if not os.path.isfile(transforms):
            raise FileNotFoundError(f"{transforms}: not found (is {folder} a dataset?)")
        with open(transforms, encoding="utf-8") as handle:
            frames = json.load(handle)["frames"]
        picks = np.linspace(0, len(frames) - 1, views).round().astype(int)
        tiles = [_composite_on_white(os.path.join(folder, frames[i]["file_path"] + ".png"), tile)
                 for i in picks]
        row = Image.fromarray(np.concatenate(tiles, axis=1))
        ImageDraw.Draw(row).text((6, 4), os.path.basename(os.path.normpath(folder)),
                                 fill=(0, 0, 0))
        rows.append(np.asarray(row))
    return Image.fromarray(np.concatenate(rows, axis=0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--tile", type=int, default=200)
    args = parser.parse_args(argv)
    try:
        contact_sheet(args.datasets, args.views, args.tile).save(args.out)
    except (OSError, KeyError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
