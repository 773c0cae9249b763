#!/usr/bin/env python3
"""Track the face points of a take through every frame.

Two forms:

    python process_track.py Example.cara                  # an initialised project
    python process_track.py Example_cam0.mkv --rom ROM.cara

With a project, the points are tracked forwards from the first frame where any face
point has a 3D position (the project's own cameras and Tracking Parameters). With a
take and a ROM (a ``.cara`` of an initialised take of the same actor and rig, see
``process_setup_ROM.py``), the take is imported, its blobs detected, the ROM loaded
(cameras, brim, labels, properties), the face initialised from the ROM at ``--frame``
and tracked over the whole take. The result goes to ``-o`` (default: ``<name>_t.cara``
beside the input).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from carapost import Session
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_FACE


def track_project(s: Session) -> int:
    """Track forwards from the first frame with a face point; returns that frame."""
    p = s.project
    face = p.points.kind == KIND_FACE
    has = np.isfinite(p.points.positions[:, face, 0]).any(axis=1)
    if not has.any():
        raise CommandError("the project has no face point with a 3D position to track "
                           "from (initialise it first)")
    first = int(np.argmax(has))
    s.set_active_range(first, p.n_frames - 1)
    s.current_frame = first
    s.track("forwards", frame=first, use_images=s.has_images)
    return first


def track_take_with_rom(s: Session, rom: Path, frame: int) -> None:
    """Detect, load the ROM, initialise from it at ``frame``, track the whole take."""
    p = s.project
    s.detect_blobs("all", cameras=range(p.n_cameras))
    s.load_rom(rom)
    s.current_frame = frame
    s.initialize_from_rom(frame=frame)
    s.set_active_range(0, p.n_frames - 1)
    s.track_take(frame=frame)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    ap.add_argument("input", help="a .cara project, or a take (camera file, .json or folder)")
    ap.add_argument("--rom", "-rom", help="ROM .cara to initialise a take from")
    ap.add_argument("--frame", type=int, default=0,
                    help="frame of the take to initialise from the ROM (default 0)")
    ap.add_argument("-o", "--output", help="project to write (default <name>_t.cara)")
    args = ap.parse_args(argv)
    src = Path(args.input)
    try:
        if src.suffix.lower() == ".cara":
            if args.rom:
                raise CommandError("--rom is for a take; a project is tracked as it is")
            s = Session.open(src)
            name, folder = src.stem, src.parent
            with s:
                first = track_project(s)
            how = f"tracked forwards from frame {first}"
        else:
            if not args.rom:
                raise CommandError("a take needs --rom ROM.cara to be initialised")
            s = Session.import_take(src, take_brim=False)
            name = s.project.take.name
            folder = src if src.is_dir() else src.parent
            with s:
                track_take_with_rom(s, Path(args.rom), args.frame)
            how = f"initialised from {args.rom} at frame {args.frame}, tracked"
        out = s.save(Path(args.output) if args.output else folder / f"{name}_t.cara")
    except (CaraFileError, CommandError, ValueError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    p = s.project
    face = p.points.kind == KIND_FACE
    tracked = float(np.isfinite(p.points.positions[:, face, 0]).mean()) if face.any() else 0.0
    print(f"{how}: {int(face.sum())} face points, {tracked:.1%} of point-frames in 3D")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
