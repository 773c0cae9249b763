"""Save/open of a long project and undo of a whole-take edit.

A 36,000-frame, 200-point, 4-camera project with 300 detections per image (43.2 M
detections, about 1.4 GB of arrays). Prints JSON lines: ``project_save_s``,
``project_open_s``, ``project_peak_mb`` (peak memory allocated while opening, measured
with tracemalloc, which numpy reports its buffers to), ``project_open_rss_mb`` (growth
of the resident set while opening: the file's arrays are mapped copy-on-write, so their
pages count here, not in tracemalloc), ``undo_whole_take_s``.

Run from the repository root: ``python benchmarks/project_io.py [--repeat N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from carapost.commands.edit import ClearActiveRange
from carapost.commands.stack import CommandStack
from carapost.io.cara import load_project, save_project
from carapost.model.project import RECON_TRIANGULATED, SOURCE_BLOB, new_project

F, P, C, D = 36_000, 200, 4, 300


def build() -> object:
    """The benchmark project, filled with random but plausible data."""
    rng = np.random.default_rng(0)
    project = new_project(F, C)
    project.points.append(P)
    pts = project.points
    pts.positions[:] = rng.normal(0, 50, size=pts.positions.shape).astype(np.float32)
    pts.recon[:] = RECON_TRIANGULATED
    pts.residual[:] = rng.random(pts.residual.shape, dtype=np.float32)
    pts.obs[:] = rng.uniform(0, 1280, size=pts.obs.shape).astype(np.float32)
    pts.source[:] = SOURCE_BLOB
    pts.detection[:] = rng.integers(0, D, size=pts.detection.shape, dtype=np.int32)
    pts.quality[:] = 1.0
    det = project.detections
    n = F * C * D
    det.offsets = np.arange(0, n + 1, D, dtype=np.int64)
    det.arrays = {
        "centre": rng.uniform(0, 1280, size=(n, 2)).astype(np.float32),
        "axes": rng.uniform(2, 8, size=(n, 2)).astype(np.float16),
        "angle": rng.uniform(0, 3, size=n).astype(np.float16),
        "colour": np.zeros(n, np.int8),
        "score": rng.random(n, dtype=np.float32).astype(np.float16),
    }
    return project


def rss_mb() -> float:
    """Resident set size of this process (MB), from /proc (Linux)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return float("nan")


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    """Print one JSON result line."""
    print(json.dumps({"metric": metric, "value": round(value, 4), "unit": unit, **extra}))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    project = build()
    size_gb = project.nbytes() / 1e9
    saves, opens, undos, peaks, rss = [], [], [], [], []
    with tempfile.TemporaryDirectory(dir=".") as tmp:
        path = Path(tmp) / "long.cara"
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            save_project(project, path)
            saves.append(time.perf_counter() - t0)
        for i in range(args.repeat):
            trace = i == args.repeat - 1
            if trace:
                tracemalloc.start()
            rss0 = rss_mb()
            t0 = time.perf_counter()
            loaded = load_project(path)
            elapsed = time.perf_counter() - t0
            rss.append(rss_mb() - rss0)
            if trace:
                peaks.append(tracemalloc.get_traced_memory()[1] / 1e6)
                tracemalloc.stop()
            else:
                opens.append(elapsed)
            del loaded
        opens = opens or [elapsed]
    stack = CommandStack(project)
    for _ in range(args.repeat):
        stack.push(ClearActiveRange(project))  # whole take: active range = all frames
        t0 = time.perf_counter()
        stack.undo()
        undos.append(time.perf_counter() - t0)
        stack.clear()
    common = {"frames": F, "points": P, "cameras": C, "detections_per_image": D,
              "project_gb": round(size_gb, 2)}
    emit("project_save_s", statistics.median(saves), "s", **common)
    emit("project_open_s", statistics.median(opens), "s", **common)
    emit("project_peak_mb", max(peaks), "MB", **common)
    emit("project_open_rss_mb", max(rss), "MB", **common)
    emit("undo_whole_take_s", statistics.median(undos), "s", **common)


if __name__ == "__main__":
    main()
