"""Score tracked 3D positions against a synthetic take's truth (tests and benchmarks)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A point is matched to a truth marker when their mean distance is within this (mm).
MATCH_GATE_MM = 5.0
#: A point "is at" a marker within this distance (mm): coverage and identity swaps.
HIT_MM = 2.0


def track_quality(
    truth: NDArray, visible: NDArray, positions: NDArray
) -> tuple[float, int, float | None, int]:
    """Coverage, identity swaps, RMSE and spurious points of tracked positions.

    The definitions are those of ``carapost evaluate``: points are matched one-to-one to
    truth markers by mean distance (Hungarian, gated at 5 mm); coverage is the fraction
    of marker-frames seen by >= 2 cameras where the matched point is within 2 mm; a swap
    is a change of the marker a point is within 2 mm of; spurious points match nothing.

    Parameters
    ----------
    truth : ndarray, shape (F, M, 3)
        Truth marker positions (mm).
    visible : ndarray, shape (F, M, C) bool
        Truth visibility per camera.
    positions : ndarray, shape (F, P, 3)
        Tracked positions (mm), NaN where none; points never present are ignored.

    Returns
    -------
    coverage : float
    swaps : int
    rmse : float or None
        RMS distance (mm) of matched points to their markers; None when nothing matched.
    spurious : int
    """
    from scipy.optimize import linear_sum_assignment

    Y = np.asarray(positions, dtype=np.float64)
    Y = Y[:, np.isfinite(Y[..., 0]).any(0)]
    d = np.linalg.norm(Y[:, :, None] - truth[:, None], axis=-1)  # (F, P, M)
    cnt = np.isfinite(d).sum(0)
    mean = np.where(cnt > 0, np.nansum(d, 0) / np.maximum(cnt, 1), 1e9)
    r, c = linear_sum_assignment(mean)
    ok = mean[r, c] <= MATCH_GATE_MM
    covered = np.zeros(truth.shape[:2], bool)
    err = []
    for i, m in zip(r[ok], c[ok], strict=True):
        covered[:, m] = np.nan_to_num(d[:, i, m], nan=np.inf) <= HIT_MM
        err.append(d[:, i, m][np.isfinite(d[:, i, m])])
    seen = visible.sum(-1) >= 2
    dn = np.nan_to_num(d, nan=np.inf)
    hit = np.where(dn.min(2) <= HIT_MM, dn.argmin(2), -1)
    swaps = sum(int(np.count_nonzero(np.diff(h[h >= 0]))) for h in hit.T)
    e = np.concatenate(err) if err else np.zeros(0)
    rmse = float(np.sqrt(np.mean(e**2))) if e.size else None
    return float(covered[seen].mean()), swaps, rmse, int(Y.shape[1] - ok.sum())
