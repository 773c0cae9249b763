"""Fuzz worker: reads ``{"reader", "path"}`` lines on stdin, answers one JSON line each.

Run by `harness.Worker` as ``python -m tests.fuzz.worker``. The address space is capped
(``CARAPOST_FUZZ_MEM_MB``) so that runaway allocation ends as a ``MemoryError`` or a
dead worker, never as a machine out of memory.
"""

from __future__ import annotations

import json
import logging
import os
import resource
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any


def _touch_project(path: Path) -> None:
    import numpy as np

    from carapost.io.cara import load_project

    project = load_project(path)
    for arr in project.points.arrays.values():
        np.asarray(arr).sum()
    for arr in project.detections.arrays.values():
        np.asarray(arr).sum()
    project.calibration.R.sum()


def _video(path: Path) -> None:
    from carapost.io.video import VideoSource

    with VideoSource(path) as src:
        for k in range(min(src.n_frames, 8)):
            src.read(k)
        if src.n_frames > 2:
            src.read(0)


def _readers() -> dict[str, Callable[[Path], Any]]:
    from carapost.io.brim_svg import read_brim_svg
    from carapost.io.c3d import read_c3d
    from carapost.io.c3d_points import project_from_c3d
    from carapost.io.labels import read_label_file, read_labels_from_cara
    from carapost.io.take_import import import_take, read_brim_csv, read_take_metadata
    from carapost.io.xcp import read_xcp

    return {
        "cara_open": _touch_project,
        "cara_labels": read_labels_from_cara,
        "label_file": read_label_file,
        "brim_csv": read_brim_csv,
        "brim_svg": read_brim_svg,
        "xcp": read_xcp,
        "take_import": import_take,
        "take_json": read_take_metadata,
        "c3d": read_c3d,
        "c3d_import": project_from_c3d,
        "video": _video,
    }


def main() -> None:
    limit = int(os.environ.get("CARAPOST_FUZZ_MEM_MB", "4096"))
    resource.setrlimit(resource.RLIMIT_AS, (limit << 20, limit << 20))
    logging.disable(logging.CRITICAL)
    from carapost.io.errors import CaraFileError

    readers = _readers()
    print(json.dumps({"ready": True}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        t0 = time.perf_counter()
        res: dict[str, Any] = {"status": "ok"}
        try:
            readers[req["reader"]](Path(req["path"]))
        except CaraFileError as exc:
            res = {"status": "documented", "exc_type": type(exc).__name__,
                   "message": str(exc)[:300], "internal": bool(getattr(exc, "internal", False))}
        except BaseException as exc:
            tb = traceback.extract_tb(exc.__traceback__)
            ours = [fr for fr in tb if "carapost" in fr.filename] or tb
            last = ours[-1] if ours else None
            where = f"{Path(last.filename).name}:{last.lineno} {last.name}" if last else ""
            res = {"status": "undocumented", "exc_type": type(exc).__name__,
                   "message": str(exc)[:300], "where": where}
        res["seconds"] = time.perf_counter() - t0
        res["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(json.dumps(res), flush=True)


if __name__ == "__main__":
    main()
