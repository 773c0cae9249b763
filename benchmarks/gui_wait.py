"""How long a GUI-like thread waits beside the frame service's decoders, without a window.

Run::

    python benchmarks/gui_wait.py TAKE.json [--mode play|jumps] [--seconds 4] [--trials 3]

A `carapost.io.frameservice.FrameService` on the take (a fresh one per trial, so no
frame is cached at the start) plays from the originals (``play``: the playback clock
at the take's rate drives ``set_clock``, as the window's playback does) or is sent to a
random frame every 150 ms (``jumps``: ``request``, as Go To Frame does). The main thread
(nice 0) stands for the GUI thread: every 10 ms it looks up the four images shown
(``display``), copies them (the views' conversion to a QImage) and does ~1 ms of Python.

Per trial (one JSON line): the tick gaps (p50, p99, max in ms: the figure the window's
``gui_stall_ms_max`` measures), and the worst gap split into the ticker's own CPU, its
run-queue wait (``/proc/thread-self/schedstat``) and the rest ("blocked": waiting for
the GIL or a lock); the frames decoded per second by all decoders; and the decoders' CPU
under the GIL per decoded frame (``gil_ms_per_frame``: each decoder thread's CPU time
outside the decode call of PyAV, which releases the GIL, divided by the frames).

The run-queue share depends on the machine's load; the blocked share much less, so it
is the figure to compare between builds (run them interleaved: the script only uses the
service's public calls, so ``PYTHONPATH`` may point at any version). Variants of one
build: ``--set DECODE_SLOTS=1`` (a constant of `carapost.io.frameservice`),
``--switch-interval 0.001`` (`sys.setswitchinterval`). ``--cache-mb 300`` makes every
insert evict an image once the cache is full, as on a long take.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np


def _schedstat() -> tuple[float, float]:
    """(CPU time, run-queue wait) of the calling thread so far, ms."""
    with open("/proc/thread-self/schedstat") as fh:
        run, wait, _ = fh.read().split()
    return int(run) / 1e6, int(wait) / 1e6


class _DecodeClock:
    """Per decoder thread: CPU time inside PyAV's decode call (which releases the GIL)
    and frames decoded, by wrapping `AVReader.read`'s iterator step."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.cpu_gil: dict[int, float] = {}
        self.last_exit: dict[int, float] = {}

    def install(self) -> None:
        from carapost.io import decode

        clock = self
        orig_open = decode.AVReader._open

        class _Timed:
            def __init__(self, it):
                self.it = it

            def __iter__(self):
                return self

            def __next__(self):
                t0 = time.thread_time()
                tid = threading.get_ident()
                last = clock.last_exit.get(tid)
                if last is not None:  # CPU since the last decode call: under the GIL
                    clock.cpu_gil[tid] = clock.cpu_gil.get(tid, 0.0) + (t0 - last)
                try:
                    return next(self.it)
                finally:
                    clock.last_exit[tid] = time.thread_time()

        def _open(reader):
            orig_open(reader)
            reader._frames = _Timed(reader._frames)

        orig_seek = decode.AVReader._seek

        def _seek(reader, index):
            orig_seek(reader, index)
            reader._frames = _Timed(reader._frames)

        decode.AVReader._open = _open
        decode.AVReader._seek = _seek


def trial(take, mode: str, seconds: float, cache_mb: float, seed: int,
          clock: _DecodeClock) -> dict:
    from carapost.io.frameservice import FrameService

    n, ncam = take.n_frames, take.n_cameras
    fps = float(take.fps or 60.0)
    fs = FrameService(take, cache_mb=cache_mb)
    rng = random.Random(seed)
    cpu0 = {}

    def decoders() -> list[threading.Thread]:
        return [t for t in threading.enumerate() if t.name.startswith("carapost-decode")]

    start = rng.randrange(max(n - int(fps * seconds) - 1, 1))
    if mode == "play":
        fs.set_read_ahead(int(2 * fps), playing=True)
        fs.request(start, direction=1)
    else:
        fs.request(start)
    time.sleep(0.2)  # videos opened
    threads = decoders()
    proc_cpu0 = time.process_time()
    clock.last_exit.clear()  # thread ids of an earlier trial's decoders are reused
    gil0 = dict(clock.cpu_gil)
    for t in threads:
        cpu0[t.native_id] = _thread_cpu(t.native_id)
    dec0 = _decoded(fs)
    sw0 = {t.native_id: _switches(t.native_id) for t in threads}
    me0 = _switches()
    gaps, cpus, waits, parts = [], [], [], []
    t0 = time.perf_counter()
    last = t0
    next_jump = t0
    frame = start
    x = 0
    last_c, last_w = _schedstat()
    work = (0.0, 0.0, 0.0)
    while True:
        s0 = time.perf_counter()
        time.sleep(0.010)
        now = time.perf_counter()
        c, w = _schedstat()
        if now - t0 > seconds:
            break
        # from the previous tick's wake-up to this one's: its work, then this sleep
        gaps.append((now - last) * 1e3)
        cpus.append(c - last_c)
        waits.append(w - last_w)
        parts.append((*work, (now - s0) * 1e3 - 10.0))
        last, last_c, last_w = now, c, w
        # the GUI's tick: the clock, the images shown, their conversion, some Python
        if mode == "play":
            due = min(start + int((now - t0) * fps), n - 1)
            fs.set_clock(due)
        s1 = time.perf_counter()
        if mode == "play":
            for f in range(due, frame, -1):
                if all(fs.display(f, c)[0] is not None for c in range(ncam)):
                    frame = f
                    break
        elif now >= next_jump:
            frame = rng.randrange(n)
            fs.request(frame)
            next_jump = now + 0.15
        for c in range(ncam):
            img = fs.display(frame, c)[0]
            if img is not None:
                img.copy()
        s2 = time.perf_counter()
        for _ in range(15000):
            x += 1
        s3 = time.perf_counter()
        work = ((s1 - now) * 1e3, (s2 - s1) * 1e3, (s3 - s2) * 1e3)
    elapsed = time.perf_counter() - t0
    me1 = _switches()
    sw1 = {t.native_id: _switches(t.native_id) for t in threads}
    dec_vol = sum(sw1[k][0] - sw0[k][0] for k in sw0)
    dec_inv = sum(sw1[k][1] - sw0[k][1] for k in sw0)
    decoded = _decoded(fs) - dec0
    dec_cpu = sum(_thread_cpu(t.native_id) - cpu0[t.native_id] for t in threads) * 1e3
    ids = {t.ident for t in threads}
    gil = sum(v - gil0.get(k, 0.0) for k, v in clock.cpu_gil.items() if k in ids) * 1e3
    proc_cpu = (time.process_time() - proc_cpu0) * 1e3
    fs.close()
    g = np.array(gaps)
    worst = int(np.argmax(g))
    blocked = g[worst] - 10.0 - cpus[worst] - waits[worst]
    blk = g - 10.0 - np.array(cpus) - np.array(waits)
    return {
        "mode": mode, "load": round(os.getloadavg()[0], 1),
        "gap_p50": round(float(np.percentile(g, 50)), 1),
        "gap_p99": round(float(np.percentile(g, 99)), 1),
        "gap_max": round(float(g.max()), 1),
        "over_30": int((g > 30).sum()), "over_50": int((g > 50).sum()), "ticks": len(g),
        "worst_cpu": round(cpus[worst], 1), "worst_runq": round(waits[worst], 1),
        "worst_blocked": round(float(blocked), 1),
        # the worst gap's wall time: set_clock, images, Python loop, sleep overshoot
        "worst_parts": [round(v, 1) for v in parts[worst]],
        "blocked_p99": round(float(np.percentile(blk, 99)), 1),
        "blocked_mean": round(float(blk.mean()), 2),
        "runq_mean": round(float(np.mean(waits)), 2),
        # the ticker's voluntary switches per tick beyond its sleep (waits for the GIL
        # or a lock), the decoders' per frame decoded (voluntary / preempted)
        "gui_waits_per_tick": round((me1[0] - me0[0]) / len(g) - 1.0, 2),
        "dec_switches_per_frame": [round(dec_vol / max(decoded, 1), 2),
                                   round(dec_inv / max(decoded, 1), 2)],
        "decoded_per_s": round(decoded / elapsed, 1),
        "decoder_cpu_ms_per_frame": round(dec_cpu / max(decoded, 1), 2),
        "gil_ms_per_frame": round(gil / max(decoded, 1), 3),
        "process_cpu_ms_per_frame": round(proc_cpu / max(decoded, 1), 2),
    }


def _switches(native_id: int | None = None) -> tuple[int, int]:
    """(voluntary, involuntary) context switches of a thread of this process so far."""
    path = f"/proc/self/task/{native_id}/status" if native_id else "/proc/thread-self/status"
    vol = inv = 0
    try:
        with open(path) as fh:
            for line in fh:
                if line.startswith("voluntary_ctxt_switches"):
                    vol = int(line.split()[1])
                elif line.startswith("nonvoluntary_ctxt_switches"):
                    inv = int(line.split()[1])
    except OSError:
        pass
    return vol, inv


def _thread_cpu(native_id: int) -> float:
    """CPU time of a thread of this process, s (Linux)."""
    try:
        with open(f"/proc/self/task/{native_id}/schedstat") as fh:
            return int(fh.read().split()[0]) / 1e9
    except OSError:
        return 0.0


def _decoded(fs) -> int:
    total = 0
    for c in range(fs.take.n_cameras):
        reader = getattr(fs._sources.get(c), "_reader", None)
        total += getattr(reader, "decoded", 0) if reader is not None else 0
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("take", type=Path)
    ap.add_argument("--mode", default="play", choices=["play", "jumps"])
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--cache-mb", type=float, default=1500.0)
    ap.add_argument("--tag", default="")
    ap.add_argument("--switch-interval", type=float, default=0.0,
                    help="sys.setswitchinterval in seconds (0: the default, 5 ms)")
    ap.add_argument("--set", action="append", default=[],
                    help="NAME=VALUE: a constant of carapost.io.frameservice (variants)")
    args = ap.parse_args()
    if args.switch_interval:
        sys.setswitchinterval(args.switch_interval)
    import carapost.io.frameservice as frameservice

    for item in args.set:
        name, value = item.split("=")
        setattr(frameservice, name, type(getattr(frameservice, name))(value))
    os.environ.setdefault("CARAPOST_CACHE_DIR",
                          str(Path(tempfile.gettempdir()) / "carapost-gui-wait-cache"))
    from carapost.session import Session

    take = Session.import_take(args.take).project.take
    clock = _DecodeClock()
    clock.install()
    for k in range(args.trials):
        row = trial(take, args.mode, args.seconds, args.cache_mb, k, clock)
        print(json.dumps({"tag": args.tag, **row}), flush=True)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
