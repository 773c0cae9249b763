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
(:func:`inconsistent_observations`). A sample wrong in every camera (the same
neighbour's blob in both cameras of a caddy) leaves no camera to compare with the
others; its neighbours in time still disagree with it as a whole
(:func:`inconsistent_samples`).

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

__all__ = ["inconsistent_observations", "inconsistent_samples", "loo_prediction",
           "loo_sides"]

#: Least distance (px) from the motion's prediction that marks a wrong observation.
MIN_OFF_PX = 1.2

#: A wrong observation is this many times further from the prediction than the
#: sample's other observations are.
RATIO = 3.0

#: A wrong sample is this many times further from the mean of its two one-sided
#: predictions than they are from each other (each has its reference's depth noise:
#: for a right one-caddy sample the two distances are alike).
SAMPLE_RATIO = 2.0

#: Least distance (mm) from its neighbours in time that marks a wrong whole sample
#: (a two-camera sample's depth noise is a few tenths of a millimetre).
MIN_SAMPLE_OFF_MM = 1.0

#: A wrong whole sample deviates this many times more than its face neighbours do at
#: the same frame.
LOCAL_RATIO = 3.0


def loo_prediction(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp], *,
                   max_frames: int = 10) -> NDArray[np.float64]:
    """Each sample predicted from the point's nearest triangulated samples before and
    after it (at most ``max_frames`` away), the sample itself left out.

    Each of the two (where found) gives its position plus the mean displacement
    of the point's neighbours (``nb``, those triangulated on both frames) since; the
    prediction is the mean of the two, or the one that exists (:func:`loo_sides`).

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
    before, after = loo_sides(X, tri, nb, max_frames=max_frames)
    have = np.isfinite(before).all(-1)[..., None], np.isfinite(after).all(-1)[..., None]
    acc = np.where(have[0], before, 0.0) + np.where(have[1], after, 0.0)
    cnt = have[0].astype(np.float64) + have[1]
    out = acc / np.maximum(cnt, 1)
    out[cnt[..., 0] == 0] = np.nan
    return out


def loo_sides(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp], *,
              max_frames: int = 10) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The two one-sided predictions of :func:`loo_prediction`: from the point's
    nearest triangulated sample before each frame, and from the one after it.

    Parameters and shapes as for :func:`loo_prediction`.

    Returns
    -------
    before, after : ndarray, shape (F, P, 3)
        NaN where that side has no reference within ``max_frames`` (or no neighbour
        triangulated on both frames).
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
    Xn = X[:, nn]  # (F, P, k, 3) the neighbours at every frame
    Tn = tri[:, nn] & valid[None]
    out = []
    for g in (prev, nxt):
        have = (g >= 0) & (g < F) & (np.abs(g - frames[:, None]) <= max_frames)
        gg = np.where(have, g, 0)
        Xg = X[gg[:, :, None], nn[None]]  # (F, P, k, 3) the neighbours at the reference
        both = Tn & tri[gg[:, :, None], nn[None]]
        n = both.sum(2)
        disp = np.where(both[..., None], Xn - Xg, 0.0).sum(2)
        est = X[gg, np.arange(P)[None]] + disp / np.maximum(n, 1)[..., None]
        est[~(have & (n > 0))] = np.nan
        out.append(est)
    return out[0], out[1]


def inconsistent_samples(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp], *,
                         min_mm: float = MIN_SAMPLE_OFF_MM, ratio: float = SAMPLE_RATIO,
                         local_ratio: float = LOCAL_RATIO, iterations: int = 4
                         ) -> NDArray[np.bool_]:
    """Whole samples the point's motion contradicts: a wrong match in every camera.

    A sample whose observations are all on a wrong blob (a neighbour's, or a blob
    merged with one, the same in both cameras of a caddy) triangulates with a small
    residual, so neither the outlier rejection nor
    :func:`inconsistent_observations` sees it. Its neighbours in time do: the
    predictions from the samples before and after it (:func:`loo_sides`) agree with
    each other and not with it. A sample is flagged when it is more than ``min_mm``
    from the mean of the two, more than ``ratio`` times as far as they are from each
    other (a turn of the motion moves both predictions alike), and more than
    ``local_ratio`` times as far as the median of its face neighbours' own
    deviations at that frame (a fast expression the neighbours share deviates them
    all). Flagged samples are left out of the references and the test repeated (a
    wrong sample spoils its neighbours' predictions) until the set no longer
    changes, at most ``iterations`` times.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm).
    tri : array_like, shape (F, P)
        Triangulated samples (the ones tested and used as references).
    nb : ndarray of int, shape (P, k)
        Each point's neighbours on the face (-1 for none).
    min_mm, ratio, local_ratio : float
    iterations : int

    Returns
    -------
    ndarray of bool, shape (F, P)

    Examples
    --------
    Five points moving together, one sample of one of them 2 mm off:

    >>> import numpy as np
    >>> F, P = 9, 5
    >>> X = np.zeros((F, P, 3)); X[..., 2] = 100.0
    >>> X[..., 1] = 10.0 * np.arange(P)
    >>> X[..., 0] += np.arange(F)[:, None] * 0.2
    >>> X[4, 0, 1] += 2.0
    >>> nb = np.array([[q for q in range(P) if q != p] for p in range(P)])
    >>> np.argwhere(inconsistent_samples(X, np.ones((F, P), bool), nb)).tolist()
    [[4, 0]]
    """
    X = np.asarray(X, np.float64)
    tri = np.asarray(tri, bool) & np.isfinite(X).all(-1)
    valid = nb >= 0
    nn = np.where(valid, nb, 0)
    suspect = np.zeros(tri.shape, bool)
    for _ in range(iterations):
        before, after = loo_sides(X, tri & ~suspect, nb)
        dev = np.linalg.norm(X - 0.5 * (before + after), axis=-1)
        spread = np.linalg.norm(before - after, axis=-1)
        # the neighbours' own deviations at the frame (not the suspects': they are
        # what is tested)
        dn = np.where(valid[None] & ~suspect[:, nn] & tri[:, nn], dev[:, nn], np.nan)
        with np.errstate(invalid="ignore"):
            cnt = np.isfinite(dn).sum(-1)
            local = np.where(cnt > 0, np.nanmedian(np.where(cnt[..., None] > 0, dn, 0.0),
                                                   axis=-1), np.inf)
            now = tri & np.isfinite(dev) & (dev > min_mm) & (dev > ratio * spread) \
                & (dev > local_ratio * local)
        if np.array_equal(now, suspect):
            break
        suspect = now
    return suspect


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
