"""Benchmark of the synthetic take generator.

``synth_300_frames_s``: wall time of `generate_take` for the default take (speech preset,
standard marker set, 300 frames, 4 cameras, 1280x720, FFV1), median of several runs.
Also reports the scene build time and the single-process time per image.

Run from the repository root: ``python benchmarks/synth.py [--runs N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time

import cv2

from carapost.synth import SynthConfig, build_scene, generate_take, render_frame


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(value, 4), "unit": unit, **extra}),
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--frames", type=int, default=300)
    args = parser.parse_args()
    config = SynthConfig(frames=args.frames)

    builds = []
    for _ in range(args.runs):
        t0 = time.perf_counter()
        build_scene(config)
        builds.append(time.perf_counter() - t0)
    emit("synth_build_scene_s", statistics.median(builds), "s", runs=args.runs,
         frames=args.frames)

    scene = build_scene(config)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    for c in range(scene.n_cameras):
        render_frame(scene, 0, c)  # background layers, warps, noise bank
    times = []
    for f in range(0, min(40, scene.n_frames)):
        t0 = time.perf_counter()
        render_frame(scene, f, f % scene.n_cameras)
        times.append(time.perf_counter() - t0)
    cv2.setNumThreads(threads)
    emit("synth_render_image_ms", 1000 * statistics.median(times), "ms", size="1280x720",
         note="one process, background layers cached, no encoding")

    totals, cpus = [], []
    for _ in range(args.runs):
        with tempfile.TemporaryDirectory() as tmp:
            c0 = os.times()
            t0 = time.perf_counter()
            generate_take(tmp, config)
            totals.append(time.perf_counter() - t0)
            c1 = os.times()
            # CPU seconds of this process and its workers: independent of other load
            cpus.append(sum(c1[:4]) - sum(c0[:4]))
    emit("synth_300_frames_s" if args.frames == 300 else f"synth_{args.frames}_frames_s",
         statistics.median(totals), "s", runs=args.runs,
         all=[round(t, 2) for t in totals], cpu_s=round(statistics.median(cpus), 2),
         load_avg=round(os.getloadavg()[0], 2), cameras=4, size="1280x720", codec="ffv1")


if __name__ == "__main__":
    main()
