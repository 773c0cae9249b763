"""Blob detection benchmark: speed, accuracy on synthetic faces, real dot-grid photos.

Run from the repository root: ``python benchmarks/blobs.py`` (about 1-2 minutes on 2
cores). Prints one JSON object per line: {"metric": ..., "value": ..., "unit": ...}.

Synthetic images come from the detector's own renderer
(``carapost.algorithms._blob_synth``: 1280x720 shaded face, ~100-160 painted markers,
brim strip with dots, exact anti-aliased truth); ``carapost.synth`` has no image renderer
with per-marker truth yet.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from carapost.algorithms._blob_eval import FaceScore, circlegrid_files, circlegrid_photo
from carapost.algorithms._blob_synth import match_to_truth, render_face
from carapost.algorithms.blobs import (
    BlobParameters,
    detect_blobs,
    detect_blobs_batch,
    preview_blobs,
)

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("standard", "dense156", "speech", "fast")


def emit(metric: str, value: float, unit: str, **extra) -> None:
    print(json.dumps({"metric": metric, "value": round(float(value), 4), "unit": unit,
                      **extra}), flush=True)


def simple_blob_detector() -> cv2.SimpleBlobDetector:
    """SimpleBlobDetector tuned to find the same dark markers (radius 4-50 px)."""
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor = True
    p.blobColor = 0
    p.minThreshold = 20
    p.maxThreshold = 200
    p.thresholdStep = 20
    p.minRepeatability = 2
    p.minDistBetweenBlobs = 3
    p.filterByArea = True
    p.minArea = math.pi * 4 * 4 * 0.3
    p.maxArea = math.pi * 50 * 50
    p.filterByCircularity = False
    p.filterByInertia = True
    p.minInertiaRatio = 0.1
    p.filterByConvexity = True
    p.minConvexity = 0.85
    return cv2.SimpleBlobDetector_create(p)


def throughput(images: list[np.ndarray], params: BlobParameters, n_frames: int) -> float:
    t = time.perf_counter()
    out = detect_blobs_batch(lambda k: images[k % len(images)], range(n_frames), params,
                             workers=2)
    dt = time.perf_counter() - t
    assert len(out) == n_frames
    return n_frames / dt


def simpleblob_throughput(images: list[np.ndarray], n_frames: int) -> float:
    det = [simple_blob_detector(), simple_blob_detector()]

    def run(i):
        return det[i % 2].detect(images[i % len(images)])

    t = time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(run, range(n_frames)))
    return n_frames / (time.perf_counter() - t)


def main() -> None:
    params = BlobParameters()
    rng = np.random.default_rng(20261122)

    # ---- speed ---------------------------------------------------------------
    speed_imgs = [render_face(rng, preset="standard").image for _ in range(6)]
    cv2.setNumThreads(1)  # parallelism comes from the two workers, as in the app
    runs = [throughput(speed_imgs, params, 400) for _ in range(3)]
    emit("blobs_images_per_s", statistics.median(runs), "images/s", workers=2,
         runs=[round(r, 1) for r in runs])
    runs = [simpleblob_throughput(speed_imgs, 120) for _ in range(3)]
    emit("simpleblob_images_per_s", statistics.median(runs), "images/s", workers=2,
         runs=[round(r, 1) for r in runs])
    cv2.setNumThreads(-1)
    times = []
    for _ in range(5):
        for img in speed_imgs:
            t = time.perf_counter()
            preview_blobs(img, params)
            times.append((time.perf_counter() - t) * 1e3)
    cpu = time.process_time()
    for img in speed_imgs * 5:
        detect_blobs(img, params)
    cpu_ms = (time.process_time() - cpu) / (5 * len(speed_imgs)) * 1e3
    emit("blob_preview_ms", statistics.median(times), "ms", p95=round(
        float(np.percentile(times, 95)), 2), cpu_ms_per_image=round(cpu_ms, 2))

    # ---- accuracy on synthetic takes ----------------------------------------
    main_score = FaceScore()
    sb_found = sb_need = 0
    sbd = simple_blob_detector()
    for preset in PRESETS:
        for noise in (2.0, 2.0, 5.0):
            s = render_face(rng, preset=preset, noise=noise)
            main_score.add(s, detect_blobs(s.image, params), params)
            kp = sbd.detect(s.image)
            pts = np.array([k.pt for k in kp], np.float64).reshape(-1, 2)
            ts = np.flatnonzero(s.colour == 0)
            _, t2d = match_to_truth(pts, s.centre[ts], s.axes[ts, 1])
            need = (s.axes[ts, 0] >= 4) & ~s.merged[ts]
            sb_need += int(need.sum())
            sb_found += int(np.sum(t2d[need] >= 0))
    r = main_score.summary()
    emit("blob_recall", r["recall"], "fraction", presets=list(PRESETS), images=12)
    emit("blob_precision", r["precision"], "fraction")
    emit("blob_centre_median_px", r["centre_median_px"], "px")
    emit("blob_centre_p95_px", r["centre_p95_px"], "px")
    for reg in ("face", "brim", "background"):
        emit(f"blob_false_per_image_{reg}", r[f"false_per_image_{reg}"], "detections/image")
    emit("simpleblob_recall", sb_found / max(sb_need, 1), "fraction")

    for option in ("merged", "highlights", "motion_blur", "dark", "white"):
        score = FaceScore()
        p = BlobParameters(find_black_blobs=option != "white",
                           find_white_blobs=option == "white")
        for preset in PRESETS:
            s = render_face(rng, preset=preset, noise=2.0, **{option: True})
            score.add(s, detect_blobs(s.image, p), p)
        r = score.summary()
        for key in ("recall", "precision", "centre_median_px", "centre_p95_px"):
            if math.isfinite(r[key]):  # all markers are blurred with motion_blur
                unit = "px" if key.endswith("px") else "fraction"
                emit(f"blob_{key}_{option}", r[key], unit)

    # ---- real dot-grid photos ------------------------------------------------
    folder = ROOT.parent / "shared" / "fixtures" / "circlegrid"
    files = circlegrid_files(folder)
    if not files:
        print(f"circlegrid photos not found in {folder}; skipped", file=sys.stderr)
        return
    ours, theirs, found, expected = [], [], 0, 0
    for path, pattern, flags in files:
        res = circlegrid_photo(path, pattern, flags)
        ours.append(res["rms_ours"])
        theirs.append(res["rms_opencv"])
        found += res["matched"]
        expected += res["expected"]
    emit("circlegrid_rms_px", math.sqrt(np.mean(np.square(ours))), "px", photos=len(files))
    emit("circlegrid_opencv_rms_px", math.sqrt(np.mean(np.square(theirs))), "px")
    emit("circlegrid_dots_found", found / expected, "fraction", dots=expected)
    emit("circlegrid_photos_ours_lower", int(np.sum(np.array(ours) < np.array(theirs))),
         "photos", of=len(files))


if __name__ == "__main__":
    main()
