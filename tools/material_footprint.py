"""Where each material model's identifiers stand: the source files of the package and the kernels
(``fracture_gs/`` without its stage layer ``pipeline/``, and ``csrc/``) that name a model's own
identifiers, per model. A model is meant to live in its class, its law header and the two registries
(``fracture_gs/materials/__init__.py``, ``csrc/common/material_registry.h``): at most ``LIMIT`` files.

Identifiers only: names in Python code (``tokenize``), and in C++ once comments and string literals
are stripped; words in comments and docstrings do not count. A model's identifiers are the names with
its own name as a word in them (``BrittleMaterial``, ``kModelNacc``, ``is_nacc``, ``VonMisesModel``)
and, for the brittle model, ``crack_normal`` and ``particle_strength``.

    python tools/material_footprint.py            # prints JSON: per model, its file count and files
    python tools/material_footprint.py --check    # exit 1 if a model stands in more than LIMIT files
"""
from __future__ import annotations

import argparse
import io
import json
import re
import sys
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 4
# Identifier patterns of each model, matched inside an identifier where a word starts (at its start,
# after "_" or as a capitalised part: "is_nacc", "kModelNacc", "NACCMaterial", not "fibonacci").
PATTERNS = {
    "brittle": (r"(?:^|_)brittle|Brittle|BRITTLE", r"crack_normal", r"particle_strength"),
    "nacc": (r"(?:^|_)nacc|Nacc|NACC",),
    "von_mises": (r"(?:^|_)von_?mises|VonMises|VON_MISES",),
}


def python_identifiers(text: str) -> set[str]:
    """The NAME tokens of Python source (keywords included; they match no pattern)."""
    names = set()
    for token in tokenize.generate_tokens(io.StringIO(text).readline):
        if token.type == tokenize.NAME:
            names.add(token.string)
    return names


_CPP_NOISE = re.compile(r'//[^\n]*|/\*.*?\*/|"(?:\\.|[^"\\])*"|\'(?:\\.|[^\'\\])*\'', re.S)
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def cpp_identifiers(text: str) -> set[str]:
    """The identifiers of C++ / CUDA source once comments and string literals are removed."""
    return set(_IDENTIFIER.findall(_CPP_NOISE.sub(" ", text)))


def source_files(root: Path = ROOT) -> list[Path]:
    """The files counted: Python under fracture_gs/ (not pipeline/), C++ and CUDA under csrc/."""
    package = [path for path in (root / "fracture_gs").rglob("*.py") if "pipeline" not in path.relative_to(root).parts]
    kernels = [path for suffix in ("*.h", "*.cpp", "*.cu") for path in (root / "csrc").rglob(suffix)]
    return sorted(package + kernels)


def footprint(root: Path = ROOT) -> dict[str, list[str]]:
    """Per model, the files (relative to ``root``) that hold one of its identifiers."""
    found: dict[str, list[str]] = {model: [] for model in PATTERNS}
    compiled = {model: re.compile("|".join(patterns)) for model, patterns in PATTERNS.items()}
    for path in source_files(root):
        text = path.read_text(encoding="utf-8")
        names = python_identifiers(text) if path.suffix == ".py" else cpp_identifiers(text)
        for model, pattern in compiled.items():
            if any(pattern.search(name) for name in names):
                found[model].append(str(path.relative_to(root)))
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help=f"exit 1 if a model stands in more than {LIMIT} files")
    args = parser.parse_args(argv)
    found = footprint()
    print(json.dumps({model: {"files": len(files), "where": files} for model, files in found.items()}, indent=2))
    over = [model for model, files in found.items() if len(files) > LIMIT]
    if args.check and over:
        print(f"error: {', '.join(over)} stand in more than {LIMIT} files", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
