"""Print the module map of docs/architecture.md: one line per module of src/carapost.

Each line is the module's path and the first line of its docstring,
so the map is written where the code is (the docstring) and the document only collects
it. ``python scripts/module_map.py --write`` replaces the map between the markers in
docs/architecture.md; ``--check`` exits 1 when the document is out of date (the test
``tests/test_architecture.py`` checks that the map lists exactly the modules that exist).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "carapost"
DOC = ROOT / "docs" / "architecture.md"
BEGIN = "<!-- module map: begin (scripts/module_map.py --write) -->"
END = "<!-- module map: end -->"

#: Layer of each top-level module or package, in the order of the layer map.
LAYERS = {
    "cli.py": "entry points", "demo.py": "entry points", "__init__.py": "entry points",
    "ui": "ui", "api.py": "session and API", "pipeline.py": "session and API",
    "session": "session and API", "export.py": "session and API", "commands": "commands",
    "io": "io", "model": "model", "algorithms": "algorithms", "parallel.py": "runtime",
    "_runtime.py": "runtime", "synth": "synth (beside the product)",
}
ORDER = ["entry points", "ui", "session and API", "commands", "io", "model", "algorithms",
         "runtime", "synth (beside the product)"]


def summary(path: Path) -> str:
    """The first line of a module's docstring (backticks kept, pipes escaped)."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    return first.replace("|", "\\|")


def modules() -> list[Path]:
    """Every module of the package, sorted by path."""
    return sorted(p for p in SRC.rglob("*.py") if "__pycache__" not in p.parts)


def module_map() -> str:
    """The Markdown tables of the map, one per layer."""
    rows: dict[str, list[str]] = {layer: [] for layer in ORDER}
    for p in modules():
        rel = p.relative_to(SRC)
        layer = LAYERS.get(rel.parts[0], "entry points")
        rows[layer].append(f"| `{rel.as_posix()}` | {summary(p)} |")
    out = []
    for layer in ORDER:
        if rows[layer]:
            out += [f"**{layer}**", "", "| module | what it holds |",
                    "| --- | --- |", *rows[layer], ""]
    return "\n".join(out).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--write", action="store_true", help="update docs/architecture.md")
    ap.add_argument("--check", action="store_true", help="exit 1 if the document is stale")
    a = ap.parse_args(argv)
    text = DOC.read_text(encoding="utf-8")
    head, rest = text.split(BEGIN)
    _, tail = rest.split(END)
    new = f"{head}{BEGIN}\n{module_map()}{END}{tail}"
    if a.write:
        DOC.write_text(new, encoding="utf-8")
    elif a.check:
        return 0 if new == text else 1
    else:
        sys.stdout.write(module_map())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
