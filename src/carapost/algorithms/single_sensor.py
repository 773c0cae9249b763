"""Single-sensor samples after tracking: depth from the neighbours' motion on both sides.

A marker seen by one camera in a frame (the detector misses it in the caddy's second
camera, or the other camera does not see it) is placed by the per-frame tracker on that
camera's ray at the depth its neighbours predict from the last frame it was
triangulated in: a prediction from one side, with the cameras of that moment. Once the
whole take is tracked both sides are known. :func:`neighbour_prediction` predicts each
such sample from the point's triangulated samples before and after it, each moved by
how its neighbours moved since (so the face's motion over the gap is followed), the two
blended by their distance in time; :func:`place_on_rays` puts the sample on its
camera's ray (with the cameras fitted over time) at the point nearest that prediction;
:func:`prediction_sigma` gives the prediction's uncertainty along the ray, measured on
the take itself by predicting triangulated samples over the same gaps.

Units: mm in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``P`` points, ``C`` cameras.

Examples
--------
A point moving with its four neighbours, missing its triangulation on frames 3-5:

>>> import numpy as np
>>> F = 9
>>> base = np.array([[0., 0, 100], [10, 0, 100], [-10, 0, 100], [0, 10, 100],
...                  [0, -10, 100]])
>>> X = base[None] + np.linspace(0, 4, F)[:, None, None] * np.array([1., 0, 0])
>>> tri = np.ones((F, 5), bool)
>>> tri[3:6, 0] = False
>>> pred, gap = neighbour_prediction(np.where(tri[..., None], X, np.nan), tri)
>>> bool(np.allclose(pred[3:6, 0], X[3:6, 0])), gap[4, 0].item()
(True, 2)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics, pixel_rays

__all__ = ["neighbour_prediction", "neighbours", "place_on_rays", "prediction_sigma"]

#: Neighbours whose motion carries a point over a gap.
NEIGHBOURS = 6


def neighbours(X: NDArray[np.float64], tri: NDArray[np.bool_], k: int = NEIGHBOURS,
               max_frames: int = 40) -> NDArray[np.intp]:
    """(P, k) the k points nearest each point (median distance over the frames where
    both are in ``tri``, at most ``max_frames`` of them spread over the take; -1 where
    fewer exist). ``X`` (F, P, 3) mm, ``tri`` (F, P)."""
    F, P = tri.shape
    rows = np.unique(np.linspace(0, F - 1, min(F, max_frames)).astype(np.intp))
    Xs = np.where(tri[rows][..., None], X[rows], np.nan)
    d = np.linalg.norm(Xs[:, :, None] - Xs[:, None, :], axis=-1)  # (f, P, P)
    cnt = np.isfinite(d).sum(0)
    need = np.maximum(3, tri[rows].sum(0) // 4)
    with np.errstate(all="ignore"):
        d = np.where(np.isfinite(d), d, np.inf)
        med = np.sort(d, axis=0)
        # the median over the frames both have: the middle one of the finite entries
        mid = np.clip((cnt - 1) // 2, 0, max(len(rows) - 1, 0))
        med = np.take_along_axis(med, mid[None], axis=0)[0]
    med[cnt < need[:, None]] = np.inf
    np.fill_diagonal(med, np.inf)
    k = min(k, max(P - 1, 1))
    order = np.argsort(med, axis=1)[:, :k]
    order[~np.isfinite(np.take_along_axis(med, order, axis=1))] = -1
    return order


def _side(tri_p: NDArray[np.bool_], forward: bool) -> NDArray[np.intp]:
    """(F,) the nearest triangulated frame at or before (``forward`` False) / at or after
    each frame (-1 where none)."""
    F = tri_p.size
    idx = np.where(tri_p, np.arange(F), -1 if not forward else F)
    if forward:
        ref = np.minimum.accumulate(idx[::-1])[::-1]
        return np.where(ref < F, ref, -1)
    return np.maximum.accumulate(idx)


def neighbour_prediction(X: ArrayLike, tri: ArrayLike, *, k: int = NEIGHBOURS,
                         nb: NDArray[np.intp] | None = None
                         ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Predict every point on every frame from its triangulated samples on both sides.

    For frame ``f`` of point ``p``, with ``a`` the last frame before (or at) ``f`` and
    ``b`` the first after (or at) it where ``p`` is triangulated, each reference gives
    ``X[g, p]`` plus the mean displacement of ``p``'s neighbours from ``g`` to ``f``
    (those triangulated on both frames); the two are blended linearly in time (the
    nearer weighs more), one side alone where only one exists.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm); only the triangulated ones are read.
    tri : array_like, shape (F, P)
        Samples to trust (triangulated).
    k : int
        Neighbours per point.
    nb : ndarray, shape (P, k), optional
        The neighbours (indices, -1 for none) when already known.

    Returns
    -------
    pred : ndarray, shape (F, P, 3)
        Predictions (NaN where the point has no reference, or no neighbour with both
        frames); equal to ``X`` on triangulated samples.
    gap : ndarray, shape (F, P)
        Frames to the nearer reference used (0 on triangulated samples; -1 where none).
    """
    X = np.asarray(X, dtype=np.float64)
    tri = np.asarray(tri, dtype=bool) & np.isfinite(X).all(-1)
    F, P = tri.shape
    if nb is None:
        nb = neighbours(X, tri, k)
    pred = np.full((F, P, 3), np.nan)
    gap = np.full((F, P), -1, dtype=np.intp)
    frames = np.arange(F)
    for p in range(P):
        if not tri[:, p].any():
            continue
        n = nb[p][nb[p] >= 0]
        if n.size == 0:
            continue
        preds, dists = [], []
        for forward in (False, True):
            g = _side(tri[:, p], forward)
            have = g >= 0
            gg = np.where(have, g, 0)
            # neighbours' displacement from g to f, over those triangulated at both
            # (index the neighbours first: a whole-take copy per point would cost F*P^2)
            both = tri[:, n] & tri[gg[:, None], n] & have[:, None]  # (F, n)
            disp = np.where(both[..., None], X[:, n] - X[gg[:, None], n], 0.0).sum(1)
            cnt = both.sum(1)
            ok = have & (cnt > 0)
            est = X[gg, p] + disp / np.maximum(cnt, 1)[:, None]
            est[~ok] = np.nan
            preds.append(est)
            dists.append(np.where(ok, np.abs(frames - g), -1))
        (pa, pb), (da, db) = preds, dists
        wa = np.where(da >= 0, 1.0, 0.0)
        wb = np.where(db >= 0, 1.0, 0.0)
        both_sides = (da > 0) & (db > 0)
        # the nearer reference weighs more: linear in time between the two
        wa = np.where(both_sides, db / np.maximum(da + db, 1), wa)
        wb = np.where(both_sides, da / np.maximum(da + db, 1), wb)
        wb = np.where((da == 0), 0.0, wb)  # a triangulated frame is its own reference
        s = wa + wb
        est = (np.nan_to_num(pa) * wa[:, None] + np.nan_to_num(pb) * wb[:, None]) / \
            np.where(s > 0, s, 1.0)[:, None]
        est[s == 0] = np.nan
        pred[:, p] = est
        near = np.where(da >= 0, da, F)
        near = np.minimum(near, np.where(db >= 0, db, F))
        gap[:, p] = np.where(s > 0, near, -1)
    pred[tri] = X[tri]
    gap[tri] = 0
    return pred, gap


def place_on_rays(pred: ArrayLike, uv: ArrayLike, R: ArrayLike, t: ArrayLike,
                  intr: CameraIntrinsics, camera: ArrayLike
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Put each sample on its camera's ray at the point nearest its prediction.

    Parameters
    ----------
    pred : array_like, shape (N, 3)
        Predicted positions (mm).
    uv : array_like, shape (N, 2)
        The one observation of each sample (raw px).
    R, t : array_like, shapes (N, C, 3, 3) and (N, C, 3)
        Each sample's frame's cameras.
    intr : CameraIntrinsics
    camera : array_like of int, shape (N,)
        The camera that observed each sample.

    Returns
    -------
    X : ndarray, shape (N, 3)
        Positions on the rays (NaN where the nearest point is behind the camera).
    distance : ndarray, shape (N,)
        Distance (mm) from the prediction to the ray.
    direction : ndarray, shape (N, 3)
        Unit ray directions (the direction the prediction's error goes into).
    """
    pred = np.asarray(pred, np.float64)
    cam = np.asarray(camera, np.intp)
    N = cam.size
    R = np.asarray(R, np.float64)[np.arange(N), cam]
    t = np.asarray(t, np.float64)[np.arange(N), cam]
    origin, d = pixel_rays(np.asarray(uv, np.float64)[None], R[None], t[None],
                           intr.subset(cam))
    origin, d = origin[0], d[0]
    s = np.einsum("ni,ni->n", pred - origin, d)
    X = origin + s[:, None] * d
    dist = np.linalg.norm(X - pred, axis=-1)
    X[~(s > 0)] = np.nan
    return X, dist, d


def prediction_sigma(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp],
                     gaps: ArrayLike, *, step: int = 2, prior_tests: int = 10
                     ) -> NDArray[np.float64]:
    """Per-axis error (mm RMS) of :func:`neighbour_prediction` over each gap length, per
    point, measured on the take: triangulated samples predicted from references ``d``
    frames before and after them, the sample itself left out.

    A point whose motion its neighbours do not share (a lip against the other lip) is
    predicted worse than the face's average: each point's own error is used, shrunk
    towards the take's pooled one by ``prior_tests`` tests' worth (few tests of its
    own, mostly the pooled value).

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
    tri : array_like, shape (F, P)
    nb : ndarray, shape (P, k)
        Neighbours (as :func:`neighbour_prediction` uses).
    gaps : array_like of int, shape (G,)
        Gap lengths (frames to the nearer reference) to measure.
    step : int
        Every ``step``-th frame is a test frame.
    prior_tests : int

    Returns
    -------
    ndarray, shape (P, G)
        RMS per axis of the prediction error (mm; includes the triangulation error of
        the references and of the test samples, so it does not understate). NaN where
        the take allowed no test of that gap at all.
    """
    X = np.asarray(X, np.float64)
    tri = np.asarray(tri, bool) & np.isfinite(X).all(-1)
    F, P = tri.shape
    gaps = np.asarray(gaps, np.intp)
    out = np.full((P, gaps.size), np.nan)
    valid = nb >= 0
    nn = np.where(valid, nb, 0)
    for j, d in enumerate(gaps):
        sq = np.zeros(P)
        cnt = np.zeros(P)
        for f0 in range(int(d), F - int(d), step):
            a, b = f0 - d, f0 + d
            ps = np.flatnonzero(tri[f0] & tri[a] & tri[b])
            if ps.size == 0:
                continue
            n, v = nn[ps], valid[ps]
            est = np.zeros((ps.size, 3))
            good = np.ones(ps.size, bool)
            for g in (a, b):
                both = v & tri[f0][n] & tri[g][n]
                disp = np.where(both[..., None], X[f0][n] - X[g][n], 0.0).sum(1)
                k = both.sum(1)
                good &= k > 0
                est += 0.5 * (X[g, ps] + disp / np.maximum(k, 1)[:, None])
            e2 = np.sum((est - X[f0, ps]) ** 2, axis=-1) / 3.0
            np.add.at(sq, ps[good], e2[good])
            np.add.at(cnt, ps[good], 1)
        if cnt.sum() == 0:
            continue
        pooled = sq.sum() / cnt.sum()
        out[:, j] = np.sqrt((sq + prior_tests * pooled) / (cnt + prior_tests))
    return out
