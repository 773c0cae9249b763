"""Extract the defaults of the reference guide's Properties pane and Tracker pane tables.

The reference guide is not part of the repository (its text is not ours). This script
reads its parameter tables and writes only names and values to a compact data file,
``tests/data/guide_defaults.json``, which the tests compare with the properties
registry in every checkout:

    {"sections": {"<section>": {"<parameter name>": {"default": 4, "unit": "px"}}}}

``default`` is null where the guide states none; ``unit`` is given for the values the
guide states in pixels (``px``) or millimetres (``mm``). Sections without parameters
(Export, Shortcut) are listed empty, so the test knows the guide has them.

Usage::

    python scripts/extract_guide_defaults.py [GUIDE] [--check]

``GUIDE`` defaults to ``$CARAPOST_GUIDE`` or ``shared/seeds/carapost-reference-guide.txt``
in a folder above the repository. ``--check`` compares instead of writing (exit 1 on a
difference).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "guide_defaults.json"
GUIDE_NAME = "carapost-reference-guide.txt"

#: Where the guide's Tracker pane table goes (its settings are not a Properties section).
TRACKER_PANE = "Tracker pane"
_HEADER_CELLS = {"Control", "Option", "Property", "Tracking parameter"}
_UNITS = {"pixels": "px", "pixel": "px", "mm": "mm"}
# a value after the word "default": a yes/no word or a number with an optional unit
_VALUE = re.compile(r"\b(True|False|selected|cleared)\b|(\d+(?:\.\d+)?)\s*(pixels?|mm)?",
                    re.IGNORECASE)


def find_guide() -> Path | None:
    """The guide from ``$CARAPOST_GUIDE`` or ``shared/seeds`` above the repository."""
    env = os.environ.get("CARAPOST_GUIDE")
    if env:
        return Path(env) if Path(env).exists() else None
    for folder in REPO.parents:
        path = folder / "shared" / "seeds" / GUIDE_NAME
        if path.exists():
            return path
    return None


def _body(lines: list[str], start: str, end: str) -> list[str]:
    """Lines between the last ``start`` heading (the first is the contents) and ``end``."""
    i = max(k for k, ln in enumerate(lines) if ln.strip() == start)
    j = next(k for k in range(i + 1, len(lines)) if lines[k].strip() == end)
    return lines[i + 1:j]


def parse_default(text: str) -> tuple[Any, str] | None:
    """The first value stated after "default" in a description, with its unit.

    Examples
    --------
    >>> parse_default("<p>Range is 0–1, default is 0.4. This value changes ...</p>")
    (0.4, '')
    >>> parse_default("By default this check box is cleared (False).")
    (False, '')
    >>> parse_default("The default value for this threshold is 0.5mm, and ...")
    (0.5, 'mm')
    >>> parse_default("Select the index of the ROM frame.") is None
    True
    """
    found = re.search(r"\bdefault\b", text, re.IGNORECASE)
    if found is None:
        return None
    value = _VALUE.search(text, found.end())
    if value is None:
        return None
    word, number, unit = value.groups()
    if word is not None:
        return word.lower() in ("true", "selected"), ""
    return (float(number) if "." in number else int(number)), _UNITS.get(
        (unit or "").lower(), "")


def _name(cell: str) -> str:
    # "Face Point Max Elastic Prediction Distance (pixels)": the unit is not the name
    return re.sub(r"\s*\((pixels|mm)\)$", "", cell.strip())


def _entry(parsed: tuple[Any, str] | None) -> dict[str, Any]:
    if parsed is None:
        return {"default": None}
    value, unit = parsed
    return {"default": value, "unit": unit} if unit else {"default": value}


def _rows(lines: list[str]) -> list[tuple[str, str]]:
    out = []
    for ln in lines:
        if "\t" not in ln:
            continue
        name, desc = ln.split("\t", 1)
        if name.strip() not in _HEADER_CELLS:
            out.append((_name(name), desc))
    return out


def extract(text: str) -> dict[str, Any]:
    """Section -> parameter name -> ``{"default": ..., "unit": ...}`` from the guide."""
    lines = text.splitlines()
    pane = _body(lines, "Properties pane", "Selection pane")
    listed = [m.group(1) for ln in pane[:20]
              if (m := re.match(r"^- \| \[(.+) section\]", ln.strip()))]
    sections: dict[str, dict[str, Any]] = {}
    for k, name in enumerate(listed):
        end = f"{listed[k + 1]} section" if k + 1 < len(listed) else None
        body = _body(pane, f"{name} section", end) if end else pane[
            max(i for i, ln in enumerate(pane) if ln.strip() == f"{name} section") + 1:]
        sections[name] = {n: _entry(parse_default(d)) for n, d in _rows(body)}
    # Tracking: one row ("Allow Single Sensor Tracking") states no default in its
    # description; the dense-set table "identical to the default settings" does.
    i = next(k for k, ln in enumerate(lines) if "identical to the default settings" in ln)
    j = next(k for k in range(i, len(lines)) if lines[k].startswith("Tracking parameter values"))
    tracking = sections["Tracking Parameters"]
    for name, value in _rows(lines[i:j]):
        parsed = _entry(parse_default("default " + value))
        if tracking[name]["default"] is None:
            tracking[name] = parsed
        elif tracking[name] != parsed:
            raise ValueError(f"the guide gives two defaults for {name!r}")
    tracker = _body(lines, TRACKER_PANE, "Graph view")
    settings_at = next(k for k, ln in enumerate(tracker) if ln.startswith("Settings\t"))
    sections[TRACKER_PANE] = {n: _entry(parse_default(d))
                              for n, d in _rows(tracker[settings_at + 1:])}
    return {"guide": GUIDE_NAME, "sections": sections}


def dumps(data: dict[str, Any]) -> str:
    """The data file's text: one parameter per line."""
    out = ['{', f'  "guide": {json.dumps(data["guide"])},', '  "sections": {']
    names = list(data["sections"])
    for k, section in enumerate(names):
        rows = data["sections"][section]
        out.append(f"    {json.dumps(section)}: {{" + ("" if rows else "}"))
        for m, (name, entry) in enumerate(rows.items()):
            comma = "," if m + 1 < len(rows) else ""
            out.append(f"      {json.dumps(name)}: {json.dumps(entry)}{comma}")
        if rows:
            out.append("    }")
        if k + 1 < len(names):
            out[-1] += ","
    out += ["  }", "}", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("guide", nargs="?", type=Path, help="the reference guide (.txt)")
    parser.add_argument("--check", action="store_true", help="compare, do not write")
    args = parser.parse_args(argv)
    guide = args.guide or find_guide()
    if guide is None or not guide.exists():
        print("reference guide not found (give its path or set CARAPOST_GUIDE)")
        return 2
    text = dumps(extract(guide.read_text(encoding="utf-8")))
    if args.check:
        same = DATA.exists() and DATA.read_text(encoding="utf-8") == text
        print("up to date" if same else f"{DATA} differs from {guide}")
        return 0 if same else 1
    DATA.parent.mkdir(parents=True, exist_ok=True)
    DATA.write_text(text, encoding="utf-8")
    print(f"wrote {DATA}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
