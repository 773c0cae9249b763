#!/usr/bin/env python3
"""Print the 3D face points of a ``.cara`` project to the console.

One line per frame and point: frame index, label, x, y, z in mm (in the brim frame),
reconstruction kind and residual (mm). Missing samples are skipped (``--all`` prints
them as ``nan``). ``--frames A B`` limits the frames (inclusive).

    python export_3d_simple.py Example.cara --frames 0 9
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from carapost.algorithms.codes import RECON_NAMES
from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_FACE


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", help=".cara project")
    ap.add_argument("--frames", nargs=2, type=int, metavar=("FIRST", "LAST"))
    ap.add_argument("--all", action="store_true", help="also print missing samples")
    args = ap.parse_args(argv)
    try:
        p = load_project(args.project)
    except CaraFileError as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    a, b = args.frames or (0, p.n_frames - 1)
    if not 0 <= a <= b < p.n_frames:
        print(f"{ap.prog}: error: frames {a}-{b} are outside the take (0-{p.n_frames - 1})",
              file=sys.stderr)
        return 2
    cols = np.flatnonzero(p.points.kind == KIND_FACE)
    labels = [p.point_label(int(c)) for c in cols]
    pos = p.points.positions
    print("frame,label,x_mm,y_mm,z_mm,kind,residual_mm")
    for f in range(a, b + 1):
        for c, label in zip(cols, labels, strict=True):
            x, y, z = pos[f, c]
            if not args.all and not np.isfinite(x):
                continue
            kind = RECON_NAMES.get(int(p.points.recon[f, c]), "?")
            print(f"{f},{label},{x:.4f},{y:.4f},{z:.4f},{kind},"
                  f"{float(p.points.residual[f, c]):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
