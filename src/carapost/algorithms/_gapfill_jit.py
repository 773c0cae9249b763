"""Compiled (numba) kernels of the gap-filling methods: one loop over the gaps and their
samples instead of (samples x neighbours x 3) gathers (:mod:`carapost.algorithms.gapfill_methods`).

Every kernel takes the flat gap table (``point``, ``start``, ``end``, ``left``,
``right``) and writes the samples in the order of
:func:`carapost.algorithms.gapfill_methods.gap_samples` (gap by gap, frame by frame).
Compiled on first use and cached on disk (``cache=True``, in ``__pycache__`` beside this
file).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["ends_blend", "guide", "interpolate_columns", "lowrank_rows", "lowrank_start", "spline",
           "to_head32"]


@numba.njit(cache=True, nogil=True)
def _offsets(start, end):  # pragma: no cover - jit
    G = len(start)
    off = np.empty(G + 1, np.int64)
    off[0] = 0
    for g in range(G):
        off[g + 1] = off[g] + (end[g] - start[g] + 1)
    return off


@numba.njit(cache=True, nogil=True)
def guide(Y, known, point, start, end, left, right, nb, nbw):  # pragma: no cover - jit
    """The neighbour prediction of :func:`~carapost.algorithms.gapfill_methods.guide_fill`.

    Y (F, P, 3) float32 head frame, known (F, P) bool, nb (P, K) int (-1: none),
    nbw (P, K) float64. Returns (S, 3) float64, NaN for a gap with neither anchor.
    """
    F = Y.shape[0]
    K = nb.shape[1]
    off = _offsets(start, end)
    out = np.full((off[-1], 3), np.nan)
    pred = np.empty((2, 3))
    for g in range(len(point)):
        p = point[g]
        a = start[g] - 1
        b = end[g] + 1
        for f in range(start[g], end[g] + 1):
            s = off[g] + f - start[g]
            for side in range(2):
                anc = a if side == 0 else b
                use = left[g] if side == 0 else right[g]
                if not use:
                    continue
                anc = min(max(anc, 0), F - 1)
                sw = 0.0
                m0 = 0.0
                m1 = 0.0
                m2 = 0.0
                for k in range(K):
                    q = nb[p, k]
                    if q < 0 or not known[f, q] or not known[anc, q]:
                        continue
                    w = nbw[p, k]
                    sw += w
                    m0 += w * (np.float64(Y[f, q, 0]) - np.float64(Y[anc, q, 0]))
                    m1 += w * (np.float64(Y[f, q, 1]) - np.float64(Y[anc, q, 1]))
                    m2 += w * (np.float64(Y[f, q, 2]) - np.float64(Y[anc, q, 2]))
                if sw > 0:
                    m0 /= sw
                    m1 /= sw
                    m2 /= sw
                else:
                    m0 = m1 = m2 = 0.0
                pred[side, 0] = Y[anc, p, 0] + m0
                pred[side, 1] = Y[anc, p, 1] + m1
                pred[side, 2] = Y[anc, p, 2] + m2
            if left[g] and right[g]:
                w = (f - a) / max(b - a, 1)
                for i in range(3):
                    out[s, i] = (1.0 - w) * pred[0, i] + w * pred[1, i]
            elif left[g]:
                for i in range(3):
                    out[s, i] = pred[0, i]
            elif right[g]:
                for i in range(3):
                    out[s, i] = pred[1, i]
    return out


@numba.njit(cache=True, nogil=True)
def spline(Y, known, point, start, end, left, right, nb, nbw, side):  # pragma: no cover - jit
    """The local cubic of :func:`~carapost.algorithms.gapfill_methods.spline_fill`, with
    ``side`` (G,) frames of context per gap; nb of shape (P, 0) for none."""
    F = Y.shape[0]
    K = nb.shape[1]
    off = _offsets(start, end)
    out = np.full((off[-1], 3), np.nan)
    wq = np.zeros(max(K, 1))
    A = np.empty((4, 4))
    B = np.empty((4, 3))
    V = np.empty(4)
    for g in range(len(point)):
        if not (left[g] and right[g]):
            continue
        p = point[g]
        sd = side[g]
        lo = max(start[g] - sd, 0)
        hi = min(end[g] + sd + 1, F)
        # neighbours known over the whole window, weights normalised
        sw = 0.0
        for k in range(K):
            wq[k] = 0.0
            q = nb[p, k]
            if q < 0:
                continue
            full = True
            for f in range(lo, hi):
                if not known[f, q]:
                    full = False
                    break
            if full:
                wq[k] = nbw[p, k]
                sw += wq[k]
        for k in range(K):
            wq[k] = wq[k] / max(sw, 1e-300)
        mid = 0.5 * (start[g] + end[g])
        half = max(0.5 * (end[g] - start[g]) + sd, 1.0)
        A[:] = 0.0
        B[:] = 0.0
        n = 0
        for j in range(2 * sd):
            f = start[g] - sd + j if j < sd else end[g] + 1 + (j - sd)
            if f < 0 or f >= F or not known[f, p]:
                continue
            n += 1
            tau = (f - mid) / half
            V[0] = 1.0
            V[1] = tau
            V[2] = tau * tau
            V[3] = tau * tau * tau
            for c in range(3):
                r = np.float64(Y[f, p, c])
                for k in range(K):
                    if wq[k] != 0.0:
                        r -= wq[k] * Y[f, nb[p, k], c]
                for i in range(4):
                    B[i, c] += V[i] * r
            for i in range(4):
                for j2 in range(4):
                    A[i, j2] += V[i] * V[j2]
        if n < 4:
            continue
        for i in range(4):
            A[i, i] += 1e-9
        coef = np.linalg.solve(A, B)
        for f in range(start[g], end[g] + 1):
            s = off[g] + f - start[g]
            tau = (f - mid) / half
            for c in range(3):
                v = coef[0, c] + tau * (coef[1, c] + tau * (coef[2, c] + tau * coef[3, c]))
                for k in range(K):
                    if wq[k] != 0.0:
                        v += wq[k] * Y[f, nb[p, k], c]
                out[s, c] = v
    return out


@numba.njit(cache=True, nogil=True)
def ends_blend(fit, Y, point, start, end, left, right):  # pragma: no cover - jit
    """Fit (F, P, 3) of each gap sample plus its offsets to ``Y`` at the anchors, blended
    linearly across the gap (one-sided: the one offset); NaN with neither anchor."""
    F = Y.shape[0]
    off = _offsets(start, end)
    out = np.full((off[-1], 3), np.nan)
    for g in range(len(point)):
        if not (left[g] or right[g]):
            continue
        p = point[g]
        a = min(max(start[g] - 1, 0), F - 1)
        b = min(max(end[g] + 1, 0), F - 1)
        for f in range(start[g], end[g] + 1):
            s = off[g] + f - start[g]
            w = (f - (start[g] - 1)) / (end[g] + 1 - (start[g] - 1))
            for c in range(3):
                ra = Y[a, p, c] - fit[a, p, c]
                rb = Y[b, p, c] - fit[b, p, c]
                if left[g] and right[g]:
                    o = (1.0 - w) * ra + w * rb
                elif left[g]:
                    o = ra
                else:
                    o = rb
                out[s, c] = fit[f, p, c] + o
    return out


@numba.njit(cache=True, nogil=True)
def interpolate_columns(M, known):  # pragma: no cover - jit
    """In place: linear interpolation in time of every column of M (F, D) over its
    unknown entries, constant beyond the first and last known one, 0 if never known."""
    F, D = M.shape
    for j in range(D):
        prev = -1
        for f in range(F):
            if not known[f, j]:
                continue
            if prev < 0:
                for h in range(f):
                    M[h, j] = M[f, j]
            elif f > prev + 1:
                a = M[prev, j]
                b = M[f, j]
                for h in range(prev + 1, f):
                    w = (h - prev) / (f - prev)
                    M[h, j] = (1.0 - w) * a + w * b
            prev = f
        if prev < 0:
            for h in range(F):
                M[h, j] = 0.0
        else:
            for h in range(prev + 1, F):
                M[h, j] = M[prev, j]


@numba.njit(cache=True, nogil=True)
def lowrank_start(Y, known):  # pragma: no cover - jit
    """The start of the low-rank completion: the (F, 3 P) float32 matrix of the head-frame
    coordinates of ``known`` samples minus each column's mean, linearly interpolated in
    time over the others (constant beyond the ends, 0 for a point never known); and
    the column means (3 P,) float64."""
    F, P, _ = Y.shape
    Z = np.empty((F, 3 * P), np.float32)
    mean = np.zeros(3 * P)
    for p in range(P):
        n = 0
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for f in range(F):
            if known[f, p]:
                n += 1
                s0 += Y[f, p, 0]
                s1 += Y[f, p, 1]
                s2 += Y[f, p, 2]
        if n:
            mean[3 * p] = s0 / n
            mean[3 * p + 1] = s1 / n
            mean[3 * p + 2] = s2 / n
        j = 3 * p
        prev = -1
        for f in range(F):
            if not known[f, p]:
                continue
            for c in range(3):
                v = Y[f, p, c] - mean[j + c]
                if prev < 0:
                    for h in range(f):
                        Z[h, j + c] = v
                elif f > prev + 1:
                    a = np.float64(Z[prev, j + c])
                    for h in range(prev + 1, f):
                        w = (h - prev) / (f - prev)
                        Z[h, j + c] = (1.0 - w) * a + w * v
                Z[f, j + c] = v
            prev = f
        for c in range(3):
            if prev < 0:
                for h in range(F):
                    Z[h, j + c] = 0.0
            else:
                for h in range(prev + 1, F):
                    Z[h, j + c] = Z[prev, j + c]
    return Z, mean


@numba.njit(cache=True, nogil=True, fastmath=True)
def lowrank_rows(Z, known, U, C, steps):  # pragma: no cover - jit
    """In place: ``steps`` expectation-maximisation steps on the missing points of each
    frame (row of Z, (F, 3 P)) with the components U (3 P, k): the missing entries
    become their projection ``U_M (U^T z)``, the known entries stay.

    ``C = Z @ U`` (F, k) comes from the caller (one BLAS product for all frames). The
    known entries' share ``U_K^T z_K`` does not change between steps, so a step costs
    2 m k for m missing entries instead of 2 (3 P) k for the whole row.
    """
    F, D = Z.shape
    P = D // 3
    k = U.shape[1]
    c0 = np.empty(k)
    x = np.empty(k)
    idx = np.empty(D, np.int64)
    zm = np.empty(D)
    UM = np.empty((D, k))
    for r in range(F):
        m = 0
        for p in range(P):
            if not known[r, p]:
                idx[m] = 3 * p
                idx[m + 1] = 3 * p + 1
                idx[m + 2] = 3 * p + 2
                m += 3
        if m == 0:
            continue
        for t in range(m):
            for i in range(k):
                UM[t, i] = U[idx[t], i]
        for i in range(k):
            c0[i] = C[r, i]
        for t in range(m):
            z = np.float64(Z[r, idx[t]])
            zm[t] = z
            for i in range(k):
                c0[i] -= UM[t, i] * z
        for _ in range(steps):
            for i in range(k):
                x[i] = c0[i]
            for t in range(m):
                z = zm[t]
                for i in range(k):
                    x[i] += UM[t, i] * z
            for t in range(m):
                acc = 0.0
                for i in range(k):
                    acc += UM[t, i] * x[i]
                zm[t] = acc
        for t in range(m):
            Z[r, idx[t]] = zm[t]


@numba.njit(cache=True, nogil=True)
def to_head32(X, known, R, t):  # pragma: no cover - jit
    """Capture frame -> head frame, ``y = R_f^T (x - t_f)``, as float32, NaN where not
    known: X (F, P, 3) float64, R (F, 3, 3), t (F, 3)."""
    F, P, _ = X.shape
    Y = np.empty((F, P, 3), np.float32)
    for f in range(F):
        for p in range(P):
            if not known[f, p]:
                Y[f, p, 0] = Y[f, p, 1] = Y[f, p, 2] = np.nan
                continue
            d0 = X[f, p, 0] - t[f, 0]
            d1 = X[f, p, 1] - t[f, 1]
            d2 = X[f, p, 2] - t[f, 2]
            for i in range(3):
                Y[f, p, i] = d0 * R[f, 0, i] + d1 * R[f, 1, i] + d2 * R[f, 2, i]
    return Y
