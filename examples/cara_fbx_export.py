#!/usr/bin/env python3
"""Export a solved ``.cara`` project as FBX, with the face points under nodes you choose.

Without options the file holds what File > Export FBX writes (every frame, face points
under ``<take>/face``, Y up). The place to customise is `node_of`: it names the node
path each point goes under, below the take node. ``--group mouth=Lip*,Mouth*`` does the
same from the command line: points whose label matches one of the patterns go under
``<take>/face/mouth``.

    python cara_fbx_export.py Example.cara -o Example.fbx
    python cara_fbx_export.py Example.cara -o Example.fbx --group mouth=Lip*,Mouth* \\
        --group brows=Brow*
"""

from __future__ import annotations

import argparse
import fnmatch
import sys
from pathlib import Path

import numpy as np

from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.io.fbx import write_fbx
from carapost.io.labels import unique_names
from carapost.model.project import KIND_BRIM, KIND_FACE


def node_of(label: str, kind: int, groups: dict[str, list[str]]) -> str:
    """The node path (below the take node) of one point: edit this to taste.

    A face point whose label matches a pattern of a group goes under ``face/<group>``
    (the first group that matches), any other face point under ``face``, a brim point
    under ``brim``.
    """
    if kind == KIND_BRIM:
        return "brim"
    for group, patterns in groups.items():
        if any(fnmatch.fnmatchcase(label, pat) for pat in patterns):
            return f"face/{group}"
    return "face"


def parse_groups(specs: list[str]) -> dict[str, list[str]]:
    groups: dict[str, list[str]] = {}
    for spec in specs:
        name, sep, patterns = spec.partition("=")
        if not sep or not name.strip() or "/" in name or not patterns.strip():
            raise ValueError(f"--group {spec!r}: write NAME=PATTERN[,PATTERN...]")
        groups[name.strip()] = [p.strip() for p in patterns.split(",") if p.strip()]
    return groups


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", help="solved .cara project")
    ap.add_argument("-o", "--output", required=True, help=".fbx file to write")
    ap.add_argument("--group", action="append", default=[], metavar="NAME=PATTERNS",
                    help="put face points whose label matches a pattern under face/NAME")
    ap.add_argument("--brim", action="store_true", help="also write the brim points")
    ap.add_argument("--up", choices=("y", "z"), default="y", help="up axis (default y)")
    args = ap.parse_args(argv)
    try:
        if Path(args.output).suffix.lower() != ".fbx":
            raise ValueError(f"{args.output}: the output must be a .fbx file")
        groups = parse_groups(args.group)
        p = load_project(args.project)
        kinds = (KIND_FACE, KIND_BRIM) if args.brim else (KIND_FACE,)
        cols = np.flatnonzero(np.isin(p.points.kind, kinds))
        if cols.size == 0:
            raise ValueError(f"{args.project}: no points to export")
        labels = unique_names([p.point_label(int(c)) for c in cols])
        kind = p.points.kind[cols].astype(np.int64)
        nodes = [node_of(lab, int(k), groups) for lab, k in zip(labels, kind, strict=True)]
        write_fbx(args.output, p.points.positions[:, cols].astype(np.float64),
                  labels=labels, rate=p.take.fps, kinds=(kind == KIND_BRIM).astype(int),
                  take_name=p.take.name or "take", up_axis=args.up, groups=nodes)
    except (CaraFileError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    for node in sorted(set(nodes)):
        print(f"{p.take.name}/{node}: {nodes.count(node)} points")
    print(f"wrote {args.output}: {len(cols)} points x {p.n_frames} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
