"""Where the GUI thread's time goes: timers around the window's drawing and delivery.

Used by ``benchmarks/playback.py --profile``. `GuiProfiler.install` wraps the methods
the GUI thread runs per frame (the views' ``refresh``, pyqtgraph's ``setImage`` /
``render`` / ``paint``, the panes' change handlers, frame delivery, the playback tick)
with timers that record wall time and the GUI thread's own CPU time. `attribute` is
called by the stall meter for every long gap between two timer ticks and charges the
gap to the wrapped calls that ran in it, so a report says which calls make the stalls
and how much of a stall was the GUI thread computing (CPU) rather than waiting (for
the GIL, or for a core on a loaded machine).
"""

from __future__ import annotations

import functools
import importlib
import inspect
import sys
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable

#: Method names wrapped wherever a carapost.ui class defines them.
UI_METHODS = ("refresh", "paintEvent", "_changed", "_frame_ready", "_tick", "flush",
              "_draw_image", "_draw_overlays", "_update_rotation", "_show_frames",
              "set_frame", "_invalidate", "resizeEvent", "_rate")
UI_MODULES = ("carapost.ui.views.camera", "carapost.ui.views.graph",
              "carapost.ui.views.continuity", "carapost.ui.views.view3d",
              "carapost.ui.panes", "carapost.ui.timebar", "carapost.ui.workspace",
              "carapost.ui.statusbar", "carapost.ui.mainwindow", "carapost.ui.context",
              "carapost.ui.playback", "carapost.ui.bridge", "carapost.ui.labelling_pane",
              "carapost.ui.empty_state", "carapost.ui.views.target_overlay")
PG_METHODS = {
    "ImageItem": ("setImage", "render", "paint"),
    "PlotCurveItem": ("setData", "paint"),
    "ScatterPlotItem": ("setData", "paint"),
    "GraphicsView": ("paintEvent",),
    "ViewBox": ("updateAutoRange", "updateMatrix"),
}


class GuiProfiler:
    """Timers around GUI-thread methods; gaps charged to the calls inside them."""

    def __init__(self) -> None:
        self.main = threading.main_thread().ident
        self.total: dict[str, list[float]] = defaultdict(lambda: [0, 0.0, 0.0, 0.0])
        self.intervals: list[tuple[float, float, float, str, int]] = []
        self.depth = 0
        self.stalls: list[dict] = []
        # Python stacks of the GUI thread sampled while a timer tick is overdue, as
        # (time, stack): what the thread ran in a burst that no wrapped method covers
        # (a lazy import, a first use, C++ reached from an unwrapped slot)
        self.samples: list[tuple[float, tuple[str, ...]]] = []
        self._sampling = False

    # -- sampling -------------------------------------------------------------------------
    def start_sampler(self, last_tick: Callable[[], float], interval: float = 0.003,
                      after: float = 0.015) -> None:
        """Sample the GUI thread's stack every ``interval`` s once ``after`` s have passed
        since the last tick (``last_tick()``, perf_counter). Costs nothing between
        stalls but a short wake-up; the sampler needs the GIL, so a stall spent in
        Python is sampled at the interpreter's switch interval (5 ms)."""
        self._sampling = True

        def where(frame, depth: int) -> tuple[str, ...]:
            stack = []
            while frame is not None and len(stack) < depth:
                code = frame.f_code
                path = code.co_filename
                short = path.rsplit("/site-packages/", 1)[-1].rsplit("/src/", 1)[-1]
                stack.append(f"{short}:{frame.f_lineno} {code.co_name}")
                frame = frame.f_back
            return tuple(stack)

        me = threading.get_ident()

        def loop() -> None:
            frames = sys._current_frames
            while self._sampling:
                time.sleep(interval)
                now = time.perf_counter()
                if now - last_tick() < after:
                    continue
                current = frames()
                names = {t.ident: t.name for t in threading.enumerate()}
                # the other threads' innermost frames: where each one was when it last
                # gave up the GIL (a thread in a C call shows the call's line), which
                # tells what may have held it while the GUI thread waited
                others = tuple(f"{names.get(ident, ident)}: {' < '.join(where(fr, 2))}"
                               for ident, fr in current.items()
                               if ident not in (self.main, me))
                self.samples.append((now, where(current.get(self.main), 14), others))

        threading.Thread(target=loop, name="gui-stack-sampler", daemon=True).start()

    def stop_sampler(self) -> None:
        self._sampling = False

    def _stacks_in(self, t0: float, t1: float, top: int = 3) -> dict:
        """The stacks sampled in [t0, t1]: the most common whole stacks, and every
        function (file and name, no line) with the number of samples it was on the
        stack in (inclusive counts)."""
        stacks = [st for t, st, _ in self.samples if t0 <= t <= t1]
        counts = Counter(stacks)
        inclusive: Counter[str] = Counter()
        for st in stacks:
            inclusive.update({f"{fr.split(':', 1)[0]} {fr.split(' ', 1)[1]}" for fr in st})
        others: Counter[str] = Counter()
        for t, _, other in self.samples:
            if t0 <= t <= t1:
                others.update(other)
        return {"samples": len(stacks),
                "top": [{"n": n, "stack": list(st)} for st, n in counts.most_common(top)],
                "functions": dict(inclusive.most_common(25)),
                "other_threads": dict(others.most_common(12))}

    # -- wrapping -------------------------------------------------------------------------
    def _wrap(self, owner: type, name: str) -> None:
        fn = owner.__dict__.get(name)
        if fn is None or not callable(fn) or getattr(fn, "_profiled", False):
            return
        label = f"{owner.__name__}.{name}"
        prof = self

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if threading.get_ident() != prof.main:
                return fn(*args, **kwargs)
            prof.depth += 1
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                t1, c1 = time.perf_counter(), time.thread_time()
                prof.depth -= 1
                row = prof.total[label]
                row[0] += 1
                row[1] += t1 - t0
                row[2] += c1 - c0
                row[3] = max(row[3], t1 - t0)
                if t1 - t0 > 0.002:
                    prof.intervals.append((t0, t1, c1 - c0, label, prof.depth))

        wrapper._profiled = True  # type: ignore[attr-defined]
        setattr(owner, name, wrapper)

    def install(self) -> None:
        """Wrap the methods (call before the window is built)."""
        import pyqtgraph as pg

        for mod_name in UI_MODULES:
            try:
                mod = importlib.import_module(mod_name)
            except ImportError:
                continue
            for _, cls in inspect.getmembers(mod, inspect.isclass):
                if cls.__module__ != mod_name:
                    continue
                for name in UI_METHODS:
                    self._wrap(cls, name)
        for cls_name, names in PG_METHODS.items():
            cls = getattr(pg, cls_name)
            for name in names:
                self._wrap(cls, name)

    # -- attribution ----------------------------------------------------------------------
    def attribute(self, t0: float, t1: float, cpu: float, phase: str,
                  gc_ms: float = 0.0) -> None:
        """Charge the gap [t0, t1] (GUI thread CPU ``cpu`` s, ``gc_ms`` of garbage
        collection in any thread) to the calls in it."""
        parts: dict[str, float] = defaultdict(float)
        for a, b, _c, label, depth in self.intervals:
            if b < t0 or a > t1:
                continue
            if depth == 0:
                parts[label] += min(b, t1) - max(a, t0)
        top = sorted(parts.items(), key=lambda kv: -kv[1])[:5]
        self.stalls.append({"phase": phase, "gap_ms": round((t1 - t0) * 1e3, 1),
                            "gui_cpu_ms": round(cpu * 1e3, 1), "gc_ms": round(gc_ms, 1),
                            "in": {k: round(v * 1e3, 1) for k, v in top},
                            "stacks": self._stacks_in(t0, t1)})

    def prune(self, before: float) -> None:
        """Forget intervals that ended before ``before`` (keeps memory bounded)."""
        if len(self.intervals) > 20000:
            self.intervals = [iv for iv in self.intervals if iv[1] >= before]
        if len(self.samples) > 20000:
            self.samples = [sm for sm in self.samples if sm[0] >= before]

    def report(self, top: int = 25) -> dict:
        """Totals by method (calls, wall ms, CPU ms, max ms) and the longest stalls."""
        rows = sorted(self.total.items(), key=lambda kv: -kv[1][1])[:top]
        return {
            "by_method": {k: {"calls": int(v[0]), "wall_ms": round(v[1] * 1e3),
                              "cpu_ms": round(v[2] * 1e3),
                              "per_call_ms": round(v[1] * 1e3 / max(v[0], 1), 2),
                              "max_ms": round(v[3] * 1e3, 1)} for k, v in rows},
            "longest_stalls": sorted(self.stalls, key=lambda s: -s["gap_ms"])[:15],
            "longest_gui_cpu": sorted(self.stalls, key=lambda s: -s["gui_cpu_ms"])[:15],
        }
