#!/usr/bin/env python3
"""Make the ``.cara`` project of a ROM take, ready to track and to initialise other takes.

Imports the take, detects its blobs, solves the cameras from the calibration brim at
``--frame`` (the take's ``<take>_brim.csv``, or ``--brim``, or a brim triangulated from
the take) and initialises the face there with Initialize 3D; ``--track`` also tracks the
whole take. Open the result in ``carapost gui`` to label the points (Labelling pane)
before it serves as a ROM for ``process_track.py TAKE --rom ROM.cara``.

    python process_setup_ROM.py shoot/ROM_cam0.mkv -o ROM.cara --track
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from carapost import Session
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_BRIM, KIND_FACE
from carapost.pipeline import brim_from_take


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("take", help="one camera file of the ROM take, its .json, or its folder")
    ap.add_argument("-o", "--output", help="project to write (default <take>_rom.cara "
                                           "beside the take)")
    ap.add_argument("--brim", help="brim model (.csv label,x,y,z in mm, or .svg)")
    ap.add_argument("--frame", type=int, default=0, help="frame to solve and initialise at")
    ap.add_argument("--track", action="store_true", help="also track the whole take")
    args = ap.parse_args(argv)
    try:
        with Session.import_take(args.take) as s:
            p = s.project
            s.detect_blobs("all", cameras=range(p.n_cameras))
            if args.brim:
                s.import_brim(args.brim)
            elif not (p.points.kind == KIND_BRIM).any():  # the take brought no brim model
                s.set_brim_model(*brim_from_take(p), description="Brim From Take")
            s.current_frame = args.frame
            s.solve_brim(frame=args.frame, method="automatic")
            s.initialize_3d(frame=args.frame)
            if args.track:
                s.set_active_range(0, p.n_frames - 1)
                s.track_take(frame=args.frame)
        folder = Path(args.take) if Path(args.take).is_dir() else Path(args.take).parent
        out = s.save(Path(args.output) if args.output
                     else folder / f"{p.take.name}_rom.cara")
    except (CaraFileError, CommandError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    face = p.points.kind == KIND_FACE
    at = np.isfinite(p.points.positions[args.frame, face, 0]).sum()
    print(f"cameras solved at frame {args.frame}; {at} of {int(face.sum())} face points "
          f"initialised; {int((p.points.kind == KIND_BRIM).sum())} brim points")
    for h in s.history():
        print(f"  history: {h.description}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
