"""How long a GUI-like thread waits for a core while four camera decoders run.

Run::

    python benchmarks/decoder_contention.py TAKE_FOLDER [--repeats 3] [--seconds 4]

``TAKE_FOLDER`` holds the camera videos (``*_cam*.mkv``, e.g. a take rendered by
``carapost synth`` or by ``benchmarks/playback.py``). One thread per video decodes it
in a loop, as `carapost.io.frameservice.FrameService` does, at a nice increment and
with an FFmpeg thread count per variant; the main thread (nice 0) stands for the GUI
thread: it sleeps 10 ms, does about 1 ms of work, and reads its own run-queue wait
from ``/proc/thread-self/schedstat`` (Linux). The variants are interleaved, so a
loaded machine weighs on each alike; the run-queue wait is the figure to compare, the
decode rate says whether the decoders lost throughput.

Output, one line per trial: the tick gap p95 and max (ms), the run-queue wait per tick
p95 (ms), and the frames decoded per second by all decoders together.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from pathlib import Path

import av
import numpy as np

#: (nice increment, FFmpeg threads per decoder; 0 = FFmpeg's default)
VARIANTS = [(4, 0), (4, 1), (10, 0), (10, 1)]


def _schedstat() -> tuple[float, float]:
    """(CPU time, run-queue wait) of the calling thread so far, ms."""
    with open("/proc/thread-self/schedstat") as fh:
        run, wait, _ = fh.read().split()
    return int(run) / 1e6, int(wait) / 1e6


def trial(videos: list[Path], nice: int, threads: int, seconds: float) -> None:
    stop = threading.Event()
    counts = [0] * len(videos)

    def decode(i: int) -> None:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + nice)
        while not stop.is_set():
            with av.open(str(videos[i])) as container:
                stream = container.streams.video[0]
                if threads:
                    stream.codec_context.thread_count = threads
                for frame in container.decode(stream):
                    frame.to_ndarray()
                    counts[i] += 1
                    if stop.is_set():
                        break

    workers = [threading.Thread(target=decode, args=(i,)) for i in range(len(videos))]
    for w in workers:
        w.start()
    time.sleep(0.3)  # decoders running
    gaps, waits = [], []
    end = time.perf_counter() + seconds
    decoded0 = sum(counts)
    last = time.perf_counter()
    while time.perf_counter() < end:
        _, w0 = _schedstat()
        time.sleep(0.010)
        now = time.perf_counter()
        gaps.append((now - last) * 1e3)
        last = now
        x = 0
        for _ in range(20000):  # about 1 ms of GUI work
            x += 1
        _, w1 = _schedstat()
        waits.append(w1 - w0)
    rate = (sum(counts) - decoded0) / seconds
    stop.set()
    for w in workers:
        w.join()
    g, q = np.array(gaps), np.array(waits)
    print(f"nice=+{nice:<2d} threads={threads} load={os.getloadavg()[0]:4.1f}  "
          f"gap p95 {np.percentile(g, 95):6.1f} max {g.max():6.1f} ms  "
          f"runqueue p95 {np.percentile(q, 95):5.1f} ms  decoded {rate:5.1f} frames/s",
          flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=4.0)
    args = ap.parse_args()
    videos = sorted(args.folder.glob("*_cam*.mkv"))
    if not videos:
        raise SystemExit(f"no *_cam*.mkv in {args.folder}")
    for _ in range(args.repeats):
        for nice, threads in VARIANTS:
            trial(videos, nice, threads, args.seconds)


if __name__ == "__main__":
    main()
