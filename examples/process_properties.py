#!/usr/bin/env python3
"""List every property group with its properties, values, units and ranges.

Without a project the values are the defaults; with one they are the project's (a value
that differs from its default is marked ``*``). ``--section`` lists one group; ``--set
KEY=VALUE`` changes a property (checked against its range) and, with ``-o``, saves the
project: this is how a script prepares the Blob Parameters or Tracking Parameters of a
batch.

    python process_properties.py
    python process_properties.py Example.cara --section "Blob Parameters"
    python process_properties.py Example.cara --set white_min_radius=2 -o Example.cara
"""

from __future__ import annotations

import argparse
import sys

from carapost import Session
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.properties import SECTIONS, PropertyError, specs_in_section
from carapost.model.properties import spec as property_spec


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", nargs="?", help=".cara project (default: the defaults)")
    ap.add_argument("--section", action="append", help="only this group (repeatable)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="change a property (one History entry for all of them)")
    ap.add_argument("-o", "--output", help="save the project here after --set")
    args = ap.parse_args(argv)
    try:
        s = Session.open(args.project) if args.project else Session()
        sections = args.section or list(SECTIONS)
        for name in sections:
            specs_in_section(name)  # an unknown section is refused before any output
        if args.set:
            values = {}
            for item in args.set:
                key, sep, value = item.partition("=")
                if not sep:
                    raise CommandError(f"--set {item!r}: write KEY=VALUE")
                key = key.strip()
                values[key] = property_spec(key).parse(value.strip())  # "2.5" -> 2.5, "on" -> True
            s.set_properties(values)
        if args.output:
            s.save(args.output)
    except (CaraFileError, CommandError, PropertyError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    props = s.project.properties
    for name in sections:
        print(f"[{name}]")
        for spec in specs_in_section(name):
            value = props[spec.key]
            changed = "*" if value != spec.default else " "
            unit = f" {spec.unit}" if spec.unit else ""
            rng = spec.range_text()
            print(f" {changed} {spec.label} ({spec.key}) = {value!r}{unit}"
                  + (f"   [{rng}]" if rng else ""))
    if args.output:
        print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
