"""The decode path of the frame service, without a window: jumps, steps, the first jump,
Detect Blobs [Current Frame], and the keyframe index of long takes.

Usage::

    python benchmarks/frame_access.py TAKE.json [TAKE.json ...]
    python benchmarks/frame_access.py --transcode OUT --gop 1 TAKE.json   # GOP variant
    python benchmarks/frame_access.py --long OUT --frames 36000 TAKE.json  # long take

``--transcode`` copies a take with its videos re-encoded losslessly (same pixels) with a
keyframe every ``--gop`` frames (`carapost.io.encode.FFV1Writer`). ``--long`` makes a
take of ``--frames`` frames by repeating camera 0's video (packets copied, timestamps
shifted: no re-encoding) and giving every camera a hard link of it, so four decoders
read four paths of the same content without four times the disk space.

Metrics (one JSON object per line, ``take`` and ``gop`` name the take measured):

* ``index_build_s``: importing the take with an empty user cache (the keyframe index of
  every video is built by demuxing it, and the last frame checked), ``index_mb`` the
  memory of the four indexes, ``index_file_kb`` their stored size.
* ``first_jump_s``: a new frame service (videos opened on the decoder threads), all
  four cameras of frame ``0.8 n + 7`` decoded.
* ``jump_ms_p95``: 25 random jumps, four cameras each (with the CPU time and decodes).
* ``step_ms_p95``: Next/Prev Frame every 100 ms after a 1.5 s pause (read-ahead).
* ``detect_current_frame_s``: a jump to a frame not cached and Detect Blobs [Current
  Frame] on it (the job reads through the same service, detects in-process).

Times are from the request to the images of all four cameras in the cache: the drawing
in the window is `benchmarks/playback.py`'s part.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(float(value), 4), "unit": unit,
                      **extra}), flush=True)


def p95(values: list[float]) -> float:
    return float(np.percentile(values, 95))


def _videos(take: Path) -> list[Path]:
    meta = json.loads(take.read_text())
    return [take.parent / v for v in meta["videos"]]


def _copy_side_files(take: Path, out: Path, frames: int | None = None) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    for f in take.parent.iterdir():
        if f.is_file() and f.suffix not in (".mkv", ".mp4") and f.name != "truth.npz":
            shutil.copy(f, out / f.name)
    if frames is not None:
        meta = json.loads(take.read_text())
        meta["frames"] = int(frames)
        (out / take.name).write_text(json.dumps(meta, indent=2))
    return out / take.name


def transcode(take: Path, out: Path, gop: int) -> Path:
    """The take with every video re-encoded losslessly, a keyframe every ``gop``."""
    from concurrent.futures import ThreadPoolExecutor

    from carapost.io.decode import AVReader
    from carapost.io.encode import FFV1Writer

    new = _copy_side_files(take, out)

    def one(video: Path) -> None:
        r = AVReader(video)
        with FFV1Writer(out / video.name, r.size, r.fps or 60.0, gop=gop,
                        slices=4 if gop == 1 else 1) as w:
            for i in range(r.n_frames):
                w.write(r.read(i))

    with ThreadPoolExecutor(2) as pool:
        list(pool.map(one, _videos(take)))
    return new


def make_long(take: Path, out: Path, frames: int) -> Path:
    """A take of ``frames`` frames: camera 0's video repeated (packets copied)."""
    import av

    videos = _videos(take)
    new = _copy_side_files(take, out, frames)
    first = out / videos[0].name
    src = av.open(str(videos[0]))
    st = src.streams.video[0]
    packets = [(p.pts, p.dts, p.is_keyframe, bytes(p)) for p in src.demux(st) if p.size]
    n = len(packets)
    period = packets[1][0] - packets[0][0]
    span = packets[-1][0] - packets[0][0] + period
    dst = av.open(str(first), "w", format="matroska")
    ost = dst.add_stream_from_template(st)
    written = 0
    loop = 0
    while written < frames:
        for pts, dts, key, data in packets:
            if written >= frames:
                break
            pk = av.Packet(data)
            pk.pts = pts + loop * span
            pk.dts = (dts if dts is not None else pts) + loop * span
            pk.is_keyframe = key
            pk.stream = ost
            pk.time_base = st.time_base
            dst.mux(pk)
            written += 1
        loop += 1
    dst.close()
    src.close()
    for v in videos[1:]:
        os.link(first, out / v.name)
    print(f"wrote {frames} frames ({n}-frame clip x {loop}) to {out}", file=sys.stderr)
    return new


def measure(take: Path) -> None:
    from carapost.algorithms.blobs import warm_up
    from carapost.commands.process import prepare_detect_blobs
    from carapost.io.decode import KeyframeIndex
    from carapost.io.frameservice import FrameService
    from carapost.session import Session

    label = take.parent.name
    cache = Path(tempfile.mkdtemp(prefix="carapost-index-"))
    os.environ["CARAPOST_CACHE_DIR"] = str(cache)
    t0, c0 = time.perf_counter(), time.process_time()
    session = Session.import_take(take)
    build = time.perf_counter() - t0
    project = session.project
    t = project.take
    n = t.n_frames
    indexes = [KeyframeIndex.load(Path(c.video_path)) for c in t.cameras]
    gop = max(ix.max_interval for ix in indexes)
    tag = {"take": label, "frames": n, "gop": gop}
    emit("index_build_s", build, "s", cpu_s=round(time.process_time() - c0, 2), **tag)
    emit("index_mb", sum(ix.pts.nbytes + ix.keyframe.nbytes for ix in indexes) / 1e6, "MB",
         index_file_kb=round(sum(f.stat().st_size for f in cache.rglob("*.npz")) / 1e3, 1),
         **tag)
    warm_up()

    def decoded(fs: FrameService) -> int:
        return sum(getattr(fs._sources.get(c), "_reader", None).decoded
                   for c in range(t.n_cameras) if fs._sources.get(c) is not None)

    def all_cams(fs: FrameService, frame: int) -> tuple[float, float]:
        t0, c0 = time.perf_counter(), time.process_time()
        for c in range(t.n_cameras):
            fs.get(frame, c)
        return (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3

    fs = FrameService(t)
    target = min(int(0.8 * n) + 7, n - 1)
    wall, cpu = all_cams(fs, target)
    emit("first_jump_s", wall / 1e3, "s", cpu_s=round(cpu / 1e3, 3), frame=target,
         decodes=decoded(fs), **tag)

    rng = random.Random(1)
    walls, cpus = [], []
    d0 = decoded(fs)
    for _ in range(25):
        f = rng.randrange(n)
        while fs.get_cached(f, 0) is not None:
            f = rng.randrange(n)
        wall, cpu = all_cams(fs, f)
        walls.append(wall)
        cpus.append(cpu)
        time.sleep(0.05)
    emit("jump_ms_p95", p95(walls), "ms", median=round(statistics.median(walls), 1),
         cpu_ms_median=round(statistics.median(cpus), 1),
         decodes_per_camera=round((decoded(fs) - d0) / 25 / t.n_cameras, 2), **tag)

    steps = []
    misses = 0
    for direction in (1, -1):
        start = n // 3 if direction > 0 else 2 * n // 3
        fs.request(start, direction=direction)
        all_cams(fs, start)
        time.sleep(1.5)
        for k in range(1, 31):
            f = start + direction * k
            misses += any(fs.get_cached(f, c) is None for c in range(t.n_cameras))
            fs.request(f, direction=direction)
            steps.append(all_cams(fs, f)[0])
            time.sleep(0.1)
    emit("step_ms_p95", p95(steps), "ms", median=round(statistics.median(steps), 2),
         cache_misses=misses, steps=len(steps), **tag)

    times, cpus = [], []
    for _ in range(3):
        f = rng.randrange(n)
        while fs.get_cached(f, 0) is not None:
            f = rng.randrange(n)
        project.set_current_frame(f)
        t0, c0 = time.perf_counter(), time.process_time()
        fs.request(f)  # what Go To Frame does
        job = prepare_detect_blobs(project, None, None, fs.get, 2,
                                   "Detect Blobs [Current Frame]")
        result = job.compute(None)
        session.apply(result)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        time.sleep(0.3)
    emit("detect_current_frame_s", statistics.median(times), "s",
         runs=[round(x, 3) for x in times], cpu_s_median=round(statistics.median(cpus), 3),
         **tag)
    fs.close()
    shutil.rmtree(cache, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("takes", nargs="+", type=Path)
    ap.add_argument("--transcode", type=Path, help="write a GOP variant here")
    ap.add_argument("--gop", type=int, default=1)
    ap.add_argument("--long", type=Path, help="write a long take here")
    ap.add_argument("--frames", type=int, default=36000)
    args = ap.parse_args()
    print(json.dumps({"uptime": os.getloadavg(), "date": time.strftime("%Y-%m-%d %H:%M")}),
          file=sys.stderr)
    if args.transcode:
        print(transcode(args.takes[0], args.transcode, args.gop))
        return
    if args.long:
        print(make_long(args.takes[0], args.long, args.frames))
        return
    for take in args.takes:
        measure(take)


if __name__ == "__main__":
    main()
