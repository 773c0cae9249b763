"""The fill methods of :mod:`carapost.algorithms.gapfill`, vectorised over all gaps.

Every method works in the *head frame*: each frame's points are moved by the rigid
transform that best aligns that frame's known points to a reference shape
(:func:`head_frame`), so the motion of the whole head is taken out and what is left is
the face's own deformation. The fills are mapped back to the capture frame afterwards.

Gaps are given as flat tables: gap ``g`` is point ``point[g]``, frames
``start[g] .. end[g]`` (inclusive); ``left[g]`` / ``right[g]`` say whether its anchor
frame ``start - 1`` / ``end + 1`` holds a known sample the method may use. A method
returns the filled head-frame positions of every gap sample, in the order of
:func:`gap_samples`, NaN where it cannot fill.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms import _gapfill_jit as _jit

__all__ = ["gap_samples", "guide_fill", "head_frame", "interpolate_columns", "lowrank_fill",
           "neighbour_table", "spline_fill", "to_head", "to_world"]


def head_frame(X: NDArray, known: NDArray[np.bool_], *, iterations: int = 1,
               min_points: int = 3, zeroed: bool = False, max_residual: float = 0.15
               ) -> tuple[NDArray, NDArray, NDArray]:
    """Per-frame rigid transform of the head: ``x = R_f y + t_f``.

    Parameters
    ----------
    X : ndarray, shape (F, P, 3)
        Positions (mm); only ``known`` samples are read.
    known : ndarray, shape (F, P) bool
    zeroed : bool
        ``X`` already holds 0 wherever it is not known (saves a copy).
    iterations : int
        Reference-shape refinements (the first reference is the frame with most points).
    min_points : int
        Frames with fewer known points take the transform of the nearest frame that
        has enough.
    max_residual : float
        When the RMS distance of the aligned points from the reference shape exceeds
        this fraction of the shape's RMS radius, the points do not move as one rigid
        head and the identity is returned for every frame.

    Returns
    -------
    R : ndarray, shape (F, 3, 3)
    t : ndarray, shape (F, 3)
    ref : ndarray, shape (P, 3)
        The reference shape (head frame, mm), NaN for a point never known.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> shape = rng.normal(size=(6, 3)) * 30
    >>> X = np.stack([shape + [f, 0.0, 0.0] for f in range(4)])
    >>> R, t, ref = head_frame(X, np.ones((4, 6), bool))
    >>> bool(np.allclose(np.einsum("fij,fpj->fpi", R, ref[None]) + t[:, None], X))
    True
    """
    F, P, _ = X.shape
    R = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
    t = np.zeros((F, 3))
    counts = known.sum(1)
    if P < min_points or counts.max(initial=0) < min_points:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = (np.nanmedian(np.where(known[..., None], X, np.nan), axis=0) if F
                   else np.full((P, 3), np.nan))
        return R, t, ref
    Xz = np.where(known[..., None], X, 0.0) if not zeroed else X
    r0 = int(np.argmax(counts))
    ref = np.where(known[r0][:, None], X[r0], np.nan)
    good = counts >= min_points
    sub = np.linspace(0, F - 1, min(F, 2000)).astype(np.intp)
    for it in range(iterations + 1):
        w = (known & np.isfinite(ref[:, 0])[None]).astype(np.float64)
        refz = np.nan_to_num(ref)
        sw = w.sum(1)
        ok = good & (sw >= min_points)
        sw = np.maximum(sw, 1.0)
        Xw = Xz * w[..., None]
        cx = Xw.sum(1) / sw[:, None]                                    # (F, 3)
        cr = (w @ refz) / sw[:, None]
        # H_f = sum_p w (ref_p - cr)(x_p - cx)^T = sum_p w ref_p x_p^T - sw cr cx^T
        H = np.matmul(refz.T, Xw)                                       # (F, 3, 3)
        del Xw
        H -= sw[:, None, None] * cr[:, :, None] * cx[:, None, :]
        U, _, Vt = np.linalg.svd(H[ok])
        d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
        D = np.zeros_like(U)
        D[:, 0, 0] = D[:, 1, 1] = 1.0
        D[:, 2, 2] = d
        R[ok] = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
        t[ok] = cx[ok] - np.matmul(R[ok], cr[ok][..., None])[..., 0]
        # the frames too sparse to fit take their nearest fitted frame's transform
        idx = np.flatnonzero(ok)
        if len(idx) < F:
            near = idx[np.clip(np.searchsorted(idx, np.arange(F)), 0, len(idx) - 1)]
            prev = idx[np.clip(np.searchsorted(idx, np.arange(F)) - 1, 0, len(idx) - 1)]
            near = np.where(np.abs(prev - np.arange(F)) < np.abs(near - np.arange(F)), prev,
                            near)
            R, t = R[near], t[near]
        if it == iterations:
            break
        Ys = to_head(X[sub], R[sub], t[sub])
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanmedian(np.where(known[sub][..., None], Ys, np.nan), axis=0)
        if not np.isfinite(ref[:, 0]).sum() >= min_points:
            break
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        Ys = np.where(known[sub][..., None], to_head(X[sub], R[sub], t[sub]), np.nan)
        ref = np.nanmedian(Ys, axis=0)
        # not a head: when the points are far from moving rigidly (a body, several
        # objects), a per-frame rigid fit swings with the motion and would rotate each
        # point's offset from its neighbours; the capture frame is used instead
        resid = np.sqrt(np.nanmean(np.sum((Ys - ref[None]) ** 2, -1)))
        spread = np.sqrt(np.nanmean(np.sum((ref - np.nanmean(ref, 0)) ** 2, -1)))
    if not resid <= max_residual * spread:
        R = np.broadcast_to(np.eye(3), (F, 3, 3)).copy()
        t = np.zeros((F, 3))
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanmedian(np.where(known[sub][..., None], X[sub], np.nan), axis=0)
    return R, t, ref


def to_head(X: NDArray, R: NDArray, t: NDArray) -> NDArray:
    """Capture frame -> head frame: ``y = R_f^T (x - t_f)``; X (F, P, 3)."""
    return np.matmul(X - t[:, None], R)


def to_world(Y: NDArray, R: NDArray, t: NDArray) -> NDArray:
    """Head frame -> capture frame: ``x = R_f y + t_f``; Y (F, P, 3)."""
    return np.matmul(Y, np.swapaxes(R, 1, 2)) + t[:, None]


def neighbour_table(Y: NDArray, known: NDArray[np.bool_], k: int, *,
                    max_frames: int = 400) -> tuple[NDArray[np.intp], NDArray]:
    """The ``k`` nearest points of every point in the head frame, with weights 1/d^2.

    Returns
    -------
    nb : ndarray, shape (P, K) int (K = min(k, P - 1)); -1 where a point has fewer
    w : ndarray, shape (P, K) float, 0 where ``nb`` is -1
    """
    F, P, _ = Y.shape
    K = max(0, min(k, P - 1))
    if K == 0:
        return np.zeros((P, 0), np.intp), np.zeros((P, 0))
    step = max(1, F // max_frames)
    Ys = np.where(known[::step, :, None], Y[::step], np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.nanmedian(Ys, axis=0)
    d = np.linalg.norm(ref[:, None] - ref[None], axis=-1)
    d[~np.isfinite(d)] = np.inf
    np.fill_diagonal(d, np.inf)
    nb = np.argsort(d, axis=1)[:, :K]
    dist = np.take_along_axis(d, nb, 1)
    w = np.where(np.isfinite(dist), 1.0 / np.maximum(dist, 1.0) ** 2, 0.0)
    nb = np.where(np.isfinite(dist), nb, -1)
    return nb.astype(np.intp), w


def _f32(Y: NDArray) -> NDArray:
    return np.ascontiguousarray(Y, dtype=np.float32)


def _ip(a: NDArray) -> NDArray:
    return np.ascontiguousarray(a, dtype=np.int64)


def _b(a: NDArray) -> NDArray:
    return np.ascontiguousarray(a, dtype=np.bool_)


def gap_samples(start: NDArray, end: NDArray) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Flat sample table of gaps: (gap index, frame) of every gap sample, gap by gap."""
    lengths = (end - start + 1).astype(np.intp)
    g = np.repeat(np.arange(len(start)), lengths)
    first = np.cumsum(lengths) - lengths
    f = start[g] + (np.arange(len(g)) - first[g])
    return g.astype(np.intp), f.astype(np.intp)


def guide_fill(Y: NDArray, known: NDArray[np.bool_], point: NDArray, start: NDArray,
               end: NDArray, left: NDArray, right: NDArray, nb: NDArray, nbw: NDArray
               ) -> NDArray:
    """Neighbour prediction, forwards from ``start - 1`` and backwards from ``end + 1``.

    The point keeps its offset from where its neighbours are: the forward prediction at
    frame f is ``y_p(a) + sum_k w_k (y_k(f) - y_k(a)) / sum_k w_k`` over the neighbours
    known at both frames (head frame, so the head's own rotation is already removed);
    the backward one the same from ``b = end + 1``. Where both exist they are blended
    linearly across the gap, so the fill meets the data at both ends. A frame where no
    neighbour is known at both frames falls back to the anchor position itself.

    Returns
    -------
    ndarray, shape (S, 3)
        Head-frame positions of the samples of :func:`gap_samples`; NaN for a gap
        with neither anchor.
    """
    if not len(point):
        return np.zeros((0, 3))
    return _jit.guide(_f32(Y), known, _ip(point), _ip(start), _ip(end), _b(left), _b(right),
                      _ip(nb), np.asarray(nbw, np.float64))


def spline_fill(Y: NDArray, known: NDArray[np.bool_], point: NDArray, start: NDArray,
                end: NDArray, left: NDArray, right: NDArray, nb: NDArray | None = None,
                nbw: NDArray | None = None, side: int | NDArray = 3) -> NDArray:
    """Local cubic through the ``side`` frames either side of the gap, after taking out
    the neighbours' own motion.

    The point's offset from the weighted mean of its neighbours (those known over the
    whole window, so the mean does not jump) is fitted by a least-squares cubic in time
    through the known samples of frames ``start - side .. start - 1`` and
    ``end + 1 .. end + side``, evaluated in the gap, and the neighbours' mean added
    back. Without such neighbours it is a plain local cubic of the head-frame
    trajectory. Needs both anchors (NaN otherwise) and 4 known samples in the window.
    ``side`` is one number or one per gap.
    """
    n = len(start)
    if not n:
        return np.zeros((0, 3))
    sides = np.broadcast_to(np.asarray(side, np.int64), (n,)).copy()
    if nb is None or not nb.shape[1]:
        nb, nbw = np.zeros((Y.shape[1], 0), np.intp), np.zeros((Y.shape[1], 0))
    return _jit.spline(_f32(Y), known, _ip(point), _ip(start), _ip(end), _b(left), _b(right),
                       _ip(nb), np.asarray(nbw, np.float64), sides)


def interpolate_columns(M: NDArray, known: NDArray[np.bool_]) -> NDArray:
    """Linear interpolation in time of every column of ``M`` (F, D) over its unknown
    entries (held constant beyond the first and last known sample; the column mean of
    0 for a column never known)."""
    out = np.array(M, dtype=np.float64)
    _jit.interpolate_columns(out, np.ascontiguousarray(known, dtype=np.bool_))
    return out


def lowrank_fill(Y: NDArray, known: NDArray[np.bool_], hidden: NDArray[np.bool_], *,
                 energy: float = 0.99, max_rank: int = 60, outer: int = 3, inner: int = 6,
                 max_rows: int = 6000) -> NDArray:
    """Low-rank completion of the frames x (points x 3) head-frame matrix.

    The approach of Gløersen & Federolf (PLOS ONE 2016): the trajectories of all
    markers are strongly correlated, so the matrix of all their coordinates is close to
    low rank. Missing entries start from linear interpolation in time; then, ``outer``
    times, the principal components of the completed matrix (mean-centred, in mm, on at
    most ``max_rows`` evenly spaced frames) are computed, enough to hold ``energy`` of
    its variance, and ``inner`` expectation-maximisation steps set every missing entry to
    its frame's projection on those components (the known entries stay), which converges
    to the least-squares fit of each frame's known entries by the components. The
    matrix is held in float32; the EM steps run compiled, frame by frame on the missing
    entries only (the known entries' share of the projection is computed once per
    refresh), so a step costs in proportion to the missing entries, not the matrix.

    Parameters
    ----------
    Y : ndarray, shape (F, P, 3)
    known : ndarray, shape (F, P) bool
        Entries the fit may read.
    hidden : ndarray, shape (F, P) bool
        Entries to estimate (the others are returned unchanged where known).

    Returns
    -------
    ndarray, shape (F, P, 3)
        ``Y`` with every unknown entry estimated (NaN for points never known).
    """
    from threadpoolctl import threadpool_limits

    # small dense products and solves: one BLAS thread (see docs/dependencies.md)
    with threadpool_limits(1, user_api="blas"):
        return _lowrank(Y, known, hidden, energy, max_rank, outer, inner, max_rows)


def _lowrank(Y: NDArray, known: NDArray[np.bool_], hidden: NDArray[np.bool_], energy: float,
             max_rank: int, outer: int, inner: int, max_rows: int) -> NDArray:
    F, P, _ = Y.shape
    D = 3 * P
    kn = np.ascontiguousarray(known & ~hidden)
    ever = kn.any(0)
    Z, mean = _jit.lowrank_start(_f32(Y), kn)
    if kn.all() or D < 6:
        return (Z + mean.astype(np.float32)).reshape(F, P, 3)
    step = max(1, F // max_rows)
    for _ in range(outer):
        S = Z[::step].astype(np.float64)
        C = S.T @ S / len(S)
        ev, V = np.linalg.eigh(C)
        ev, V = ev[::-1], V[:, ::-1]
        total = max(ev.sum(), 1e-12)
        k = int(np.searchsorted(np.cumsum(ev) / total, energy) + 1)
        k = max(1, min(k, max_rank, D - 1))
        U = np.ascontiguousarray(V[:, :k])
        # EM: the missing entries take their projection on the components, the known
        # entries stay; a few steps per refresh of the components (compiled, per frame
        # on its missing entries only)
        _jit.lowrank_rows(Z, kn, U, (Z @ U.astype(np.float32)).astype(np.float64), inner)
    Z += mean.astype(np.float32)
    out = Z.reshape(F, P, 3)
    out[:, ~ever] = np.nan
    return out
