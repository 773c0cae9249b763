"""Compiled (numba) kernel of the stabilisation's Gauss-Newton step: the block
tridiagonal normal equations of all frames in one pass over the samples
(:func:`carapost.algorithms.stabilise.stabilise_assisted`).

Compiled on first use and cached on disk (``cache=True``, in ``__pycache__`` beside this
file).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["normal_equations"]


@numba.njit(cache=True, nogil=True, inline="always")
def _add_jtj(M, w, a0, a1, a2, b0, b1, b2):  # pragma: no cover - jit
    """M (6 x 6) += w J(a)^T J(b), J(s) = [-[s]x | I]."""
    ab = a0 * b0 + a1 * b1 + a2 * b2
    # rotation-rotation: (a . b) I - b a^T
    M[0, 0] += w * (ab - b0 * a0)
    M[0, 1] -= w * b0 * a1
    M[0, 2] -= w * b0 * a2
    M[1, 0] -= w * b1 * a0
    M[1, 1] += w * (ab - b1 * a1)
    M[1, 2] -= w * b1 * a2
    M[2, 0] -= w * b2 * a0
    M[2, 1] -= w * b2 * a1
    M[2, 2] += w * (ab - b2 * a2)
    # rotation-translation: [a]x ; translation-rotation: -[b]x
    M[0, 4] -= w * a2
    M[0, 5] += w * a1
    M[1, 3] += w * a2
    M[1, 5] -= w * a0
    M[2, 3] -= w * a1
    M[2, 4] += w * a0
    M[3, 1] += w * b2
    M[3, 2] -= w * b1
    M[4, 0] -= w * b2
    M[4, 2] += w * b0
    M[5, 0] += w * b1
    M[5, 1] -= w * b0
    M[3, 3] += w
    M[4, 4] += w
    M[5, 5] += w


@numba.njit(cache=True, nogil=True, inline="always")
def _add_jtr(g, w, s0, s1, s2, r0, r1, r2):  # pragma: no cover - jit
    """g (6,) += w J(s)^T r = w [s x r, r]."""
    g[0] += w * (s1 * r2 - s2 * r1)
    g[1] += w * (s2 * r0 - s0 * r2)
    g[2] += w * (s0 * r1 - s1 * r0)
    g[3] += w * r0
    g[4] += w * r1
    g[5] += w * r2


@numba.njit(cache=True, nogil=True)
def normal_equations(S, ref, weight, wb, wi):  # pragma: no cover - jit
    """Normal equations of one Gauss-Newton step of the stabilisation cost.

    S (F, P, 3) stabilised positions (NaN where missing), ref (P, 3), weight (F, P) the
    stable points' weights (0 = not stable), wb / wi the base and inter-frame weights.
    Returns diag (F, 6, 6), off (F-1, 6, 6) (block (f, f-1)) and g (F, 6) with the
    update solving ``H theta = -g``.
    """
    F, P = S.shape[0], S.shape[1]
    diag = np.zeros((F, 6, 6))
    off = np.zeros((max(F - 1, 0), 6, 6))
    g = np.zeros((F, 6))
    for f in range(F):
        for n in range(P):
            m = weight[f, n]
            if m <= 0.0:
                continue
            a0, a1, a2 = S[f, n, 0], S[f, n, 1], S[f, n, 2]
            if not (np.isfinite(a0) and np.isfinite(a1) and np.isfinite(a2)):
                continue
            w = wb * m
            r0, r1, r2 = a0 - ref[n, 0], a1 - ref[n, 1], a2 - ref[n, 2]
            if w > 0.0 and np.isfinite(r0) and np.isfinite(r1) and np.isfinite(r2):
                _add_jtj(diag[f], w, a0, a1, a2, a0, a1, a2)
                _add_jtr(g[f], w, a0, a1, a2, r0, r1, r2)
            if wi > 0.0 and f > 0:
                b0, b1, b2 = S[f - 1, n, 0], S[f - 1, n, 1], S[f - 1, n, 2]
                if not (np.isfinite(b0) and np.isfinite(b1) and np.isfinite(b2)):
                    continue
                w = wi * m
                r0, r1, r2 = a0 - b0, a1 - b1, a2 - b2
                _add_jtj(diag[f], w, a0, a1, a2, a0, a1, a2)
                _add_jtj(diag[f - 1], w, b0, b1, b2, b0, b1, b2)
                _add_jtj(off[f - 1], -w, a0, a1, a2, b0, b1, b2)
                _add_jtr(g[f], w, a0, a1, a2, r0, r1, r2)
                _add_jtr(g[f - 1], -w, b0, b1, b2, r0, r1, r2)
    return diag, off, g


@numba.njit(cache=True, nogil=True)
def transform_points(T, X):  # pragma: no cover - jit
    """X (F, P, 3) mapped by per-frame transforms T (F, 4, 4): (F, P, 3), NaN kept."""
    F, P = X.shape[0], X.shape[1]
    out = np.empty((F, P, 3))
    for f in range(F):
        for n in range(P):
            x0, x1, x2 = X[f, n, 0], X[f, n, 1], X[f, n, 2]
            for i in range(3):
                out[f, n, i] = T[f, i, 0] * x0 + T[f, i, 1] * x1 + T[f, i, 2] * x2 + T[f, i, 3]
    return out


@numba.njit(cache=True, nogil=True)
def error_sums(S, base, stable):  # pragma: no cover - jit
    """Sums of squared distances of the stable points to the base frame (other frames)
    and to the previous frame, and their counts: (sum_b, n_b, sum_i, n_i)."""
    F, P = S.shape[0], S.shape[1]
    sb, si = 0.0, 0.0
    nb, ni = 0, 0
    for f in range(F):
        for n in range(P):
            if not stable[f, n]:
                continue
            if f != base:
                d = 0.0
                for i in range(3):
                    d += (S[f, n, i] - S[base, n, i]) ** 2
                if np.isfinite(d):
                    sb += d
                    nb += 1
            if f > 0:
                d = 0.0
                for i in range(3):
                    d += (S[f, n, i] - S[f - 1, n, i]) ** 2
                if np.isfinite(d):
                    si += d
                    ni += 1
    return sb, nb, si, ni
