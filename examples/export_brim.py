#!/usr/bin/env python3
"""Print the calibration brim of a ``.cara`` project to the console.

The brim model (label and x, y, z in mm, as ``<take>_brim.csv`` and File > Import
Calibration Brim give it), then, per camera, how many brim dots it sees at ``--frame``
and the cameras' positions in the brim frame there.

    python export_brim.py Example.cara --frame 0
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_BRIM


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", help=".cara project")
    ap.add_argument("--frame", type=int, default=0, help="frame for the cameras (default 0)")
    args = ap.parse_args(argv)
    try:
        p = load_project(args.project)
    except CaraFileError as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    cols = np.flatnonzero(p.points.kind == KIND_BRIM)
    if not cols.size:
        print(f"{ap.prog}: error: {args.project} has no brim points", file=sys.stderr)
        return 2
    f = args.frame
    if not 0 <= f < p.n_frames:
        print(f"{ap.prog}: error: frame {f} is outside the take (0-{p.n_frames - 1})",
              file=sys.stderr)
        return 2
    print("label,x_mm,y_mm,z_mm")
    for c in cols:
        # the brim is rigid: its model position is the same at every frame it has one
        xyz = p.points.positions[:, c]
        good = np.isfinite(xyz[:, 0])
        x, y, z = xyz[f] if good[f] else (xyz[good][0] if good.any() else (np.nan,) * 3)
        print(f"{p.point_label(int(c))},{x:.4f},{y:.4f},{z:.4f}")
    cal = p.calibration
    print(f"# cameras at frame {f}" + ("" if cal.solved[f] else " (not solved there)"))
    seen = np.isfinite(p.points.obs[f][cols, :, 0]).sum(axis=0)
    for k, cam in enumerate(p.take.cameras):
        centre = -cal.R[f, k].T @ cal.t[f, k]
        print(f"# {cam.name}: {int(seen[k])} brim dots observed, centre "
              f"({centre[0]:.2f}, {centre[1]:.2f}, {centre[2]:.2f}) mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
