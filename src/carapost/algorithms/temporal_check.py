"""Wrong observations found by time: a detection far from where the point's motion says.

Outlier rejection inside one frame (:func:`carapost.algorithms.triangulation.triangulate`
dropping the camera that fits worst) cannot see a wrong blob in the one camera of the
other caddy: a point seen by two cameras of one caddy has a poorly fixed depth, and the
lone camera of the other caddy is what fixes it, so the least-squares solution moves its
depth to agree with the wrong blob and every residual stays small. Nor can it see a
wrong blob in a two-camera sample. Time can: the point's neighbours in time, moved by
how its neighbours on the face moved, predict where it is
(:func:`loo_prediction`, the sample itself left out), and a wrong blob sits pixels away
from that prediction in its camera while the right ones agree with it
(:func:`inconsistent_observations`).

Units: mm in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``P`` points, ``C`` cameras.

Examples
--------
>>> import numpy as np
>>> X = np.zeros((5, 2, 3)); X[..., 2] = 100.0
>>> X[:, 1, 0] = 10.0
>>> tri = np.ones((5, 2), bool)
>>> nb = np.array([[1], [0]])
>>> pred = loo_prediction(X, tri, nb)
>>> bool(np.allclose(pred[1:4], X[1:4]))
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics, project

__all__ = ["inconsistent_observations", "loo_prediction"]

#: Least distance (px) from the motion's prediction that marks a wrong observation.
MIN_OFF_PX = 1.2

#: A wrong observation is this many times further from the prediction than the
#: sample's other observations are.
RATIO = 3.0


def loo_prediction(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp], *,
                   max_frames: int = 10) -> NDArray[np.float64]:
    """Each sample predicted from the point's nearest triangulated samples before and
    after it (at most ``max_frames`` away), the sample itself left out.

    Each of the two (where found) gives its position plus the mean displacement
    of the point's neighbours (``nb``, those triangulated on both frames) since; the
    prediction is the mean of the two, or the one that exists.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm).
    tri : array_like, shape (F, P)
        Triangulated samples.
    nb : ndarray of int, shape (P, k)
        Each point's neighbours (-1 for none).
    max_frames : int
        Farthest reference on each side (frames).

    Returns
    -------
    ndarray, shape (F, P, 3)
        Predictions (NaN where neither side gives one).
    """
    X = np.asarray(X, np.float64)
    tri = np.asarray(tri, bool) & np.isfinite(X).all(-1)
    F, P = tri.shape
    valid = nb >= 0
    nn = np.where(valid, nb, 0)
    frames = np.arange(F)
    idx = np.where(tri, frames[:, None], -1)
    prev = np.full((F, P), -1)
    prev[1:] = np.maximum.accumulate(idx, axis=0)[:-1]  # last triangulated frame < f
    idx = np.where(tri, frames[:, None], F)
    nxt = np.full((F, P), F)
    nxt[:-1] = np.minimum.accumulate(idx[::-1], axis=0)[::-1][1:]  # first one > f
    acc = np.zeros((F, P, 3))
    cnt = np.zeros((F, P))
    Xn = X[:, nn]  # (F, P, k, 3) the neighbours at every frame
    Tn = tri[:, nn] & valid[None]
    for g in (prev, nxt):
        have = (g >= 0) & (g < F) & (np.abs(g - frames[:, None]) <= max_frames)
        gg = np.where(have, g, 0)
        Xg = X[gg[:, :, None], nn[None]]  # (F, P, k, 3) the neighbours at the reference
        both = Tn & tri[gg[:, :, None], nn[None]]
        n = both.sum(2)
        disp = np.where(both[..., None], Xn - Xg, 0.0).sum(2)
        ok = have & (n > 0)
        est = X[gg, np.arange(P)[None]] + disp / np.maximum(n, 1)[..., None]
        acc += np.where(ok[..., None], est, 0.0)
        cnt += ok
    out = acc / np.maximum(cnt, 1)[..., None]
    out[cnt == 0] = np.nan
    return out


def inconsistent_observations(obs: ArrayLike, pred: ArrayLike, R: ArrayLike, t: ArrayLike,
                              intr: CameraIntrinsics, mask: ArrayLike, *,
                              min_px: float = MIN_OFF_PX, ratio: float = RATIO
                              ) -> NDArray[np.bool_]:
    """Observations far from the motion's prediction while the sample's others agree.

    For each masked sample, the distance of each observation to the prediction's
    projection in its camera; the furthest is flagged when it is more than ``min_px``
    away and more than ``ratio`` times as far as the next furthest (an error of the
    prediction itself moves every camera's projection alike, a wrong blob only its own).

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
    pred : array_like, shape (F, P, 3)
        Predicted positions (:func:`loo_prediction`).
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    mask : array_like of bool, shape (F, P)
        Samples to test (those with >= 2 observations are tested).
    min_px, ratio : float

    Returns
    -------
    ndarray of bool, shape (F, P, C)
        At most one flagged observation per sample.
    """
    o = np.asarray(obs, np.float64)
    Xp = np.asarray(pred, np.float64)
    F, P, C, _ = o.shape
    has = np.isfinite(o).all(-1)
    m = np.asarray(mask, bool) & (has.sum(-1) >= 2) & np.isfinite(Xp).all(-1)
    out = np.zeros((F, P, C), bool)
    fi, pi = np.nonzero(m)
    if fi.size == 0:
        return out
    Rm = np.asarray(R, np.float64)
    tm = np.asarray(t, np.float64)
    uv = np.empty((fi.size, C, 2))
    for f in np.unique(fi):
        rows = fi == f
        uv[rows] = project(Xp[f, pi[rows]], Rm[f], tm[f], intr)[0]
    d = np.linalg.norm(uv - o[fi, pi], axis=-1)
    d = np.where(has[fi, pi], d, -1.0)
    order = np.argsort(-d, axis=1)
    worst = d[np.arange(fi.size), order[:, 0]]
    second = d[np.arange(fi.size), order[:, 1]]
    bad = (worst > min_px) & (worst > ratio * np.maximum(second, 0.0))
    out[fi[bad], pi[bad], order[bad, 0]] = True
    return out
