#!/usr/bin/env python3
"""Detect the blobs in every image of a take and save them as ``<take>_b.cara``.

The project is written beside the take (or to ``-o``); open it in ``carapost gui`` to
solve the brim and track, or give it to ``process_track.py``.

    python process_detect_blobs.py shoot/Example_cam0.mkv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from carapost import Session
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.io.take_import import find_take_files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("take", help="one camera file of the take, its .json/.xcp, or its folder")
    ap.add_argument("-o", "--output", help="project to write (default: <take>_b.cara "
                                           "beside the take)")
    ap.add_argument("--workers", type=int, default=2, help="detector processes (default 2)")
    args = ap.parse_args(argv)
    try:
        files = find_take_files(args.take)
        out = Path(args.output) if args.output else files.folder / f"{files.name}_b.cara"
        with Session.import_take(args.take) as s:
            p = s.project
            s.detect_blobs("all", cameras=range(p.n_cameras), workers=args.workers)
            written = s.save(out)
    except (CaraFileError, CommandError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"{p.detections.total} detections in {p.n_frames} frames x {p.n_cameras} cameras")
    print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
