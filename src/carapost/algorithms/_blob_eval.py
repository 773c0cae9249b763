"""Accuracy measurements for the blob detector (shared by its tests and benchmark).

Not a public API.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from carapost.algorithms._blob_synth import REGION_NAMES, SynthImage, match_to_truth
from carapost.algorithms.blobs import BlobDetections, BlobParameters, detect_blobs

#: (file name prefix, patternSize, flags) of the real dot-grid photos in shared/fixtures.
CIRCLEGRID_PATTERNS = (
    ("cloudcv_acircles4x11_grid_", (4, 11), cv2.CALIB_CB_ASYMMETRIC_GRID),
    ("cloudcv_opencv_acircles1_7x13", (7, 13), cv2.CALIB_CB_ASYMMETRIC_GRID),
    ("shike_symdots14x13_", (14, 13), cv2.CALIB_CB_SYMMETRIC_GRID),
)


@dataclass
class FaceScore:
    """Accumulated detection accuracy over synthetic face images."""

    expected: int = 0
    found: int = 0
    detections: int = 0
    false: dict = field(default_factory=lambda: {n: 0 for n in REGION_NAMES.values()})
    images: int = 0
    centre_err: list = field(default_factory=list)

    def add(self, s: SynthImage, det: BlobDetections, params: BlobParameters) -> None:
        """Score one image: recall over markers in the radius range that are unoccluded
        (not merged with another, not washed out); a detection is false when it is not
        on any marker (merged pairs and out-of-range markers are neither)."""
        self.images += 1
        for colour, lo, hi, on in ((0, params.black_min_radius, params.black_max_radius,
                                    params.find_black_blobs),
                                   (1, params.white_min_radius, params.white_max_radius,
                                    params.find_white_blobs)):
            if not on:
                continue
            ts = np.flatnonzero(s.colour == colour)
            ds = np.flatnonzero(det.colour == colour)
            self.detections += len(ds)
            d2t, t2d = match_to_truth(det.centre[ds].astype(np.float64), s.centre[ts],
                                      s.axes[ts, 1])
            need = ((s.axes[ts, 0] >= lo) & (s.axes[ts, 0] <= hi) & ~s.merged[ts]
                    & s.visible[ts])
            self.expected += int(need.sum())
            hit = need & (t2d >= 0)
            self.found += int(hit.sum())
            if not s.blurred:
                err = det.centre[ds[t2d[hit]]] - s.centre[ts[hit]]
                self.centre_err.extend(np.hypot(err[:, 0], err[:, 1]).tolist())
            un = ds[d2t < 0]
            if len(un):
                dist, idx = cKDTree(s.centre).query(det.centre[un].astype(np.float64))
                excused = (dist < 2.5 * s.axes[idx, 0]) & (
                    s.merged[idx] | ~s.visible[idx] | (s.axes[idx, 0] < lo)
                    | (s.axes[idx, 0] > hi) | (s.colour[idx] != colour))
                for j in un[~excused]:
                    x, y = det.centre[j]
                    reg = s.region_map[int(np.clip(round(y), 0, s.region_map.shape[0] - 1)),
                                       int(np.clip(round(x), 0, s.region_map.shape[1] - 1))]
                    self.false[REGION_NAMES[int(reg)]] += 1

    @property
    def recall(self) -> float:
        return self.found / max(self.expected, 1)

    @property
    def precision(self) -> float:
        return 1.0 - sum(self.false.values()) / max(self.detections, 1)

    def summary(self) -> dict:
        e = np.asarray(self.centre_err) if self.centre_err else np.full(1, np.nan)
        return {
            "recall": self.recall,
            "precision": self.precision,
            "centre_median_px": float(np.median(e)),
            "centre_p95_px": float(np.percentile(e, 95)),
            **{f"false_per_image_{k}": v / max(self.images, 1) for k, v in self.false.items()},
        }


def _ideal_grid(pattern: tuple[int, int], flags: int) -> np.ndarray:
    per_row, rows = pattern
    pts = []
    for i in range(rows):
        for j in range(per_row):
            if flags & cv2.CALIB_CB_ASYMMETRIC_GRID:
                pts.append((2 * j + i % 2, i))
            else:
                pts.append((j, i))
    return np.asarray(pts, np.float64)


def _homography_rms(ideal: np.ndarray, pts: np.ndarray) -> float:
    h, _ = cv2.findHomography(ideal, pts, 0)
    proj = cv2.perspectiveTransform(ideal[None], h)[0]
    return float(np.sqrt(np.mean(np.sum((proj - pts) ** 2, axis=1))))


def circlegrid_photo(path: Path, pattern: tuple[int, int], flags: int,
                     params: BlobParameters | None = None) -> dict:
    """Compare our centres with ``cv2.findCirclesGrid`` on one real dot-grid photo.

    Returns a dict with ``expected`` (dots in the pattern), ``matched`` (grid positions
    with one of our detections within 30 % of the grid spacing), ``rms_ours`` and
    ``rms_opencv`` (RMS residual in px against a homography fitted from the ideal grid
    to each set of centres separately).
    """
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"cannot read dot-grid photo {path}")
    ok, cv_centres = cv2.findCirclesGrid(img, pattern, flags=flags)
    if not ok:
        raise RuntimeError(f"cv2.findCirclesGrid failed on {path}")
    cv_centres = cv_centres.reshape(-1, 2).astype(np.float64)
    ideal = _ideal_grid(pattern, flags)
    det = detect_blobs(img, params or BlobParameters(black_min_radius=2.0))
    h_cv, _ = cv2.findHomography(ideal, cv_centres, 0)
    grid = cv2.perspectiveTransform(ideal[None], h_cv)[0]
    spacing = np.median(np.linalg.norm(np.diff(cv_centres, axis=0), axis=1))
    ours = det.centre.astype(np.float64)
    dist, idx = cKDTree(ours).query(grid) if len(ours) else (np.full(len(grid), np.inf),
                                                             np.zeros(len(grid), int))
    hit = dist < 0.3 * spacing
    out = {"expected": len(ideal), "matched": int(hit.sum()),
           "rms_opencv": _homography_rms(ideal, cv_centres)}
    out["rms_ours"] = (_homography_rms(ideal[hit], ours[idx[hit]]) if hit.sum() >= 8
                       else float("nan"))
    return out


def circlegrid_files(folder: Path) -> list[tuple[Path, tuple[int, int], int]]:
    """The dot-grid photos present in ``folder`` with their pattern size and flags."""
    out = []
    for prefix, pattern, flags in CIRCLEGRID_PATTERNS:
        for p in sorted(folder.glob(prefix + "*.png")):
            out.append((p, pattern, flags))
    return out
