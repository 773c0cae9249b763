"""Score tracked 3D positions against a synthetic take's truth.

One implementation serves ``carapost evaluate`` (`carapost.api.evaluate`, which adds
labels, file checks and the 2D reprojection) and the tests and benchmarks
(`track_quality`, on arrays).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

#: Largest mean distance (mm) at which a point is matched to a truth marker.
MATCH_GATE_MM = 5.0
#: Distance (mm) within which a point "is at" a marker (coverage, identity swaps).
HIT_MM = 2.0


class TrackScore(NamedTuple):
    """Result of `score_tracks` (P tracked points, M truth markers).

    Attributes
    ----------
    match : ndarray, shape (P,) int64
        Truth marker matched to each point, -1 for none (a spurious point).
    marker_rmse : dict of int to float
        RMS distance (mm) of each matched marker to its point over the frames where both
        exist, in point order; markers without such frames are left out.
    rmse : float or None
        RMS distance (mm) over all those frames; None when there are none.
    coverage : float or None
        Fraction of truth marker-frames seen (by >= 2 cameras) at which the matched point
        is within `HIT_MM`; None when no marker-frame is seen.
    swaps : ndarray, shape (P,) int64
        Identity changes along each point's track.
    """

    match: NDArray[np.int64]
    marker_rmse: dict[int, float]
    rmse: float | None
    coverage: float | None
    swaps: NDArray[np.int64]


def _pair_distances(
    A: NDArray[np.float64], B: NDArray[np.float64], chunk: int = 256
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int32], NDArray[np.float64]]:
    """Distances between every point of A [F,P,3] and B [F,M,3] over frames.

    Returns the sum of distances [P,M] and the count of frames [P,M] where both exist,
    and per frame the nearest marker of each point [F,P] (-1 if none) and its distance.
    Chunked over frames so that memory stays O(chunk * P * M).
    """
    F, P, _ = A.shape
    M = B.shape[1]
    total = np.zeros((P, M))
    count = np.zeros((P, M), dtype=np.int64)
    nearest = np.full((F, P), -1, dtype=np.int32)
    nearest_d = np.full((F, P), np.inf)
    for s in range(0, F, chunk):
        a, b = A[s:s + chunk], B[s:s + chunk]
        va, vb = ~np.isnan(a[..., 0]), ~np.isnan(b[..., 0])
        a0, b0 = np.where(va[..., None], a, 0.0), np.where(vb[..., None], b, 0.0)
        d2 = ((a0 * a0).sum(-1)[:, :, None] + (b0 * b0).sum(-1)[:, None, :]
              - 2.0 * np.einsum("fpi,fmi->fpm", a0, b0))
        d = np.sqrt(np.maximum(d2, 0.0))
        both = va[:, :, None] & vb[:, None, :]
        d = np.where(both, d, np.inf)
        total += np.where(both, d, 0.0).sum(axis=0)
        count += both.sum(axis=0)
        if M:
            nearest[s:s + chunk] = np.argmin(d, axis=2)
            nearest_d[s:s + chunk] = np.min(d, axis=2)
    nearest[~np.isfinite(nearest_d)] = -1
    return total, count, nearest, nearest_d


def score_tracks(
    positions: NDArray,
    truth: NDArray,
    visible: NDArray | None = None,
    preferred: NDArray | None = None,
) -> TrackScore:
    """Match tracked points to truth markers and score them (the ``evaluate`` metrics).

    Matching: a point whose `preferred` marker is within `MATCH_GATE_MM` (mean distance
    over the frames where both exist) is matched to it; the rest are matched one-to-one
    by the Hungarian method on the mean distance, keeping pairs within the same gate.
    A swap is a change, from one frame to the next at which the point is within `HIT_MM`
    of some marker, of the nearest such marker.

    Parameters
    ----------
    positions : ndarray, shape (F, P, 3)
        Tracked positions (mm), NaN where none.
    truth : ndarray, shape (F, M, 3)
        Truth marker positions (mm), NaN where none.
    visible : ndarray, shape (F, M, C) bool, optional
        Truth visibility per camera; without it every marker-frame counts as seen.
    preferred : ndarray, shape (P,) int, optional
        Marker to try first for each point (e.g. the one with the same label), -1 for none.

    Returns
    -------
    TrackScore
    """
    from scipy.optimize import linear_sum_assignment

    Y = np.asarray(positions, dtype=np.float64)
    X = np.asarray(truth, dtype=np.float64)
    F, P = Y.shape[:2]
    M = X.shape[1]

    total, count, nearest, nearest_d = _pair_distances(Y, X)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.inf)

    # Preferred matches first, then Hungarian on the rest.
    match = np.full(P, -1, dtype=np.int64)
    if preferred is not None:
        for i, m in enumerate(np.asarray(preferred).tolist()):
            if m >= 0 and mean[i, m] <= MATCH_GATE_MM and m not in match:
                match[i] = m
    free_p = np.flatnonzero(match < 0)
    free_m = np.setdiff1d(np.arange(M), match[match >= 0])
    if free_p.size and free_m.size:
        cost = mean[np.ix_(free_p, free_m)]
        rows, cols = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
        ok = cost[rows, cols] <= MATCH_GATE_MM
        match[free_p[rows[ok]]] = free_m[cols[ok]]

    # 3D error of the matched pairs (a loop over points, vectorised over frames).
    marker_rmse: dict[int, float] = {}
    sq_sum, n_sq = 0.0, 0
    covered = np.zeros((F, M), dtype=bool)
    for i in np.flatnonzero(match >= 0):
        m = int(match[i])
        d = np.linalg.norm(Y[:, i] - X[:, m], axis=-1)
        ok = ~np.isnan(d)
        if ok.any():
            marker_rmse[m] = float(np.sqrt(np.mean(d[ok] ** 2)))
            sq_sum += float(np.sum(d[ok] ** 2))
            n_sq += int(ok.sum())
        covered[:, m] = ok & (np.nan_to_num(d, nan=np.inf) <= HIT_MM)

    seen = (np.ones((F, M), dtype=bool) if visible is None
            else np.asarray(visible).astype(bool).sum(axis=-1) >= 2)
    seen &= ~np.isnan(X[..., 0])

    # Identity swaps: changes of the nearest marker within HIT_MM along each point's track.
    hit = np.where(nearest_d <= HIT_MM, nearest, -1)
    swaps = np.zeros(P, dtype=np.int64)
    for i in range(P):
        ids = hit[:, i][hit[:, i] >= 0]
        swaps[i] = np.count_nonzero(np.diff(ids)) if ids.size > 1 else 0

    return TrackScore(
        match=match,
        marker_rmse=marker_rmse,
        rmse=float(np.sqrt(sq_sum / n_sq)) if n_sq else None,
        coverage=float(covered[seen].mean()) if seen.any() else None,
        swaps=swaps,
    )


def track_quality(
    truth: NDArray, visible: NDArray, positions: NDArray
) -> tuple[float, int, float | None, int]:
    """Coverage, identity swaps, RMSE and spurious points of tracked positions.

    The metrics of ``carapost evaluate`` (`score_tracks`) without labels: points are
    matched one-to-one to truth markers by mean distance (Hungarian, gated at 5 mm);
    coverage is the fraction of marker-frames seen by >= 2 cameras where the matched
    point is within 2 mm; a swap is a change of the marker a point is within 2 mm of;
    spurious points match nothing.

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
        NaN when no marker-frame is seen by >= 2 cameras.
    swaps : int
    rmse : float or None
        RMS distance (mm) of matched points to their markers; None when nothing matched.
    spurious : int
    """
    Y = np.asarray(positions, dtype=np.float64)
    Y = Y[:, np.isfinite(Y[..., 0]).any(0)]
    s = score_tracks(Y, truth, visible)
    coverage = np.nan if s.coverage is None else s.coverage
    return coverage, int(s.swaps.sum()), s.rmse, int(np.count_nonzero(s.match < 0))


#: Names of the sample groups `group_quality` reports.
GROUPS = ("all", "one_caddy", "two_caddies")


def group_quality(truth: NDArray, visible: NDArray, positions: NDArray,
                  caddies: list[list[int]] | tuple[tuple[int, ...], ...],
                  sigma: NDArray | None = None, spurious_gate_mm: float = MATCH_GATE_MM
                  ) -> dict[str, dict[str, float | int | None]]:
    """Accuracy of tracked points by how the truth marker was seen: by the cameras of one
    caddy only, by both caddies, and overall.

    Points are matched to markers as in `score_tracks`. A sample (frame, matched point)
    belongs to ``one_caddy`` when the marker is seen by >= 2 cameras at that frame and
    all of them are on one caddy, to ``two_caddies`` when cameras of both caddies see
    it; samples of markers seen by fewer than two cameras count in ``all`` only.

    Parameters
    ----------
    truth : ndarray, shape (F, M, 3)
    visible : ndarray, shape (F, M, C) bool
    positions : ndarray, shape (F, P, 3)
        Tracked positions (mm), NaN where none; points never present are ignored.
    caddies : sequence of sequences of int
        Camera indices of each caddy.
    sigma : ndarray, shape (F, P), optional
        Estimated standard deviation (mm) of each sample's error along its worst
        direction; gives ``within_1sigma`` / ``within_2sigma``: the fraction of samples
        with a finite sigma whose error is within 1 / 2 sigma.
    spurious_gate_mm : float
        A point whose mean distance to every marker exceeds this is spurious.

    Returns
    -------
    dict
        Per group: ``samples``, ``rmse_mm``, ``median_mm``, ``p95_mm``, ``p99_mm``,
        ``max_mm``, ``over_0_5mm`` (fraction), ``coverage`` (of the group's seen
        marker-frames, within `HIT_MM`), ``within_1sigma``, ``within_2sigma`` (None
        without sigma); ``all`` also has ``swaps``, ``spurious`` and ``points``.
    """
    Y = np.asarray(positions, dtype=np.float64)
    present = np.isfinite(Y[..., 0]).any(0)
    Y = Y[:, present]
    sig = None if sigma is None else np.asarray(sigma, dtype=np.float64)[:, present]
    vis = np.asarray(visible).astype(bool)
    X = np.asarray(truth, dtype=np.float64)
    s = score_tracks(Y, X, vis)
    F, M = X.shape[:2]
    n_cad = np.stack([vis[..., list(cams)].any(-1) for cams in caddies], axis=-1)
    seen = (vis.sum(-1) >= 2) & np.isfinite(X[..., 0])
    one = seen & (n_cad.sum(-1) == 1)
    two = seen & (n_cad.sum(-1) >= 2)
    err = np.full((F, M), np.nan)
    sg = np.full((F, M), np.nan)
    for i in np.flatnonzero(s.match >= 0):
        m = int(s.match[i])
        err[:, m] = np.linalg.norm(Y[:, i] - X[:, m], axis=-1)
        if sig is not None:
            sg[:, m] = sig[:, i]
    out: dict[str, dict[str, float | int | None]] = {}
    for name, mask in (("all", np.isfinite(X[..., 0])), ("one_caddy", one),
                       ("two_caddies", two)):
        e = err[mask & np.isfinite(err)]
        row: dict[str, float | int | None] = {"samples": int(e.size)}
        if e.size:
            row.update(rmse_mm=float(np.sqrt(np.mean(e ** 2))), median_mm=float(np.median(e)),
                       p95_mm=float(np.percentile(e, 95)), p99_mm=float(np.percentile(e, 99)),
                       max_mm=float(e.max()), over_0_5mm=float(np.mean(e > 0.5)))
        else:
            row.update(rmse_mm=None, median_mm=None, p95_mm=None, p99_mm=None, max_mm=None,
                       over_0_5mm=None)
        grp_seen = seen & mask
        hit = np.nan_to_num(err, nan=np.inf) <= HIT_MM
        row["coverage"] = float(hit[grp_seen].mean()) if grp_seen.any() else None
        within = mask & np.isfinite(err) & np.isfinite(sg) & (sg > 0)
        if within.any():
            ratio = err[within] / sg[within]
            row["within_1sigma"] = float(np.mean(ratio <= 1.0))
            row["within_2sigma"] = float(np.mean(ratio <= 2.0))
        else:
            row["within_1sigma"] = row["within_2sigma"] = None
        out[name] = row
    out["all"]["swaps"] = int(s.swaps.sum())
    out["all"]["spurious"] = int(np.count_nonzero(s.match < 0))
    out["all"]["points"] = int(Y.shape[1])
    return out
