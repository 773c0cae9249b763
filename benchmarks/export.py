"""Export speed: C3D and FBX for a 10-minute take (200 points x 36,000 frames x 4 cameras).

Prints one JSON object per line: ``c3d_export_s``, ``c3d_export_peak_mb`` and
``fbx_export_s`` (medians of several runs). Peak memory is measured with ``tracemalloc``
(Python/numpy allocations made during the export call, i.e. on top of the input arrays).

Run from the repository root: ``python benchmarks/export.py [--runs N]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from carapost.io.c3d import write_c3d
from carapost.io.fbx import write_fbx

N_FRAMES, N_POINTS, N_CAMS, RATE = 36_000, 200, 4, 60.0


def synthetic_take(seed: int = 0) -> dict:
    """Smooth random-walk trajectories with 2 % gaps, residuals and camera masks."""
    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(0.0, 0.05, (N_FRAMES, N_POINTS, 3)), axis=0)
    pos += rng.normal(0.0, 60.0, (1, N_POINTS, 3))
    # Gaps as runs (occlusions) rather than isolated samples.
    starts = rng.random((N_FRAMES, N_POINTS)) < 0.002
    gaps = np.zeros_like(starts)
    for k in range(10):
        gaps[k:] |= starts[: N_FRAMES - k]
    pos[gaps] = np.nan
    residuals = rng.gamma(2.0, 0.15, (N_FRAMES, N_POINTS))
    mask = rng.random((N_FRAMES, N_POINTS, N_CAMS)) < 0.8
    modified = (rng.random((N_FRAMES, N_POINTS)) < 0.01) & ~gaps
    kinds = (np.arange(N_POINTS) >= N_POINTS - 20).astype(int)  # last 20 are brim points
    labels = [f"marker{i:03d}" for i in range(N_POINTS)]
    return dict(
        pos=pos, residuals=residuals, mask=mask, modified=modified, kinds=kinds, labels=labels
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    take = synthetic_take()
    c3d_times, c3d_peaks, fbx_times = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        c3d_path, fbx_path = Path(tmp) / "take.c3d", Path(tmp) / "take.fbx"

        def c3d_export() -> None:
            write_c3d(
                c3d_path,
                take["pos"],
                labels=take["labels"],
                rate=RATE,
                residuals=take["residuals"],
                camera_mask=take["mask"],
                modified=take["modified"],
            )

        for _ in range(args.runs):
            t0 = time.perf_counter()
            c3d_export()
            c3d_times.append(time.perf_counter() - t0)
        for _ in range(3):  # memory runs separately: tracemalloc slows allocation down
            tracemalloc.start()
            c3d_export()
            c3d_peaks.append(tracemalloc.get_traced_memory()[1] / 1e6)
            tracemalloc.stop()
        for _ in range(args.runs):
            t0 = time.perf_counter()
            write_fbx(fbx_path, take["pos"], labels=take["labels"], rate=RATE, kinds=take["kinds"])
            fbx_times.append(time.perf_counter() - t0)
        sizes = {p.suffix: p.stat().st_size / 1e6 for p in (c3d_path, fbx_path)}

    def emit(metric: str, value: float, unit: str, runs: list[float]) -> None:
        line = {"metric": metric, "value": round(value, 3), "unit": unit}
        line["runs"] = [round(r, 3) for r in runs]
        print(json.dumps(line))

    emit("c3d_export_s", statistics.median(c3d_times), "s", c3d_times)
    emit("c3d_export_peak_mb", statistics.median(c3d_peaks), "MB", c3d_peaks)
    emit("fbx_export_s", statistics.median(fbx_times), "s", fbx_times)
    print(json.dumps({"note": "file sizes (MB)", "c3d": sizes[".c3d"], "fbx": sizes[".fbx"]}))


if __name__ == "__main__":
    main()
