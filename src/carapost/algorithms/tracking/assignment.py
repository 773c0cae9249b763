"""Detections packed per frame and the optimal one-to-one assignment of the matcher."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from carapost.algorithms.tracking.records import FrameDetections

#: Infeasible assignment cost (anything far above the "no match" cost of 1).
INFEASIBLE_COST = 1e6


def pair_distances(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances between ``a`` (..., P, 2) and ``b`` (..., N, 2): (..., P, N).

    Component by component: reducing a length-2 last axis is several times slower.
    """
    dx = a[..., :, None, 0] - b[..., None, :, 0]
    dy = a[..., :, None, 1] - b[..., None, :, 1]
    return np.sqrt(dx * dx + dy * dy)


def assign(cost: NDArray[np.float64]) -> NDArray[np.intp]:
    """Optimal one-to-one assignment with a unit "no match" cost per row.

    ``cost`` is (P, N) with values >= INFEASIBLE_COST meaning infeasible; returns the matched column
    of each row or -1.
    """
    P, N = cost.shape
    out = np.full(P, -1, dtype=np.intp)
    if P == 0 or N == 0:
        return out
    feas = cost < INFEASIBLE_COST
    rows = np.flatnonzero(feas.any(1))
    if rows.size == 0:
        return out
    colsel = np.flatnonzero(feas[rows].any(0))
    sub = cost[np.ix_(rows, colsel)]
    # fast path: rows with one candidate whose column nobody else wants
    cnt_r = (sub < INFEASIBLE_COST).sum(1)
    cnt_c = (sub < INFEASIBLE_COST).sum(0)
    j = np.argmin(sub, axis=1)
    simple = (cnt_r == 1) & (cnt_c[j] == 1) & (sub[np.arange(len(rows)), j] <= 1.0)
    out[rows[simple]] = colsel[j[simple]]
    rest = ~simple
    if not rest.any():
        return out
    r2 = np.flatnonzero(rest)
    c2 = np.flatnonzero((sub[r2] < INFEASIBLE_COST).any(0))
    if c2.size == 0:
        return out
    block = sub[np.ix_(r2, c2)]
    n = len(r2)
    dummy = np.full((n, n), INFEASIBLE_COST)
    np.fill_diagonal(dummy, 1.0)
    full = np.concatenate([block, dummy], axis=1)
    ri, ci = linear_sum_assignment(full)
    ok = (ci < len(c2)) & (full[ri, ci] < 1.0 + 1e-12)
    ok &= full[ri, ci] < INFEASIBLE_COST
    out[rows[r2[ri[ok]]]] = colsel[c2[ci[ok]]]
    return out


class PackedFrame(NamedTuple):
    """One frame's detections as NaN-padded arrays over cameras (:func:`pack_detections`)."""

    centres: NDArray[np.float64]  # (C, N, 2) NaN padded
    axes: NDArray[np.float64]     # (C, N, 2) NaN where unknown
    counts: NDArray[np.intp]      # (C,)


def pack_detections(dets: FrameDetections, C: int) -> PackedFrame:
    """Pack one frame's per-camera ``(centre [N, 2], axes [N, 2] or None)`` detections.

    Parameters
    ----------
    dets : sequence of C tuples
        Detections of one frame per camera (px).
    C : int
        Number of cameras (``ValueError`` when ``dets`` has another length).

    Returns
    -------
    PackedFrame
        ``centres`` and ``axes`` (C, N, 2) NaN-padded to the largest count N (>= 1),
        ``counts`` (C,).
    """
    if len(dets) != C:
        raise ValueError(f"detections must give {C} cameras per frame, got {len(dets)}")
    counts = np.array([len(d[0]) for d in dets], dtype=np.intp)
    N = max(int(counts.max(initial=0)), 1)
    centres = np.full((C, N, 2), np.nan)
    axes = np.full((C, N, 2), np.nan)
    for c, (cen, ax) in enumerate(dets):
        n = counts[c]
        if n:
            centres[c, :n] = np.asarray(cen, np.float64).reshape(n, 2)
            if ax is not None:
                axes[c, :n] = np.asarray(ax, np.float64).reshape(n, 2)
    return PackedFrame(centres, axes, counts)
