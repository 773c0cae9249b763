"""docs/architecture.md stays true: its module map lists every module, and no module
grows past the size the document allows."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "carapost"
DOC = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")

#: Modules allowed over MAX_LINES, each with the reason docs/architecture.md gives.
OVERSIZE: dict[str, str] = {}
MAX_LINES = 800


def _modules() -> set[str]:
    return {p.relative_to(SRC).as_posix() for p in SRC.rglob("*.py")
            if "__pycache__" not in p.parts}


def test_module_map_lists_exactly_the_modules_that_exist():
    begin = DOC.index("<!-- module map: begin")
    end = DOC.index("<!-- module map: end -->")
    listed = set(re.findall(r"^\| `([^`]+\.py)` \|", DOC[begin:end], flags=re.M))
    existing = _modules()
    assert not existing - listed, f"missing from the map: {sorted(existing - listed)}"
    assert not listed - existing, f"in the map but gone: {sorted(listed - existing)}"


def test_no_module_over_the_size_limit():
    over = {m: n for m in _modules()
            if (n := len((SRC / m).read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert set(over) <= set(OVERSIZE), f"over {MAX_LINES} lines: {over}"
    for m in OVERSIZE:
        assert m in DOC, f"{m} is allowed over the limit but docs/architecture.md says not why"


def _package_of(module: str) -> str:
    return module.rsplit(".", 1)[0]


def test_no_module_imports_another_packages_private_names():
    """A private name (``_x``, or a private module ``pkg/_x.py``) is used only inside its
    own package; anything another package needs is public and documented."""
    import ast

    shared = {"carapost._runtime"}  # process-wide settings, documented as shared
    bad = []
    for path in SRC.rglob("*.py"):
        rel = path.relative_to(SRC.parent).with_suffix("")
        me = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        my_pkg = me if path.name == "__init__.py" else _package_of(me)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                mods = [(node.module, a.name) for a in node.names]
            elif isinstance(node, ast.Import):
                mods = [(a.name, "") for a in node.names]
            else:
                continue
            for mod, name in mods:
                if not mod.startswith("carapost") or mod in shared:
                    continue
                parts = mod.split(".")
                private_mod = next((i for i, p in enumerate(parts) if p.startswith("_")
                                    and not p.startswith("__")), None)
                if private_mod is not None:
                    owner = ".".join(parts[:private_mod])
                    if not (my_pkg + ".").startswith(owner + "."):
                        bad.append(f"{me}: {mod}")
                if name.startswith("_") and not name.startswith("__"):
                    if not (my_pkg + ".").startswith(_package_of(mod) + ".") and my_pkg != mod:
                        bad.append(f"{me}: {mod}.{name}")
    assert not bad, bad
