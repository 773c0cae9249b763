"""Write docs/properties.md from the properties registry (one table per section).

Usage::

    python scripts/gen_properties_doc.py           # rewrite docs/properties.md
    python scripts/gen_properties_doc.py --check   # exit 1 if it is out of date

The algorithm sections come from the parameter dataclasses' field metadata
(``carapost.algorithms.params.param``), so after changing a parameter's label, range,
unit, default or help, rerun this script.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from carapost.algorithms.params import format_value
from carapost.model.properties import SECTIONS, PropertySpec, specs_in_section
from carapost.ui.settings import PREFERENCES

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "properties.md"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _allowed(s: PropertySpec) -> str:
    """Range column: ``0 – 1`` for inclusive bounds, in words otherwise."""
    if s.choices is not None:
        return ", ".join(s.choices)
    if s.minimum is None and s.maximum is None:
        return ""
    if s.minimum is not None and s.maximum is not None and not (
            s.min_exclusive or s.max_exclusive):
        return f"{format_value(s.minimum)} – {format_value(s.maximum)}"
    return s.range_text()


def properties_markdown() -> str:
    """Reference of every property as Markdown: the text of ``docs/properties.md``."""
    lines = [
        "# Properties reference",
        "",
        "Generated from `carapost.model.properties.SPECS` by `scripts/gen_properties_doc.py`;",
        "do not edit by hand. Regenerate with `python scripts/gen_properties_doc.py`.",
        "",
        "Names and defaults follow the reference guide. Ranges are inclusive unless",
        "written out in words; where the guide gives no range or default the help text",
        "says the value is our choice. The sections Blob Parameters, Initialize 3D",
        "Parameters, Initialize From ROM Parameters, Tracking Parameters and Triangulation",
        "Parameters are generated from the fields of `BlobParameters`, `Init3DParameters`,",
        "`RomParameters`, `TrackingParameters` and `TriangulationParameters` (keys are",
        "field names), so `carapost.algorithms.params.from_mapping(cls, props)` builds",
        "them. The guide's Shortcut section only lists shortcuts and has no parameters.",
        "The Triangulation Parameters section and the contents of the Export section are",
        "ours (the guide names the Export section without listing its options). Target",
        "Tracker holds the settings of the Tracker pane. The guide's Display section",
        "(point labels and their font size), the Show Again Flags and the Tracker pane's",
        "Update Timeline / 2D View Every Frame are user settings",
        "(`carapost.ui.settings.PREFERENCES`), not project properties: they are listed",
        "last, are kept per user on this computer and are not saved in the `.cara`.",
        "",
    ]
    for name in SECTIONS:
        lines += [
            f"## {name}",
            "",
            "| Label | Key | Type | Default | Range | Unit | Help |",
            "|---|---|---|---|---|---|---|",
        ]
        for s in specs_in_section(name):
            cells = [s.label, f"`{s.key}`", s.kind, format_value(s.default), _allowed(s),
                     s.unit, s.help]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        lines.append("")
    lines += [
        "## User settings (this computer)",
        "",
        "| Label | Key | Type | Default | Range | Unit | Help |",
        "|---|---|---|---|---|---|---|",
    ]
    for pref in PREFERENCES:
        allowed = (f"{pref.minimum} – {pref.maximum}" if pref.minimum is not None
                   and pref.maximum is not None else "")
        cells = [pref.label, f"`{pref.key}`", pref.kind, format_value(pref.default),
                 allowed, pref.unit, pref.help]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="only check that the file is up to date")
    args = parser.parse_args(argv)
    text = properties_markdown()
    if args.check:
        ok = DOC.exists() and DOC.read_text(encoding="utf-8") == text
        if not ok:
            print(f"{DOC} is stale; run python {Path(__file__).relative_to(REPO)}")
        return 0 if ok else 1
    DOC.write_text(text, encoding="utf-8")
    print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
