"""After both passes: a second look at the blobs where a tracked point has no sample.

The per-frame tracker keeps a marker seen by one camera only while its ray stays near the
prediction from the frame before (Single Sensor Tracking), and loses it for good once a
frame disagrees: a thin, dark, oblique marker that the detector misses in the second
camera of its caddy then has no sample for the rest of the take, although its blob in
the first camera is there in every frame. Once the whole take is tracked the point's
triangulated samples on both sides are known, and so is where its neighbours moved:
:func:`recover_lost_samples` predicts the point on each frame where it has no sample
(:func:`carapost.algorithms.single_sensor.neighbour_prediction`, at most
`MAX_RECOVERY_GAP` frames from a triangulated sample), projects the prediction into every
camera and attaches the blob no other point uses that lies within the prediction's own
uncertainty (measured on the take, :func:`~carapost.algorithms.single_sensor.prediction_sigma`)
of that projection and has the size of the point's blobs in that camera. Two cameras
or more give a triangulated sample (kept when it lands within that uncertainty of the
prediction), one camera a single-sensor sample on its ray, which
:func:`carapost.algorithms.tracking.time_checks.place_single_sensor` then places and
gives its sigma.

Shapes: ``F`` frames, ``P`` points, ``C`` cameras; the arrays are a track result's,
changed in place.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.algorithms.codes import (
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
)
from carapost.algorithms.single_sensor import (
    neighbour_prediction,
    neighbours,
    place_on_rays,
    prediction_sigma,
)
from carapost.algorithms.tracking.records import FrameDetections
from carapost.algorithms.uncertainty import retriangulate

__all__ = ["MAX_RECOVERY_GAP", "recover_lost_samples"]

#: Farthest (frames) from a triangulated sample of the point that a lost sample is
#: looked for (1 s at 60 fps; the prediction from the neighbours' motion drifts beyond).
MAX_RECOVERY_GAP = 60
#: Search radius (px) around the predicted projection: this many times the prediction's
#: error (per axis, measured on the take for that gap) ...
GATE_SIGMAS = 3.0
#: ... within these bounds (px): below, the blob centre's own noise; above, the spacing
#: of dense markers.
GATE_PX = (1.5, 4.0)
#: A blob is the point's when its semi-major axis is within this factor of the median
#: of the point's blobs in that camera (a neighbour, a nostril or a crease is not).
SIZE_RATIO = 1.6
#: Largest error (mm per axis, measured on the take for the gap and the sides it is
#: predicted from) of a prediction a lost sample is recovered from: a single-sensor
#: sample's depth along its ray is the prediction's, and samples beyond 1 mm would be
#: worse than none.
MAX_SIGMA_MM = 0.15
#: Gap lengths (frames) at which the prediction's error is measured for the gate.
_GAPS = np.array([1, 2, 4, 8, 16, 32, 60])


def one_sided_sigma(X: NDArray[np.float64], tri: NDArray[np.bool_], nb: NDArray[np.intp],
                    gaps: NDArray[np.intp], *, step: int = 2, prior_tests: int = 10
                    ) -> NDArray[np.float64]:
    """Per-axis error (mm RMS) of the prediction from one side only (a reference ``d``
    frames before or after, moved with the neighbours), per point and gap, measured on
    the take's triangulated samples as
    :func:`carapost.algorithms.single_sensor.prediction_sigma` measures it from both
    sides (each point's own error shrunk towards the pooled one by ``prior_tests``).

    Returns
    -------
    ndarray, shape (P, G)
        NaN where the take allowed no test of a gap.
    """
    F, P = tri.shape
    out = np.full((P, len(gaps)), np.nan)
    valid = nb >= 0
    nn = np.where(valid, nb, 0)
    for j, d in enumerate(gaps):
        sq = np.zeros(P)
        cnt = np.zeros(P)
        for f0 in range(0, F, step):
            for g in (f0 - int(d), f0 + int(d)):
                if not 0 <= g < F:
                    continue
                ps = np.flatnonzero(tri[f0] & tri[g])
                if ps.size == 0:
                    continue
                n, v = nn[ps], valid[ps]
                ok = v & tri[f0][n] & tri[g][n]
                k = ok.sum(1)
                disp = np.where(ok[..., None], X[f0][n] - X[g][n], 0.0).sum(1)
                est = X[g, ps] + disp / np.maximum(k, 1)[:, None]
                e2 = np.sum((est - X[f0, ps]) ** 2, axis=-1) / 3.0
                good = k > 0
                np.add.at(sq, ps[good], e2[good])
                np.add.at(cnt, ps[good], 1)
        if cnt.sum() == 0:
            continue
        pooled = sq.sum() / cnt.sum()
        out[:, j] = np.sqrt((sq + prior_tests * pooled) / (cnt + prior_tests))
    return out


def _monotone(curve: NDArray[np.float64]) -> NDArray[np.float64]:
    """A curve over the gaps made non-decreasing (NaN: the largest measured value, the
    gap's error taken as at least the shorter gaps')."""
    if not np.isfinite(curve).any():
        return curve
    filled = np.where(np.isfinite(curve), curve, 0.0)
    out = np.maximum.accumulate(filled, axis=1)
    return np.where(out > 0, out, np.nanmax(curve))


def _sides(tri: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(F, P) True where the point has a triangulated sample both before and after."""
    before = np.maximum.accumulate(tri, axis=0)
    after = np.maximum.accumulate(tri[::-1], axis=0)[::-1]
    return before & after


def recover_lost_samples(o: dict[str, NDArray[Any]], R: NDArray, t: NDArray,
                         face: NDArray[np.bool_], intr: CameraIntrinsics,
                         fixed: NDArray[np.bool_],
                         detections: Callable[[int], FrameDetections], first: int = 0,
                         nb: NDArray[np.intp] | None = None,
                         max_gap: int = MAX_RECOVERY_GAP) -> NDArray[np.float32]:
    """Attach the free blobs that a point without a sample predicts; return the sigmas
    of the single-sensor samples recovered.

    Parameters
    ----------
    o : dict of arrays
        The track result's arrays (``positions``, ``recon``, ``obs``, ``source``,
        ``detection``, ``quality``, ``residual``), frames from ``first``; changed in
        place.
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
        The cameras (fitted over time).
    face : ndarray of bool, shape (P,)
    intr : CameraIntrinsics
    fixed : ndarray of bool, shape (F,)
        Frames left alone (the initialised frame).
    detections : callable
        Take frame -> `FrameDetections` (centres and axes per camera).
    first : int
        Take frame of row 0 of the arrays.
    nb : ndarray of int, shape (P, k), optional
        Each point's neighbours, when already known.
    max_gap : int
        Farthest frame (from a triangulated sample of the point) looked at.

    Returns
    -------
    ndarray, shape (F, P), float32
        Sigma (mm) of each recovered single-sensor sample: the error of its prediction
        (per axis, along the ray) measured on the take for its gap and sides; NaN
        elsewhere (triangulated recoveries get theirs from their geometry).
    """
    recon = o["recon"]
    F, P = recon.shape
    C = intr.n_cameras
    sigma = np.full((F, P), np.nan, np.float32)
    tri = (recon == RECON_TRIANGULATED) & face[None, :]
    if tri.sum() < 10:
        return sigma
    X = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
    nb = neighbours(X, tri) if nb is None else nb
    pred, gap = neighbour_prediction(X, tri, nb=nb)
    lost = ((recon == RECON_NONE) & face[None, :] & ~fixed[:, None]
            & (gap > 0) & (gap <= max_gap) & np.isfinite(pred).all(-1))
    if not lost.any():
        return sigma
    det = o["detection"]
    # the error of the prediction (mm per axis) for each lost sample's gap: from both
    # sides (interpolated) or from one (extrapolated), each measured on the take
    sides = _sides(tri)
    two_curve = _monotone(prediction_sigma(X, tri, nb, _GAPS))
    one_curve = _monotone(one_sided_sigma(X, tri, nb, _GAPS))
    fl, pl = np.nonzero(lost)
    g = gap[fl, pl].astype(np.float64)
    j = np.clip(np.searchsorted(_GAPS, g) - 1, 0, _GAPS.size - 2)
    w = np.clip((g - _GAPS[j]) / (_GAPS[j + 1] - _GAPS[j]), 0.0, 1.0)
    both = sides[fl, pl]
    curve = np.where(both[:, None], two_curve[pl], one_curve[pl])
    sig_mm = curve[np.arange(fl.size), j] * (1 - w) + curve[np.arange(fl.size), j + 1] * w
    # a prediction too poor for a sample within MAX_SIGMA_MM is not used
    trust = np.isfinite(sig_mm) & (sig_mm <= MAX_SIGMA_MM)
    fl, pl, g, sig_mm = fl[trust], pl[trust], g[trust], sig_mm[trust]
    if fl.size == 0:
        return sigma
    size = _blob_sizes(detections, det, first)  # (P, C) median semi-major axis
    uv, depth = project(pred[fl, pl][:, None], R[fl], t[fl], intr)  # (N, 1, C, 2)
    uv, depth = uv[:, 0], depth[:, 0]
    gate = np.clip(GATE_SIGMAS * sig_mm[:, None] * intr.focal[None, :]
                   / np.where(depth > 0, depth, np.inf), *GATE_PX)  # (N, C)
    pick = np.full((fl.size, C), -1, np.int64)
    blob_uv = np.full((fl.size, C, 2), np.nan)
    for f in np.unique(fl):
        rows = np.flatnonzero(fl == f)
        frame = detections(int(f + first))
        for c in range(C):
            cen, ax = frame[c]
            if len(cen) == 0 or ax is None:
                continue
            cen = np.asarray(cen, np.float64).reshape(-1, 2)
            major = np.asarray(ax, np.float64).reshape(-1, 2)[:, 0]
            free = np.ones(len(cen), bool)
            used = det[f, :, c]
            free[used[(used >= 0) & (used < len(cen))]] = False
            d = np.linalg.norm(cen[None] - uv[rows, c][:, None], axis=-1)  # (n, D)
            d[:, ~free] = np.inf
            ref = size[pl[rows], c]
            ratio = major[None, :] / np.where(np.isfinite(ref), ref, np.nan)[:, None]
            d[~((ratio <= SIZE_RATIO) & (ratio >= 1.0 / SIZE_RATIO))] = np.inf
            k = np.argmin(d, axis=1)
            best = d[np.arange(rows.size), k]
            ok = best <= gate[rows, c]
            # one blob for one point: the nearest claim wins
            for r in np.argsort(best):
                if ok[r] and (pick[rows, c] == k[r]).any():
                    ok[r] = False
                if ok[r]:
                    pick[rows[r], c] = k[r]
            blob_uv[rows[ok], c] = cen[k[ok]]
    n_cam = (pick >= 0).sum(1)
    # two cameras or more: triangulate, kept when near the prediction
    many = np.flatnonzero(n_cam >= 2)
    if many.size:
        obs = np.full((F, P, C, 2), np.nan)
        obs[fl[many], pl[many]] = blob_uv[many]
        mask = np.zeros((F, P), bool)
        mask[fl[many], pl[many]] = True
        Xt, res = retriangulate(obs, R, t, intr, mask)
        Xm = Xt[fl[many], pl[many]]
        near = np.linalg.norm(Xm - pred[fl[many], pl[many]], axis=-1) <= \
            GATE_SIGMAS * np.sqrt(3.0) * np.maximum(sig_mm[many], 0.05)
        good = many[near & np.isfinite(Xm).all(-1)]
        bad = many[~(near & np.isfinite(Xm).all(-1))]
        # a triangulation the prediction does not bear out: keep the nearer camera only
        for r in bad:
            cams = np.flatnonzero(pick[r] >= 0)
            dist = np.linalg.norm(blob_uv[r, cams] - uv[r, cams], axis=-1)
            drop = cams[np.argsort(dist)[1:]]
            pick[r, drop] = -1
            blob_uv[r, drop] = np.nan
        _attach(o, fl[good], pl[good], pick[good], blob_uv[good])
        recon[fl[good], pl[good]] = RECON_TRIANGULATED
        o["positions"][fl[good], pl[good]] = Xt[fl[good], pl[good]].astype(
            o["positions"].dtype)
        o["residual"][fl[good], pl[good]] = res[fl[good], pl[good]].astype(
            o["residual"].dtype)
        n_cam[bad] = 1
    one = np.flatnonzero(n_cam == 1)
    if one.size:
        cam = np.argmax(pick[one] >= 0, axis=1)
        Xs, dist, _ = place_on_rays(pred[fl[one], pl[one]], blob_uv[one, cam],
                                    R[fl[one]], t[fl[one]], intr, cam)
        okr = np.isfinite(Xs).all(-1)
        one, Xs, dist = one[okr], Xs[okr], dist[okr]
        _attach(o, fl[one], pl[one], pick[one], blob_uv[one])
        recon[fl[one], pl[one]] = RECON_SINGLE_SENSOR
        o["positions"][fl[one], pl[one]] = Xs.astype(o["positions"].dtype)
        o["residual"][fl[one], pl[one]] = dist.astype(o["residual"].dtype)
        sigma[fl[one], pl[one]] = sig_mm[one]
    return sigma


def _attach(o: dict[str, NDArray[Any]], f: NDArray[np.intp], p: NDArray[np.intp],
            pick: NDArray[np.int64], uv: NDArray[np.float64]) -> None:
    """Attach blob ``pick[i, c]`` (centre ``uv[i, c]``) to sample (f[i], p[i])."""
    has = pick >= 0
    for c in range(pick.shape[1]):
        m = has[:, c]
        o["obs"][f[m], p[m], c] = uv[m, c].astype(o["obs"].dtype)
        o["detection"][f[m], p[m], c] = pick[m, c]
        o["source"][f[m], p[m], c] = SOURCE_BLOB
        o["quality"][f[m], p[m], c] = 1.0


def _blob_sizes(detections: Callable[[int], FrameDetections], det: NDArray[np.integer],
                first: int) -> NDArray[np.float64]:
    """(P, C) median semi-major axis (px) of each point's blobs in each camera, over at
    most 120 frames spread over the take (NaN where it has none there)."""
    F, P, C = det.shape
    rows = np.unique(np.linspace(0, F - 1, min(F, 120)).astype(np.intp))
    vals = np.full((rows.size, P, C), np.nan)
    for i, f in enumerate(rows):
        frame = detections(int(f + first))
        for c in range(C):
            ax = frame[c][1]
            m = det[f, :, c] >= 0
            if ax is not None and m.any():
                vals[i, m, c] = np.asarray(ax, np.float64).reshape(-1, 2)[det[f, m, c], 0]
    with warnings.catch_warnings():  # a point never seen by a camera: NaN, no warning
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(vals, axis=0)
