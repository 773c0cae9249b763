#!/usr/bin/env python3
"""Convert between frame index, burnt-in frame number and timecode of a take.

carapost counts frames from 0 (the frame index); the capture software prints a frame
number on the image (the burnt-in number, by default index + 1); the take's start
timecode and frame rate give each frame's SMPTE timecode. Give one of ``--frame``,
``--burnt-in`` or ``--timecode`` (repeatable) and all three are printed; without any,
the first and last frames are.

    python export_timecode.py Example.cara --frame 0 --timecode 01:00:00:10
"""

from __future__ import annotations

import argparse
import sys

from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.io.timecode import (
    burnt_in_to_frame_index,
    frame_index_to_burnt_in,
    frame_index_to_timecode,
    timecode_to_frame_index,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("project", help=".cara project")
    ap.add_argument("--frame", type=int, action="append", default=[], help="frame index")
    ap.add_argument("--burnt-in", type=int, action="append", default=[],
                    help="burnt-in frame number")
    ap.add_argument("--timecode", action="append", default=[], help="HH:MM:SS:FF")
    ap.add_argument("--first-burnt-in", type=int, default=1,
                    help="burnt-in number of frame index 0 (default 1)")
    args = ap.parse_args(argv)
    try:
        p = load_project(args.project)
        take = p.take
        first = args.first_burnt_in
        frames = list(args.frame)
        frames += [burnt_in_to_frame_index(n, first) for n in args.burnt_in]
        frames += [timecode_to_frame_index(tc, take.timecode_start, take.fps)
                   for tc in args.timecode]
        if not frames:
            frames = [0, p.n_frames - 1]
        print(f"# {take.name}: {p.n_frames} frames at {take.fps:g} fps, starting at "
              f"{take.timecode_start}")
        print("frame_index,burnt_in,timecode,subframe,in_take")
        for f in frames:
            tc, sub = frame_index_to_timecode(f, take.timecode_start, take.fps)
            inside = "yes" if 0 <= f < p.n_frames else "no"
            print(f"{f},{frame_index_to_burnt_in(f, first)},{tc},{sub},{inside}")
    except (CaraFileError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
