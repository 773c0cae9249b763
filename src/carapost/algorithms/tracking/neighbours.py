"""The neighbour graph of the tracked points and the means taken over it.

Face points are predicted elastically from their nearest neighbours in 3D (in the start
frame), weighted by a Gaussian of that distance; these are the graph and the weighted,
outlier-resistant means the matcher and the drivers use.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree


def neighbour_graph(rest: ArrayLike, k: int) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Nearest neighbours of each point in 3D and their elastic weights.

    Parameters
    ----------
    rest : array_like, shape (P, 3)
        Rest positions (mm); NaN rows get no neighbours and are nobody's neighbour.
    k : int
        Neighbours per point.

    Returns
    -------
    index : ndarray, shape (P, k)
        Neighbour columns (P where there is none).
    weight : ndarray, shape (P, k)
        ``exp(-(d / s)^2)`` with ``s`` 1.5 times the median nearest-neighbour distance;
        0 where there is no neighbour.
    """
    X = np.asarray(rest, dtype=np.float64)
    P = X.shape[0]
    ok = np.isfinite(X).all(-1)
    cols = np.flatnonzero(ok)
    index = np.full((P, k), P, dtype=np.intp)
    weight = np.zeros((P, k))
    if cols.size < 2:
        return index, weight
    kk = min(k, cols.size - 1)
    d, j = cKDTree(X[cols]).query(X[cols], k=kk + 1)
    d, j = d[:, 1:], j[:, 1:]
    s = 1.5 * float(np.median(d[:, 0]))
    s = s if s > 0 else 1.0
    index[cols, :kk] = cols[j]
    weight[cols, :kk] = np.exp(-((d / s) ** 2))
    return index, weight


def weighted_neighbour_mean(values: NDArray[np.float64], valid: NDArray[np.bool_],
                             nb: NDArray[np.intp], w: NDArray[np.float64]
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean of the neighbours' ``values`` where ``valid``, and the summed weight.

    ``values`` is (P, ..., D), ``valid`` (P, ...), ``nb``/``w`` (P, k); returns the mean
    (P, ..., D) (0 where no support) and the support (P, ...).
    """
    P = values.shape[0]
    pad_v = np.concatenate([np.nan_to_num(values), np.zeros((1,) + values.shape[1:])])
    pad_m = np.concatenate([valid, np.zeros((1,) + valid.shape[1:], bool)])
    wm = w.reshape(w.shape + (1,) * (valid.ndim - 1)) * pad_m[nb]  # (P, k, ...)
    support = wm.sum(1)
    total = (wm[..., None] * pad_v[nb]).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(support[..., None] > 0, total / support[..., None], 0.0)
    return mean.reshape((P,) + values.shape[1:]), support


def robust_mean(values: NDArray[np.float64], valid: NDArray[np.bool_],
                 w: NDArray[np.float64], gate: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted mean over neighbours without the ones far from their median.

    ``values`` (n, k, D) per neighbour (e.g. 3D motions), ``valid`` (n, k), weights ``w``
    (n, k). Neighbours further than ``gate`` from the component-wise median of the valid
    ones are left out (with three or more valid neighbours). Returns the mean (n, D), 0
    where nothing is left, and the summed weight of the neighbours used (n,).
    """
    n, k, D = values.shape
    cnt = valid.sum(1)
    srt = np.sort(np.where(valid[..., None], values, np.inf), axis=1)
    idx = np.broadcast_to((np.maximum(cnt, 1) - 1)[:, None, None] // 2, (n, 1, D))
    med = np.take_along_axis(srt, idx, axis=1)  # (n, 1, D), lower median
    dev2 = np.zeros((n, k))
    for i in range(D):
        dev2 += (values[..., i] - med[..., i]) ** 2
    keep = valid & ((dev2 <= gate * gate) | (cnt < 3)[:, None])
    wm = w * keep
    support = wm.sum(1)
    total = (wm[..., None] * np.where(keep[..., None], values, 0.0)).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(support[:, None] > 0, total / support[:, None], 0.0)
    return mean, support


def shadows(X: NDArray[np.float64], lost: NDArray[np.bool_], seen: NDArray[np.bool_],
             face: NDArray[np.bool_], spacing: float) -> NDArray[np.bool_]:
    """Lost face points whose carried estimate lies on a tracked face point.

    Two markers are never closer than about the marker spacing, so a lost point's
    neighbour-carried estimate (``X``, (P, 3) mm) within half the ``spacing`` of a point
    tracked in the last frame has drifted onto that marker; matching it would take the
    marker's blobs from its own point (the point then slips or is lost, and the lost one
    takes its identity). Returns (P,) bool.
    """
    out = np.zeros(lost.shape, bool)
    cand = np.flatnonzero(lost & face & np.isfinite(X).all(-1))
    ref = np.flatnonzero(seen & face & np.isfinite(X).all(-1))
    if cand.size and ref.size:
        d, _ = cKDTree(X[ref]).query(X[cand])
        out[cand] = d < 0.5 * spacing
    return out


def marker_spacing(X: NDArray[np.float64]) -> float:
    """Median nearest-neighbour distance of the finite rows of ``X`` (mm; 10 if unknown)."""
    X = X[np.isfinite(X).all(-1)]
    if len(X) < 2:
        return 10.0
    d, _ = cKDTree(X).query(X, k=2)
    return float(np.median(d[:, 1]))
