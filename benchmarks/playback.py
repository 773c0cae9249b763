"""Frame access and playback in the main window, on a real take with videos.

Run under Xvfb with a real window::

    xvfb-run -a -s "-screen 0 1920x1080x24" python benchmarks/playback.py TAKE.json

``TAKE.json`` is a take from ``carapost synth`` or ``carapost demo`` (4 x 1280x720
FFV1). Without it, a 300-frame synthetic take is rendered into a temporary folder first.
``--codecs`` also measures the readers (OpenCV against PyAV) and the proxy formats.

Metrics (one JSON object per line; times from the request to the images of all four
cameras drawn in their views):

* ``first_jump_s``: the first jump after the take was opened.
* ``open_stall_ms``: the longest gap between the ticks of a 10 ms timer while the take
  is opened again (``--opens`` times, a fresh session each time): from the call to the
  images of every camera on screen and 0.3 s after (median of the openings; max too).
* ``jump_ms_p95``: jumps to random frames anywhere in the take (95th percentile).
* ``step_ms_p95``: Next/Prev Frame, one step every 100 ms after a pause in which the
  read-ahead runs (95th percentile, forwards and backwards).
* ``playback_fps``: frames shown per second with all their images while playing from
  the originals (View > Play; the take's rate is the target), with the video frames
  decoded meanwhile and ``complete_fraction``, the share of the frames decoded that
  every camera decoded (only those can be shown; the rest was work thrown away).
* ``gui_stall_ms_max``: longest gap between the ticks of a 10 ms timer on the GUI
  thread over everything above.
* ``detect_current_frame_s``: Go To Frame on a frame not cached, then Detect Blobs
  [Current Frame] until its result is in the History.
* ``rss_mb_max`` / ``cache_mb_max``: resident memory and image cache over a scrub
  session of ``--scrub-s`` seconds (random jumps and steps).
* ``steal_s``: CPU time the hypervisor took for other tenants during the run (a
  virtual machine's steal time; the stalls it causes look "blocked" from inside).

The script only uses what every version of the window has (``set_frame``, the camera
views, the actions), so the same file measures the code before the frame service.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import random
import resource
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-bench-"))
# a user cache of its own (keyframe indexes, proxies): proxies written by an earlier run
# would be played in the originals' phase
os.environ.setdefault("CARAPOST_CACHE_DIR", tempfile.mkdtemp(prefix="carapost-bench-cache-"))


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(float(value), 4), "unit": unit,
                      **extra}), flush=True)


def p95(values: list[float]) -> float:
    return float(np.percentile(values, 95)) if values else float("nan")


def steal_s() -> float:
    """Seconds of CPU the hypervisor took from this machine's CPUs so far (the steal
    column of ``/proc/stat``; 0 where there is none): the other tenants' share, which
    the GUI thread's stalls show as "blocked" time."""
    try:
        with open("/proc/stat") as fh:
            fields = fh.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


class Stalls:
    """Longest gap between the ticks of a 10 ms timer on the GUI thread."""

    def __init__(self, profiler=None) -> None:
        from PySide6.QtCore import Qt, QTimer

        self.timer = QTimer()
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self._tick)
        self.last = time.perf_counter()
        self.last_cpu = time.thread_time()
        self.max_gap = 0.0
        self.max_busy = 0.0  # GUI thread CPU time between two ticks (load-independent)
        self.phase = "open"
        self.by_phase: dict[str, float] = {}
        # longest gap and GUI CPU since `window_reset` (one window: one take opening)
        self.window_gap = self.window_busy = 0.0
        self.busy_by_phase: dict[str, float] = {}
        self.profiler = profiler
        self._sched = f"/proc/self/task/{threading.get_native_id()}/schedstat"
        self.last_runq = self._runq()
        # the longest gap split into the GUI thread's CPU time, its wait for a core
        # (run queue) and the rest (blocked: waiting for the GIL or a lock)
        self.worst: dict[str, dict[str, float]] = {}
        # garbage collections (any thread: one holds the GIL) as (start, end, generation)
        self.gc_runs: list[tuple[float, float, int]] = []
        self.gc_by_phase: dict[str, dict[str, float]] = {}
        self._gc_start = 0.0
        gc.callbacks.append(self._gc)

    def _gc(self, phase: str, info: dict) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._gc_start = now
            return
        gen = int(info["generation"])
        self.gc_runs.append((self._gc_start, now, gen))
        row = self.gc_by_phase.setdefault(self.phase, {"gen2": 0, "gen2_ms_max": 0.0,
                                                       "gc_ms_max": 0.0})
        ms = (now - self._gc_start) * 1e3
        row["gc_ms_max"] = round(max(row["gc_ms_max"], ms), 1)
        if gen == 2:
            row["gen2"] += 1
            row["gen2_ms_max"] = round(max(row["gen2_ms_max"], ms), 1)
        if len(self.gc_runs) > 5000:
            del self.gc_runs[:2500]

    def gc_in(self, t0: float, t1: float) -> float:
        """Milliseconds of garbage collection (any thread) inside [t0, t1]."""
        return sum(max(0.0, min(b, t1) - max(a, t0)) for a, b, _ in self.gc_runs
                   if b >= t0) * 1e3

    def window_reset(self) -> None:
        self.window_gap = self.window_busy = 0.0

    def _runq(self) -> float:
        try:
            with open(self._sched) as fh:
                return int(fh.read().split()[1]) / 1e9
        except OSError:
            return 0.0

    def start(self) -> None:
        self.last = time.perf_counter()
        self.last_cpu = time.thread_time()
        self.last_runq = self._runq()
        self.timer.start(10)

    def _tick(self) -> None:
        now, cpu, runq = time.perf_counter(), time.thread_time(), self._runq()
        gap, busy = now - self.last, cpu - self.last_cpu
        if gap > self.worst.get(self.phase, {}).get("gap_ms", 0.0) / 1e3:
            wait = runq - self.last_runq
            self.worst[self.phase] = {"gap_ms": round(gap * 1e3, 1),
                                      "cpu_ms": round(busy * 1e3, 1),
                                      "runqueue_ms": round(wait * 1e3, 1),
                                      "blocked_ms": round((gap - busy - wait) * 1e3, 1),
                                      "gc_ms": round(self.gc_in(self.last, now), 1)}
        self.last_runq = runq
        self.max_gap = max(self.max_gap, gap)
        self.window_gap = max(self.window_gap, gap)
        self.window_busy = max(self.window_busy, busy)
        self.max_busy = max(self.max_busy, busy)
        self.by_phase[self.phase] = max(self.by_phase.get(self.phase, 0.0), gap)
        self.busy_by_phase[self.phase] = max(self.busy_by_phase.get(self.phase, 0.0), busy)
        if self.profiler is not None:
            if gap > 0.04 or busy > 0.02:
                self.profiler.attribute(self.last, now, busy, self.phase,
                                        gc_ms=self.gc_in(self.last, now))
            self.profiler.prune(now - 1.0)
        self.last, self.last_cpu = now, cpu


class DecodeLog:
    """Which video frames were decoded, per file, while on (originals through
    ``VideoSource.read``, proxies through ``ProxyReader.read`` where they exist)."""

    def __init__(self) -> None:
        self.on = False
        self.frames: dict[str, set[int]] = {}
        self.calls = 0
        targets = []
        try:
            from carapost.io.video import VideoSource

            targets.append(VideoSource)
        except ImportError:
            pass
        try:
            from carapost.io.proxy import ProxyReader

            targets.append(ProxyReader)
        except ImportError:
            pass
        for cls in targets:
            self._wrap(cls)

    def _wrap(self, cls) -> None:
        original = cls.read
        log = self

        def read(reader, index):
            if log.on:
                log.calls += 1
                log.frames.setdefault(str(reader.path), set()).add(int(index))
            return original(reader, index)

        cls.read = read

    def reset(self) -> None:
        self.frames, self.calls = {}, 0

    def summary(self, n_cameras: int) -> dict[str, float]:
        """Frames decoded and the fraction of them decoded for every camera (a frame
        only some cameras have cannot be shown)."""
        # the files played (a few original frames may be read beside the proxies)
        sets = sorted(self.frames.values(), key=len, reverse=True)[:n_cameras]
        if len(sets) < n_cameras:
            return {"decoded": self.calls, "complete_fraction": 0.0}
        union = set.union(*sets)
        complete = set.intersection(*sets)
        return {"decoded": self.calls,
                "complete_fraction": round(len(complete) / max(len(union), 1), 3)}


class Bench:
    def __init__(self, app, take: Path, profiler=None) -> None:
        from carapost.session import Session
        from carapost.ui.mainwindow import MainWindow

        self.app = app
        self.w = MainWindow(restore=False)
        self.w.resize(1920, 1050)
        self.w.show()
        self.pump(0.2)
        self.session = Session.import_take(take)
        self.p = self.session.project
        self.views = []
        self.decodes = DecodeLog()
        self.stalls = Stalls(profiler)
        self.stalls.start()

    def pump(self, seconds: float = 0.0) -> None:
        end = time.perf_counter() + seconds
        while True:
            self.app.processEvents()
            if time.perf_counter() >= end:
                return
            time.sleep(0.001)

    def sensor_views(self):
        return [v for v in self.w.context.shell.all_views() if v.kind == "sensor"]

    def shown(self, frame: int) -> bool:
        views = self.sensor_views()
        for v in views:
            if hasattr(v, "image_frame"):
                if v.image_frame != frame:
                    return False
            elif getattr(v, "_drawn_frame", None) != frame:
                return False
        return bool(views)

    def go(self, frame: int, timeout: float = 60.0) -> float:
        """Seconds from ``set_frame`` to the images of every camera on screen."""
        t0 = time.perf_counter()
        self.w.set_frame(frame)
        self.w.flush()
        frames = self.w.context.frames
        cams = range(self.p.n_cameras)
        self.last_cached_s = None  # when every camera's image was in the cache
        while not self.shown(frame):
            if self.last_cached_s is None and all(
                    frames.cached(frame, c) is not None for c in cams):
                self.last_cached_s = time.perf_counter() - t0
            self.app.processEvents()
            if time.perf_counter() - t0 > timeout:
                raise RuntimeError(f"frame {frame} never showed")
            time.sleep(0.0005)
        if self.last_cached_s is None:
            self.last_cached_s = time.perf_counter() - t0
        return time.perf_counter() - t0

    # -- the measurements ------------------------------------------------------------
    def open_and_first_jump(self) -> None:
        try:  # proxies are measured on their own, later
            from carapost.ui.settings import set_build_proxies

            set_build_proxies(self.w.context.settings, False)
        except ImportError:
            pass
        t0 = time.perf_counter()
        self.w.context.set_session(self.session)
        self.w.flush()
        self.pump(0.05)
        emit("open_s", time.perf_counter() - t0, "s")
        n = self.p.n_frames
        emit("first_jump_s", self.go(int(n * 0.8)), "s", frame=int(n * 0.8))

    def opens(self, take: Path, count: int = 5) -> None:
        """Open the take ``count`` times more (a fresh session each time, as File >
        Open does) and measure each opening: the longest gap between ticks from the
        call to the images of every camera on screen and 0.3 s after (the panes are
        drawn by then), and the time to the first complete images."""
        from carapost.session import Session

        gaps, busy, first = [], [], []
        for k in range(count):
            # Read before, not part of the opening, and off the GUI thread as File >
            # Import does (a worker job): read here on the GUI thread, its 0.3-0.5 s
            # were counted as one gap of the "opens" phase. The ticks meanwhile (the
            # previous take's read-ahead, the worker's GIL use) are phase "opens_read".
            self.stalls.phase = "opens_read"
            with ThreadPoolExecutor(1) as reader:
                read = reader.submit(Session.import_take, take)
                while not read.done():
                    self.pump(0.01)
            session = read.result()   # an error of the reading is raised here
            self.stalls.phase = "opens"
            # a frame of its own per opening: a view still showing the previous take's
            # frame must not count as drawn
            session.project.set_current_frame((37 * (k + 1)) % max(session.project.n_frames, 1))
            self.pump(0.5)
            self.stalls.window_reset()
            t0 = time.perf_counter()
            self.w.context.set_session(session)
            self.w.flush()
            frame = session.project.current_frame
            while not self.shown(frame):
                self.app.processEvents()
                if time.perf_counter() - t0 > 60:
                    raise RuntimeError("the take's first images never showed")
                time.sleep(0.0005)
            first.append((time.perf_counter() - t0) * 1e3)
            self.pump(0.3)
            gaps.append(self.stalls.window_gap * 1e3)
            busy.append(self.stalls.window_busy * 1e3)
            self.session, self.p = session, session.project
        emit("open_stall_ms", statistics.median(gaps), "ms", max=round(max(gaps), 1),
             opens=count, gaps=[round(g, 1) for g in gaps],
             gui_cpu_ms_median=round(statistics.median(busy), 1),
             note="longest gap between 10 ms ticks while a take opens, median of opens")
        emit("open_first_images_ms", statistics.median(first), "ms",
             max=round(max(first), 1), note="set_session to the images of every camera")

    def jumps(self, count: int = 25) -> None:
        self.stalls.phase = "jumps"
        rng = random.Random(1)
        n = self.p.n_frames
        times, cached = [], []
        for _ in range(count):
            f = rng.randrange(n)
            while abs(f - self.p.current_frame) < 30:
                f = rng.randrange(n)
            times.append(self.go(f) * 1e3)
            cached.append(self.last_cached_s * 1e3)
            self.pump(0.05)
        # decoded: until every camera's image was in the cache (the frame service's
        # share); the rest is the GUI thread's, from there to the images on screen
        emit("jump_ms_p95", p95(times), "ms", median=round(statistics.median(times), 1),
             jumps=count, decoded_ms_p95=round(p95(cached), 1),
             decoded_ms_median=round(statistics.median(cached), 1),
             times=[round(t) for t in times])

    def steps(self, count: int = 30) -> None:
        self.stalls.phase = "steps"
        n = self.p.n_frames
        times, cpu, waits, misses = [], [], [], 0
        frames = self.w.context.frames
        sched = f"/proc/self/task/{threading.get_native_id()}/schedstat"

        def runq() -> float:
            try:
                with open(sched) as fh:
                    return int(fh.read().split()[1]) / 1e6
            except OSError:
                return 0.0

        for direction in (1, -1):
            start = n // 3 if direction > 0 else 2 * n // 3
            self.go(start)
            self.pump(1.5)  # the read-ahead runs while the artist looks
            for k in range(1, count + 1):
                f = start + direction * k
                misses += any(frames.cached(f, c) is None for c in range(self.p.n_cameras))
                c0, r0 = time.thread_time(), runq()
                times.append(self.go(f) * 1e3)
                cpu.append((time.thread_time() - c0) * 1e3)
                waits.append(runq() - r0)
                self.pump(0.1)
        # where a step's time goes: the GUI thread's own CPU, its wait for a core (run
        # queue) and the rest (blocked: the GIL, or a miss waiting for a decoder)
        emit("step_ms_p95", p95(times), "ms", median=round(statistics.median(times), 1),
             steps=len(times), cache_misses=misses,
             gui_cpu_ms_median=round(statistics.median(cpu), 2),
             gui_cpu_ms_p95=round(p95(cpu), 2), runqueue_ms_p95=round(p95(waits), 1),
             blocked_ms_p95=round(p95([t - c - w for t, c, w in
                                       zip(times, cpu, waits, strict=True)]), 1))

    def playback(self, seconds: float = 6.0) -> None:
        self.stalls.phase = "playback"
        p = self.p
        p.set_view_range((0, p.n_frames - 1)) if hasattr(p, "set_view_range") else None
        self._play_from_start(seconds, self.shown, "originals")

    def _play_from_start(self, seconds: float, shown: Callable[[int], bool],
                         source: str) -> None:
        """Play from frame 0 for ``seconds``; emit the rate of frames ``shown`` drew."""
        ctx, p = self.w.context, self.p
        self.go(0)
        self.pump(0.5)
        drawn: set[int] = set()
        t0 = time.perf_counter()
        gui0, cpu0 = time.thread_time(), time.process_time()
        self.decodes.reset()
        self.decodes.on = True
        ctx.playback.toggle(True)
        while ctx.playback.playing and time.perf_counter() - t0 < seconds:
            self.app.processEvents()
            if shown(p.current_frame):
                drawn.add(p.current_frame)
            time.sleep(0.0005)
        elapsed = time.perf_counter() - t0
        gui, cpu = time.thread_time() - gui0, time.process_time() - cpu0
        self.decodes.on = False
        ctx.playback.stop()
        emit("playback_fps", len(drawn) / elapsed, "frames/s", source=source,
             take_fps=p.take.fps, seconds=round(elapsed, 2),
             reported_dropped=ctx.playback.dropped,
             shown_late=getattr(ctx.playback, "late", None),
             gui_cpu_ms_per_frame=round(gui / max(len(drawn), 1) * 1e3, 2),
             cpu_ms_per_frame=round(cpu / max(len(drawn), 1) * 1e3, 2),
             **self.decodes.summary(p.n_cameras))

    def playback_from_proxies(self, seconds: float = 6.0) -> None:
        """Write the proxies (View > Build Playback Proxies), then play from them."""
        self.stalls.phase = "playback_from_proxies"
        ctx = self.w.context
        if not hasattr(ctx, "proxies"):
            return
        t0 = time.perf_counter()
        self.w.action("view.build_proxies").trigger()
        while ctx.proxies.running:
            self.pump(0.05)
        self.pump(0.2)
        emit("proxy_build_s", time.perf_counter() - t0, "s", cameras=self.p.n_cameras,
             frames=self.p.n_frames)
        n_cameras = self.p.n_cameras
        self._play_from_start(
            seconds, lambda f: all(ctx.frames.cached(f, c) is not None
                                   for c in range(n_cameras)), "proxies")

    def display_cost(self, count: int = 60) -> None:
        """GUI thread CPU per frame with every image cached (no decoding): what one
        frame costs to show in four views, whatever the load."""
        # a tight loop of its own, not something an artist does: no stall ticks meanwhile
        self.stalls.timer.stop()
        start = self.p.n_frames // 4
        frames = range(start, start + count)
        for f in frames:  # fill the cache
            self.go(f)
        self.pump(0.3)
        costs = []
        for _ in range(2):
            for f in frames:
                c0 = time.thread_time()
                self.w.set_frame(f)
                self.w.flush()
                for _ in range(3):  # delivery, then the paint events
                    self.app.processEvents()
                costs.append((time.thread_time() - c0) * 1e3)
        emit("gui_frame_cpu_ms", statistics.median(costs), "ms", p95=round(p95(costs), 2),
             frames=len(costs), note="GUI thread CPU per frame shown, images cached")
        self.stalls.start()

    def detect_current(self) -> None:
        self.stalls.phase = "detect_current"
        rng = random.Random(7)
        times = []
        for _ in range(3):
            f = rng.randrange(self.p.n_frames)
            t0 = time.perf_counter()
            self.w.set_frame(f)
            self.w.flush()
            self.w.action("process.blobs_current").trigger()
            while self.w.runner.busy:
                self.app.processEvents()
                time.sleep(0.001)
            times.append(time.perf_counter() - t0)
            self.pump(0.3)
        emit("detect_current_frame_s", statistics.median(times), "s",
             runs=[round(t, 3) for t in times])

    def scrub_session(self, seconds: float) -> None:
        self.stalls.phase = "scrub_session"
        rng = random.Random(3)
        n = self.p.n_frames
        peak = rss_mb()
        cache_peak = 0.0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            if rng.random() < 0.3:
                self.go(rng.randrange(n))
            else:
                f = self.p.current_frame
                for k in range(1, 11):
                    self.go(min(max(f + k, 0), n - 1))
                    self.pump(0.03)
            peak = max(peak, rss_mb())
            stats = getattr(self.w.context.frames, "stats", lambda: {})()
            cache_peak = max(cache_peak, stats.get("cache_mb", 0.0))
        stats = getattr(self.w.context.frames, "stats", lambda: {})()
        emit("rss_mb_max", peak, "MB", seconds=seconds,
             maxrss_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3))
        emit("cache_mb_max", cache_peak, "MB", limit_mb=stats.get("cache_limit_mb"))


def bench_codecs(take: Path) -> None:
    """Readers and proxy formats on the take's first video (one core, no window)."""
    import av
    import cv2

    from carapost.io.decode import AVReader

    video = sorted(p for p in take.parent.glob("*cam0.*") if p.suffix != ".json")[0]
    rng = random.Random(5)
    n = AVReader(video).n_frames
    targets = [rng.randrange(n) for _ in range(15)]
    cap = cv2.VideoCapture(str(video))
    t0 = time.perf_counter()
    for _ in range(60):
        cap.read()
    emit("opencv_sequential_ms", (time.perf_counter() - t0) / 60 * 1e3, "ms/frame")
    t0 = time.perf_counter()
    for k in targets:
        cap.set(cv2.CAP_PROP_POS_FRAMES, k)
        cap.read()
    emit("opencv_random_ms", (time.perf_counter() - t0) / len(targets) * 1e3, "ms/read")
    reader = AVReader(video)
    t0 = time.perf_counter()
    for i in range(60):
        reader.read(i)
    emit("pyav_sequential_ms", (time.perf_counter() - t0) / 60 * 1e3, "ms/frame")
    t0 = time.perf_counter()
    for k in targets:
        reader.read(k)
    emit("pyav_random_ms", (time.perf_counter() - t0) / len(targets) * 1e3, "ms/read",
         keyframe_interval=reader.index.max_interval)
    frames = [reader.read(i) for i in range(60)]
    with tempfile.TemporaryDirectory() as tmp:
        for name, codec, pix, half, opts in (
                ("mjpeg_full", "mjpeg", "yuvj420p", False, {"q:v": "4"}),
                ("mjpeg_half", "mjpeg", "yuvj420p", True, {"q:v": "4"}),
                ("ffv1_allkey_full", "ffv1", "gray", False, {"g": "1"}),
                ("ffv1_allkey_half", "ffv1", "gray", True, {"g": "1"})):
            path = Path(tmp) / f"{name}.{'avi' if codec == 'mjpeg' else 'mkv'}"
            out = av.open(str(path), "w")
            st = out.add_stream(codec, rate=60)
            h, w = frames[0].shape
            if half:
                h, w = h // 2, w // 2
            st.width, st.height, st.pix_fmt, st.options = w, h, pix, opts
            for img in frames:
                im = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA) if half else img
                for pk in st.encode(av.VideoFrame.from_ndarray(im, format="gray")):
                    out.mux(pk)
            for pk in st.encode():
                out.mux(pk)
            out.close()
            c = av.open(str(path))
            t0 = time.perf_counter()
            count = sum(1 for fr in c.decode(c.streams.video[0]) if fr.to_ndarray() is not None)
            c.close()
            emit(f"proxy_{name}_decode_ms", (time.perf_counter() - t0) / count * 1e3,
                 "ms/frame", kb_per_frame=round(path.stat().st_size / count / 1e3))


def render_take(folder: Path, frames: int) -> Path:
    from carapost.synth import SynthConfig, generate_take

    return Path(generate_take(folder, SynthConfig(preset="speech", frames=frames, seed=0),
                              workers=2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("take", nargs="?", help="take .json (default: render 300 frames)")
    ap.add_argument("--scrub-s", type=float, default=120.0)
    ap.add_argument("--codecs", action="store_true", help="also measure readers/proxies")
    ap.add_argument("--profile", action="store_true",
                    help="time the GUI thread's drawing and delivery; charge stalls to it")
    ap.add_argument("--only", default="",
                    help="comma-separated phases: opens,jumps,steps,display,playback,detect,"
                         "scrub,proxies")
    ap.add_argument("--opens", type=int, default=5, help="openings measured (opens phase)")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="sys.setswitchinterval in seconds (0: the application's own)")
    args = ap.parse_args()
    from carapost.ui.app import application

    only = set(filter(None, args.only.split(",")))

    def run(phase: str) -> bool:
        return not only or phase in only

    if args.switch_interval > 0:
        sys.setswitchinterval(args.switch_interval)
    tmp = tempfile.TemporaryDirectory()
    take = Path(args.take) if args.take else render_take(Path(tmp.name), 300)
    if args.codecs:
        bench_codecs(take)
    profiler = None
    if args.profile:
        sys.path.insert(0, str(Path(__file__).parent))
        from gui_profile import GuiProfiler

        profiler = GuiProfiler()
        profiler.install()
    app = application()
    b = Bench(app, take, profiler)
    if profiler is not None:
        profiler.start_sampler(lambda: getattr(b.stalls, "last", time.perf_counter()))
    cpu0, steal0 = time.process_time(), steal_s()
    b.open_and_first_jump()
    if run("opens"):
        b.opens(take, args.opens)
    if run("jumps"):
        b.jumps()
    if run("steps"):
        b.steps()
    if run("display"):
        b.display_cost()
    if run("playback"):
        b.playback()
    if run("detect"):
        b.detect_current()
    emit("gui_stall_ms_max", b.stalls.max_gap * 1e3, "ms",
         by_phase={k: round(v * 1e3) for k, v in b.stalls.by_phase.items()})
    if run("scrub"):
        b.scrub_session(args.scrub_s)
    if run("proxies"):
        b.playback_from_proxies()
    emit("gui_stall_ms_max_all", b.stalls.max_gap * 1e3, "ms",
         by_phase={k: round(v * 1e3) for k, v in b.stalls.by_phase.items()},
         note="including the scrub session and proxy playback")
    emit("gui_busy_ms_max", b.stalls.max_busy * 1e3, "ms",
         by_phase={k: round(v * 1e3) for k, v in b.stalls.busy_by_phase.items()},
         note="GUI thread CPU time between two 10 ms ticks (the load does not stretch it)")
    print(json.dumps({"longest_gap_split": b.stalls.worst}), flush=True)
    print(json.dumps({"garbage_collections": b.stalls.gc_by_phase}), flush=True)
    if profiler is not None:
        print(json.dumps({"profile": profiler.report()}, indent=1), flush=True)
    emit("cpu_s", time.process_time() - cpu0, "s")
    emit("steal_s", steal_s() - steal0, "s",
         note="CPU time the hypervisor gave other tenants during the run, all CPUs")
    b.w.context.stack.mark_clean()  # no "save changes?" box for the detections made
    b.p.modified = False
    b.w.context.shutdown()
    b.w.close()
    tmp.cleanup()
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
