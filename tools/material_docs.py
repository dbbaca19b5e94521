"""The material table's and state block's layout per model, as docs/design_mpm.md shows it.

Rendered from the model classes of the registry (``fracture_gs.materials.MODELS``), which
``tests/test_material_registry.py`` holds equal to the compiled kernels' own description
(``_C.material_models()``, from the headers in ``csrc/common/materials/``).

    python tools/material_docs.py            # prints the block
    python tools/material_docs.py --write    # rewrites the generated block of docs/design_mpm.md
    python tools/material_docs.py --check    # exit 1 if the block differs from what it would write
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from fracture_gs.materials import MODELS, TABLE_COLUMNS  # noqa: E402
from fracture_gs.materials.model import FIRST_PARAMETER  # noqa: E402

DOC = Path(__file__).resolve().parents[1] / "docs" / "design_mpm.md"
BEGIN, END = "<!-- generated:material-layout -->", "<!-- /generated:material-layout -->"


def markdown() -> str:
    """The layout table: per model, its code, its three parameter columns (4-6), its state fields
    (field 0 first) and the fields every frame holds under their own name."""
    lines = [f"| model | col 0 | col {FIRST_PARAMETER} | col {FIRST_PARAMETER + 1} | col {FIRST_PARAMETER + 2} "
             "| state fields (0: the fracture variable) | frame fields |",
             "|---|---|---|---|---|---|---|"]
    for cls in MODELS:
        columns = [f"`{name}`" if name else "—" for name in cls.parameter_columns]
        state = ", ".join(f"`{name}`" for name in cls.state_fields)
        frames = ", ".join(f"`{name}`" for name in cls.frame_fields) or "—"
        lines.append(f"| `{cls.name}` (`{cls.__name__}`) | {cls.code} | {' | '.join(columns)} | {state} | {frames} |")
    shared = ", ".join(f"{i} `{name}`" for i, name in enumerate(TABLE_COLUMNS) if not name.startswith("parameter_"))
    lines.append("")
    lines.append(f"Columns every row has: {shared}.")
    return "\n".join(lines)


def rendered(text: str) -> str:
    """``text`` with its generated block replaced by :func:`markdown`."""
    if BEGIN not in text or END not in text:
        raise SystemExit(f"error: {DOC} has no {BEGIN} ... {END} block")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{markdown()}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="rewrite the block in docs/design_mpm.md")
    mode.add_argument("--check", action="store_true", help="exit 1 if docs/design_mpm.md's block is out of date")
    args = parser.parse_args(argv)
    if not (args.write or args.check):
        print(markdown())
        return 0
    text = DOC.read_text(encoding="utf-8")
    new = rendered(text)
    if args.check:
        if new != text:
            print(f"error: {DOC}'s material layout differs from tools/material_docs.py's; run it with --write",
                  file=sys.stderr)
            return 1
        return 0
    DOC.write_text(new, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
