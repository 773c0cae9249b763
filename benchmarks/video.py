"""Frame access speed: sequential decode (frames/s) and random-access latency.

Writes 1280x720 gray test videos of 300 frames (FFV1 in .mkv, mp4v in .mp4) into a
temporary folder: a smooth shaded background, 90 dark dots drifting a little from frame
to frame and sensor noise (sigma 2 grey levels), like a head-camera view. Then measures,
through `carapost.io.video.VideoSource`:

- ``decode_ffv1_fps`` / ``decode_mp4v_fps``: reading every frame in order (frames/s),
  median of 3 runs;
- ``random_access_ms``: latency of one read at a random frame of the FFV1 video
  (seeks; every read lands on a frame other than the next one), median of 3 runs of 25
  reads each.

Run from the repository root: ``python benchmarks/video.py``.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from carapost.io.video import VideoSource

W, H, N = 1280, 720, 300
RUNS = 3


def _frames(rng: np.random.Generator):
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    base = 150 + 50 * np.cos((xx - W / 2) / W * 2.5) * np.cos((yy - H / 2) / H * 2.0)
    dots = rng.uniform([60, 60], [W - 60, H - 60], (90, 2))
    for i in range(N):
        img = base.copy()
        pos = dots + 8 * np.sin(i / 15 + np.arange(90))[:, None]
        for x, y in pos:
            cv2.circle(img, (int(x * 16), int(y * 16)), 7 * 16, 40.0, -1, cv2.LINE_AA, 4)
        img += rng.normal(0, 2.0, img.shape).astype(np.float32)
        yield np.clip(img, 0, 255).astype(np.uint8)


def _write(path: Path, fourcc: str, rng: np.random.Generator) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 60.0, (W, H),
                             isColor=False)
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {fourcc} here")
    for img in _frames(rng):
        writer.write(img)
    writer.release()
    return path


def _sequential_fps(path: Path) -> float:
    src = VideoSource(path)
    start = time.perf_counter()
    for i in range(src.n_frames):
        src.read(i)
    elapsed = time.perf_counter() - start
    src.close()
    return src.n_frames / elapsed


def _random_ms(path: Path, rng: np.random.Generator, reads: int = 25) -> float:
    src = VideoSource(path)
    src.read(0)
    src.read(N // 2)  # the one-off seek check happens here, not in the timed reads
    times = []
    last = N // 2
    for _ in range(reads):
        index = int(rng.integers(0, N))
        while index in (last, last + 1):
            index = int(rng.integers(0, N))
        start = time.perf_counter()
        src.read(index)
        times.append(time.perf_counter() - start)
        last = index
    src.close()
    return statistics.median(times) * 1000.0


def main() -> None:
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        ffv1 = _write(Path(tmp) / "bench_cam0.mkv", "FFV1", rng)
        mp4v = _write(Path(tmp) / "bench_cam1.mp4", "mp4v", rng)
        results = [
            ("decode_ffv1_fps", statistics.median(_sequential_fps(ffv1) for _ in range(RUNS)),
             "frames/s"),
            ("decode_mp4v_fps", statistics.median(_sequential_fps(mp4v) for _ in range(RUNS)),
             "frames/s"),
            ("random_access_ms",
             statistics.median(_random_ms(ffv1, np.random.default_rng(r)) for r in range(RUNS)),
             "ms"),
        ]
    for metric, value, unit in results:
        print(json.dumps({"metric": metric, "value": round(float(value), 2), "unit": unit}))


if __name__ == "__main__":
    main()
