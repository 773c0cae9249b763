#!/usr/bin/env python3
"""Detect blobs in every take found that has no ``.cara`` with detections yet.

The argument is a folder (searched recursively) or a file name with wildcards; each take
found gets ``<take>_b.cara`` beside it (as ``process_detect_blobs.py`` writes), unless a
``<take>.cara`` or ``<take>_b.cara`` with detections is already there. One take at a
time, on this machine: for hundreds of takes on a cluster, use ``carapost batch``.

    python process_batch_detect_blobs.py /data/jobs
    python process_batch_detect_blobs.py "/data/jobs/ROM*_cam0.mkv"
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from carapost import Session
from carapost.batch import BatchError, discover_takes
from carapost.commands.stack import CommandError
from carapost.io.cara import load_project
from carapost.io.errors import CaraFileError
from carapost.io.take_import import find_take_files


def has_detections(path: Path) -> bool:
    """Whether ``path`` is a readable project with at least one detection."""
    try:
        return path.is_file() and load_project(path).detections.total > 0
    except CaraFileError:
        return False  # unreadable: made again


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", metavar="DIR_OR_WILDCARD",
                    help="folder of takes, take file, or wildcard (quote it)")
    args = ap.parse_args(argv)
    try:
        takes = discover_takes(args.inputs)
    except (BatchError, CaraFileError) as exc:
        print(f"{ap.prog}: error: {exc}", file=sys.stderr)
        return 2
    made = skipped = failed = 0
    for take in takes:
        files = find_take_files(take)
        done = [files.folder / f"{files.name}{end}" for end in (".cara", "_b.cara")]
        if any(has_detections(p) for p in done):
            print(f"skip {files.name}: {next(p for p in done if p.is_file()).name} "
                  "has detections")
            skipped += 1
            continue
        try:
            with Session.import_take(take) as s:
                s.detect_blobs("all", cameras=range(s.project.n_cameras))
                out = s.save(done[1])
        except (CaraFileError, CommandError, ValueError) as exc:
            print(f"FAILED {files.name}: {exc}", file=sys.stderr)
            failed += 1
            continue
        print(f"{files.name}: {s.project.detections.total} detections -> {out}")
        made += 1
    print(f"{made} made, {skipped} skipped, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
