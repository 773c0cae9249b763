"""Accuracy measurements for the blob detector against synthetic truth and real dot-grid
photos (shared by its tests, ``benchmarks/blobs.py`` and ``scripts/train_blob_model.py``;
moved here from ``carapost.algorithms._blob_eval``: the product packages never import
it).

Not part of the product API.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from carapost.algorithms.blobs import BlobDetections, BlobParameters, detect_blobs
from carapost.algorithms.codes import KIND_BRIM, KIND_FACE
from carapost.synth.blob_images import (
    REGION_BACKGROUND,
    REGION_BRIM,
    REGION_FACE,
    REGION_NAMES,
    SynthImage,
    match_nearest,
    match_to_truth,
)

#: (file name prefix, patternSize, flags) of the real dot-grid photos in shared/fixtures.
CIRCLEGRID_PATTERNS = (
    ("cloudcv_acircles4x11_grid_", (4, 11), cv2.CALIB_CB_ASYMMETRIC_GRID),
    ("cloudcv_opencv_acircles1_7x13", (7, 13), cv2.CALIB_CB_ASYMMETRIC_GRID),
    ("shike_symdots14x13_", (14, 13), cv2.CALIB_CB_SYMMETRIC_GRID),
)


@dataclass
class _Tally:
    """Counts shared by the scorers: truth blobs expected and found, detections, falses."""

    expected: int = 0
    found: int = 0
    detections: int = 0
    images: int = 0
    false: dict = field(default_factory=lambda: {n: 0 for n in REGION_NAMES.values()})
    centre_err: list = field(default_factory=list)

    @property
    def recall(self) -> float:
        return self.found / max(self.expected, 1)

    @property
    def precision(self) -> float:
        return 1.0 - sum(self.false.values()) / max(self.detections, 1)


@dataclass
class FaceScore(_Tally):
    """Accumulated detection accuracy over synthetic face images."""

    def add(self, s: SynthImage, det: BlobDetections, params: BlobParameters) -> None:
        """Score one image: recall over markers whose major axis (``2 x`` the truth
        semi-major axis) is in the radius range and that are unoccluded (not merged with
        another, not washed out); a detection is false when it is not on any marker
        (merged pairs and out-of-range markers are neither)."""
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
            major = 2 * s.axes[ts, 0]  # Min / Max Radius bound the full major axis
            need = (major >= lo) & (major <= hi) & ~s.merged[ts] & s.visible[ts]
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
                    s.merged[idx] | ~s.visible[idx] | (2 * s.axes[idx, 0] < lo)
                    | (2 * s.axes[idx, 0] > hi) | (s.colour[idx] != colour))
                for j in un[~excused]:
                    x, y = det.centre[j]
                    reg = s.region_map[int(np.clip(round(y), 0, s.region_map.shape[0] - 1)),
                                       int(np.clip(round(x), 0, s.region_map.shape[1] - 1))]
                    self.false[REGION_NAMES[int(reg)]] += 1

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

    ``params`` default: Min Radius 4 px, Max Radius 100 px (major-axis length).

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
    # The dots of the 14x13 plate photos are ~60 px across, beyond the default Max
    # Radius of 50 px (the longest axis): this evaluation searches up to 100 px.
    det = detect_blobs(img, params or BlobParameters(black_max_radius=100.0))
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


# --------------------------------------------------------------------------- carapost.synth

#: Rim points per disc for the projected-ellipse computation.
_RIM_POINTS = 64


def projected_ellipses(centres: np.ndarray, normals: np.ndarray, radii: np.ndarray,
                       R: np.ndarray, t: np.ndarray, intr) -> tuple[np.ndarray, np.ndarray,
                                                                      np.ndarray]:
    """Image ellipses of 3D discs, computed from the scene geometry (not from pixels).

    Each disc's rim is sampled at 64 points, projected through the camera model
    (perspective and lens distortion), and the area moments of the projected polygon give
    the ellipse: semi-axes ``2 sqrt(eigenvalue)`` of the second central moments and the
    area centroid.

    Parameters
    ----------
    centres, normals : ndarray [N, 3]
        Disc centres (mm) and unit normals in the world (helmet) frame.
    radii : ndarray [N], mm
    R, t : ndarray [3, 3], [3]
        World -> camera pose of the view.
    intr : CameraIntrinsics
        Intrinsics of that one camera.

    Returns
    -------
    axes : ndarray [N, 2] px (semi-major, semi-minor)
    centroid : ndarray [N, 2] px, area centroid of the projected disc
    ok : ndarray [N] bool, the whole rim projects in front of the camera

    Examples
    --------
    A 5 mm disc facing the camera 500 mm away, focal length 1000 px: 10 px semi-axes
    (the 64-point rim polygon is a little smaller than the circle).

    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics
    >>> intr = CameraIntrinsics(focal=np.array([1000.0]),
    ...                         principal_point=np.array([[640.0, 360.0]]))
    >>> axes, centroid, ok = projected_ellipses(
    ...     np.array([[0.0, 0.0, 500.0]]), np.array([[0.0, 0.0, -1.0]]), np.array([5.0]),
    ...     np.eye(3), np.zeros(3), intr)
    >>> np.round(axes, 2).tolist(), np.round(centroid, 2).tolist(), ok.tolist()
    ([[9.99, 9.99]], [[640.0, 360.0]], [True])
    """
    from carapost.algorithms.camera import project

    n = len(centres)
    if n == 0:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool)
    nrm = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(nrm, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(nrm, u)
    th = np.linspace(0, 2 * np.pi, _RIM_POINTS, endpoint=False)
    ring = (np.cos(th)[None, :, None] * u[:, None, :]
            + np.sin(th)[None, :, None] * v[:, None, :])
    rim = centres[:, None, :] + radii[:, None, None] * ring
    uv, _ = project(rim.reshape(-1, 3), R[None], t[None], intr)
    p = uv[:, 0].reshape(n, _RIM_POINTS, 2)
    ok = np.isfinite(p).all(axis=(1, 2))
    p = np.nan_to_num(p)
    x, y = p[..., 0], p[..., 1]
    x1, y1 = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cr = x * y1 - x1 * y
    area = 0.5 * cr.sum(axis=1)
    area = np.where(np.abs(area) > 1e-12, area, 1e-12)
    cx = ((x + x1) * cr).sum(axis=1) / (6 * area)
    cy = ((y + y1) * cr).sum(axis=1) / (6 * area)
    sxx = ((x * x + x * x1 + x1 * x1) * cr).sum(axis=1) / (12 * area) - cx * cx
    syy = ((y * y + y * y1 + y1 * y1) * cr).sum(axis=1) / (12 * area) - cy * cy
    sxy = ((x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y) * cr).sum(axis=1) / (24 * area) - cx * cy
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0))
    a = 2 * np.sqrt(np.maximum(half_tr + root, 0))
    b = 2 * np.sqrt(np.maximum(half_tr - root, 0))
    return np.column_stack([a, b]), np.column_stack([cx, cy]), ok


@dataclass
class SynthView:
    """One rendered ``carapost.synth`` image with the truth the blob scorer needs.

    Attributes
    ----------
    image : ndarray [H, W] uint8
    centre : ndarray [N, 2], truth ``uv`` of the visible face markers then brim dots
    axes : ndarray [N, 2], projected semi-axes (major, minor) px, from the geometry
    kind : ndarray [N] int, KIND_FACE or KIND_BRIM
    touching : ndarray [N] bool, the projected disc touches another one (< 1 px gap)
    cut : ndarray [N] bool, the projected disc reaches past the image border
    spread : ndarray [N], half the motion-blur streak length in px (0 without blur)
    region_map : ndarray [H, W] uint8, REGION_BACKGROUND / REGION_FACE / REGION_BRIM
    blurred : bool, face markers are motion blurred
    """

    image: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    kind: np.ndarray
    touching: np.ndarray
    cut: np.ndarray
    spread: np.ndarray
    region_map: np.ndarray
    blurred: bool


def _coverage_layers(scene, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """Skin and brim coverage of one camera at the nominal pose (cached on the scene)."""
    from carapost.synth.render import render_background

    key = f"_blob_eval_cov{camera}"
    if key not in scene.cache:
        head, brim = render_background(scene, camera)
        scene.cache[key] = (np.ascontiguousarray(head[..., 1]),
                            np.ascontiguousarray(brim[..., 1]))
    return scene.cache[key]


def synth_view(scene, frame: int, camera: int, *, regions: bool = True) -> SynthView:
    """Render one view of a ``carapost.synth`` scene and compute its blob truth.

    Truth blobs are the visible face markers and the visible brim dots. Their projected
    ellipses come from :func:`projected_ellipses` (disc radius, normal, flexed camera
    pose, lens distortion) at the frame instant (the middle of the shutter with motion
    blur). The region map (face silhouette, brim strip, background) is the renderer's own
    coverage of the skin and brim layers, warped like the rendered frame.
    """
    from carapost.synth import render_frame
    from carapost.synth.render import prepare

    prepare(scene)
    img = render_frame(scene, frame, camera)
    intr = scene.intrinsics.subset([camera])
    R, t = scene.cam_R[frame, camera], scene.cam_t[frame, camera]
    vis = scene.visible[frame, :, camera]
    bvis = scene.brim_visible[frame, :, camera]
    pts = np.vstack([scene.seen_points[frame, camera][vis], scene.brim3d[bvis]])
    nrm = np.vstack([scene.seen_normals[frame, camera][vis], scene.brim_normals[bvis]])
    rad = np.concatenate([scene.marker_radius_mm[vis], scene.brim_radius_mm[bvis]])
    axes, _centroid, _ok = projected_ellipses(pts, nrm, rad, R, t, intr)
    centre = np.vstack([scene.uv[frame, vis, camera], scene.brim_uv[frame, bvis, camera]])
    kind = np.concatenate([np.full(int(vis.sum()), KIND_FACE), np.full(int(bvis.sum()),
                                                                           KIND_BRIM)])
    spread = np.zeros(len(centre))
    if scene.blur_points is not None:
        from carapost.algorithms.camera import project

        bp = scene.blur_points[frame, camera][:, vis]  # (S, J, 3)
        uvb, _ = project(bp.reshape(-1, 3), R[None], t[None], intr)
        uvb = uvb[:, 0].reshape(bp.shape[0], -1, 2)
        spread[: int(vis.sum())] = 0.5 * np.linalg.norm(uvb[-1] - uvb[0], axis=1)
    # Pairs of discs that touch after projection (their blobs merge in the image).
    touching = np.zeros(len(centre), bool)
    if len(centre) > 1:
        tree = cKDTree(centre)
        pairs = tree.query_pairs(2 * float(axes[:, 0].max()) + 2 * float(spread.max()) + 1.0,
                                 output_type="ndarray")
        if len(pairs):
            i, j = pairs[:, 0], pairs[:, 1]
            gap = (np.linalg.norm(centre[i] - centre[j], axis=1) - axes[i, 0] - axes[j, 0]
                   - spread[i] - spread[j])
            close = gap < 1.0
            touching[i[close]] = True
            touching[j[close]] = True
    h, w = img.shape
    ext = axes[:, 0] + spread
    cut = ((centre[:, 0] - ext < -0.5) | (centre[:, 1] - ext < -0.5)
           | (centre[:, 0] + ext > w - 0.5) | (centre[:, 1] + ext > h - 0.5))
    region = np.full((h, w), REGION_BACKGROUND, np.uint8)
    if regions:
        head_cov, brim_cov = _coverage_layers(scene, camera)
        a_head, a_brim = scene.cache["warps"]
        hw = cv2.warpAffine(head_cov, a_head[frame, camera], (w, h), flags=cv2.INTER_LINEAR)
        bw = cv2.warpAffine(brim_cov, a_brim[frame, camera], (w, h), flags=cv2.INTER_LINEAR)
        region[hw >= 0.5] = REGION_FACE
        region[bw >= 0.5] = REGION_BRIM
    return SynthView(img, centre, axes, kind, touching, cut, spread, region,
                     scene.blur_points is not None)


@dataclass
class SynthScore(_Tally):
    """Blob detection accuracy accumulated over ``carapost.synth`` views (black markers).

    A truth blob *counts* for recall when its projected major axis (twice the
    semi-major axis, the guide's meaning of Min / Max Radius) is inside the radius
    range, it does not touch another disc and it is not cut by the image border.
    A detection matches a truth blob within ``clip(0.5 * minor, 1, 3)`` px of its centre
    (plus half the motion-blur streak). Unmatched detections are false unless they lie on
    a truth blob that does not count (too small or large, touching, cut); false ones are
    classified by the region map at their centre.
    """

    missed_axes: list = field(default_factory=list)

    def add(self, v: SynthView, det: BlobDetections, params: BlobParameters) -> None:
        """Score the detections of one view."""
        self.images += 1
        lo, hi = params.black_min_radius, params.black_max_radius
        ds = np.flatnonzero(det.colour == 0)
        self.detections += len(ds)
        tol = np.clip(0.5 * v.axes[:, 1], 1.0, 3.0) + v.spread
        d2t, t2d = match_nearest(det.centre[ds].astype(np.float64), v.centre, tol)
        major = 2 * v.axes[:, 0]  # Min / Max Radius bound the full major axis
        need = (major >= lo) & (major <= hi) & ~v.touching & ~v.cut
        self.expected += int(need.sum())
        hit = need & (t2d >= 0)
        self.found += int(hit.sum())
        self.missed_axes.extend(v.axes[need & (t2d < 0), 0].tolist())
        if not v.blurred:
            err = det.centre[ds[t2d[hit]]] - v.centre[hit]
            self.centre_err.extend(np.hypot(err[:, 0], err[:, 1]).tolist())
        elif np.any(v.kind[hit] == KIND_BRIM):  # the brim is never motion blurred
            sel = hit & (v.kind == KIND_BRIM)
            err = det.centre[ds[t2d[sel]]] - v.centre[sel]
            self.centre_err.extend(np.hypot(err[:, 0], err[:, 1]).tolist())
        un = ds[d2t < 0]
        if len(un) and len(v.centre):
            dist, idx = cKDTree(v.centre).query(det.centre[un].astype(np.float64))
            excused = (dist < v.axes[idx, 0] + v.spread[idx] + 2.0) & ~need[idx]
            un = un[~excused]
        for j in un:
            x, y = det.centre[j]
            reg = v.region_map[int(np.clip(round(float(y)), 0, v.region_map.shape[0] - 1)),
                               int(np.clip(round(float(x)), 0, v.region_map.shape[1] - 1))]
            self.false[REGION_NAMES[int(reg)]] += 1

    def merge(self, other: SynthScore) -> None:
        """Add another score's counts to this one."""
        self.expected += other.expected
        self.found += other.found
        self.detections += other.detections
        self.images += other.images
        for k, v in other.false.items():
            self.false[k] += v
        self.centre_err.extend(other.centre_err)
        self.missed_axes.extend(other.missed_axes)

    def summary(self) -> dict:
        e = np.asarray(self.centre_err) if self.centre_err else np.full(1, np.nan)
        return {
            "images": self.images,
            "expected": self.expected,
            "recall": self.recall,
            "precision": self.precision,
            "centre_median_px": float(np.median(e)),
            "centre_p95_px": float(np.percentile(e, 95)),
            **{f"false_per_image_{k}": v / max(self.images, 1) for k, v in self.false.items()},
        }


def synth_scene(markers: str = "standard", preset: str = "speech", *, frames: int = 121,
                seed: int = 0, **options):
    """A ``carapost.synth`` scene for blob evaluation (1280x720, 4 cameras, 60 fps)."""
    from carapost.synth import SynthConfig, build_scene

    return build_scene(SynthConfig(preset=preset, markers=markers, frames=frames, seed=seed,
                                   **options))
