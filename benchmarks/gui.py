"""Speed of the main window (run under Xvfb: ``xvfb-run -a python benchmarks/gui.py``).

Metrics (one JSON object per line, medians of several runs):

* ``scrub_fps``: frames per second scrubbing a 4-camera 1280x720 take with overlays
  for 90 markers (detections, rings, projections, errors), images already cached.
* ``continuity_redraw_ms``: redraw of the continuity chart of 300 points x 36,000
  frames after a zoom/scroll (codes cached; the full recompute after a whole-take
  edit is reported as ``continuity_recompute_ms``).
* ``startup_s``: a fresh process to an open, drawn main window.
* ``open_first_frame_s``: File > Open of a 36,000-frame project (90 markers, 4
  cameras, detections) to its first frame drawn.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-bench-"))


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(value, 4), "unit": unit, **extra}),
          flush=True)


def settle(app, n: int = 3) -> None:
    for _ in range(n):
        app.processEvents()


def bench_scrub(app) -> None:
    from carapost.synth.demo_project import demo_project, render_dots
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow

    p = demo_project(120, 90, 4, size=(1280, 720), seed=2)
    frames = list(range(60))
    images = {(f, c): render_dots(p, f, c) for f in frames for c in range(4)}
    source = ArrayFrameSource(lambda f, c: images[(f, c)], cache_size=1024)
    source.prefetch(range(60), [0, 1, 2, 3])
    w = MainWindow(restore=False)
    w.resize(1920, 1050)
    w.set_project(p, source)
    w.show()
    settle(app, 10)
    p.set_selection(points=[int(i) for i in p.points.ids[:3]])
    rates = []
    for _ in range(5):
        t0 = time.perf_counter()
        for f in frames:
            w.set_frame(f)
            w.flush()
            app.processEvents()  # paints the four views
        rates.append(len(frames) / (time.perf_counter() - t0))
        w.set_frame(0)
        w.flush()
        settle(app)
    emit("scrub_fps", statistics.median(rates), "frames/s", cameras=4, size="1280x720",
         markers=90, runs=len(rates))
    w.stack.mark_clean()
    w.close()


def big_project(n_frames: int, n_points: int, n_cameras: int = 4, *, detections: bool):
    """A long project filled cheaply (random continuity, detections at the points)."""
    from carapost.model.project import new_project

    rng = np.random.default_rng(0)
    p = new_project(n_frames, n_cameras, image_size=(1280, 720))
    p.points.append(n_points)
    pts = p.points
    pts.positions[:] = rng.normal(0, 50, (1, n_points, 3)).astype(np.float32)
    pts.recon[:] = 1
    seen = rng.random((n_frames // 50 + 1, n_points, n_cameras)) < 0.85
    seen = np.repeat(seen, 50, axis=0)[:n_frames]
    base = rng.uniform([100, 100], [1180, 620], (1, n_points, n_cameras, 2))
    pts.obs[:] = np.where(seen[..., None], base, np.nan).astype(np.float32)
    pts.source[:] = seen.astype(np.int8)
    gaps = rng.random((n_frames // 200 + 1, n_points)) < 0.05
    gaps = np.repeat(gaps, 200, axis=0)[:n_frames]
    pts.positions[gaps] = np.nan
    if detections:
        counts = seen.sum(axis=1).astype(np.int64)  # [F, C]
        det = p.detections
        det.offsets = np.zeros(n_frames * n_cameras + 1, np.int64)
        np.cumsum(counts.reshape(-1), out=det.offsets[1:])
        n = int(det.offsets[-1])
        f_i, p_i, c_i = np.nonzero(seen)
        order = np.lexsort((p_i, c_i, f_i))
        det.arrays = {
            "centre": base[0, p_i[order], c_i[order]].astype(np.float32),
            "axes": np.full((n, 2), 4.0, np.float16),
            "angle": np.zeros(n, np.float16),
            "colour": np.zeros(n, np.int8),
            "score": np.ones(n, np.float16),
        }
    return p


def bench_continuity(app) -> None:
    from carapost.ui.context import ViewContext
    from carapost.ui.views.continuity import ContinuityView, point_codes

    p = big_project(36000, 300, detections=False)
    ctx = ViewContext()
    ctx.project = p
    chart = ContinuityView(ctx)
    chart.resize(1400, 900)
    chart.show()
    settle(app, 5)
    chart.refresh(None)
    settle(app, 3)
    times = []
    ranges = [(0, 36000), (1000, 5000), (20000, 20500), (0, 18000), (35000, 36000)] * 3
    for a, b in ranges:
        chart.vb.blockSignals(True)
        chart.vb.setXRange(a, b, padding=0)
        chart.vb.blockSignals(False)
        t0 = time.perf_counter()
        chart.render()
        chart.repaint()
        times.append(1000 * (time.perf_counter() - t0))
    emit("continuity_redraw_ms", statistics.median(times), "ms", points=300, frames=36000,
         runs=len(times), max_ms=round(max(times), 1))
    recompute = []
    for _ in range(3):
        t0 = time.perf_counter()
        chart._codes = point_codes(p)
        chart.render()
        chart.repaint()
        recompute.append(1000 * (time.perf_counter() - t0))
    emit("continuity_recompute_ms", statistics.median(recompute), "ms", points=300,
         frames=36000, runs=len(recompute))
    chart.close()


STARTUP = r"""
import sys, time
t0 = float(sys.argv[1])
from carapost.ui.app import application
app = application()
from carapost.ui.mainwindow import MainWindow
w = MainWindow(restore=False)
w.show()
for _ in range(5):
    app.processEvents()
w.repaint()
print(time.time() - t0)
w.close()
"""


def bench_startup() -> None:
    runs = []
    for _ in range(5):
        t0 = time.time()
        out = subprocess.run([sys.executable, "-c", STARTUP, repr(t0)], capture_output=True,
                             text=True, check=True, env=os.environ.copy())
        runs.append(float(out.stdout.strip().splitlines()[-1]))
    emit("startup_s", statistics.median(runs), "s", runs=len(runs))


def bench_open(app, folder: Path) -> None:
    from carapost.io.cara import save_project
    from carapost.ui.mainwindow import MainWindow

    p = big_project(36000, 90, detections=True)
    path = save_project(p, folder / "long.cara")
    del p
    runs = []
    for _ in range(3):
        w = MainWindow(restore=False)
        w.resize(1920, 1050)
        w.show()
        settle(app, 5)
        t0 = time.perf_counter()
        w.open_project(str(path))
        w.flush()
        for v in w.workspace.views():
            v.repaint()
        runs.append(time.perf_counter() - t0)
        w.stack.mark_clean()
        w.close()
        settle(app)
    emit("open_first_frame_s", statistics.median(runs), "s", frames=36000, markers=90,
         cameras=4, file_mb=round(path.stat().st_size / 1e6), runs=len(runs))


def main() -> None:
    from carapost.ui.app import application

    app = application()
    bench_scrub(app)
    bench_continuity(app)
    bench_startup()
    with tempfile.TemporaryDirectory() as tmp:
        bench_open(app, Path(tmp))


if __name__ == "__main__":
    main()
