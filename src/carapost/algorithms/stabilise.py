"""Stabilisation: per-frame rigid transforms that remove the head's slip in the rig.

A head-mounted rig slips on the head while the actor talks, so the face markers move
in the helmet (brim) frame although the skull did not move relative to the face. The
stabilisation maps every frame's points by one rigid transform ``T_f`` onto the base
frame, using points that move with the skull and not with expression ("stable
points"):

- :func:`stabilise_manual`: the points the artist chose, every frame fitted to the base
  frame by weighted least squares (Kabsch, SVD), vectorised over frames.
- :func:`stabilise_assisted`: starts from that choice and minimises the weighted
  stabilisation error over the range: in each iteration every frame keeps its
  ``stable_points_percent`` most stable points (smallest distance to their base-frame
  position after the current transform), and is refitted onto a target that mixes the
  base frame (Base Frame Weighting) and its stabilised neighbours (Inter Frame
  Weighting); the iteration stops when the stabilisation error no longer decreases or
  after Max Processing Iterations.
- :func:`stabilise_auto` (:mod:`carapost.algorithms.stabilise_auto`): no selection at
  all. It picks the seed set (the points whose distances to each other vary least
  through the take), fits every frame to the take's mean stabilised shape with the same
  per-frame trimming (so no single frame's noise or expression steers it), and expresses
  the result relative to the most neutral frame.

Conventions: positions are (F, P, 3) in mm (NaN where missing); ``T`` is (F, 4, 4)
float64 with ``stabilised = raw @ T[f, :3, :3].T + T[f, :3, 3]``; a frame that could
not be stabilised (fewer than three usable points) has an all-NaN transform.

The stabilisation errors are those of the reference workflow's glossary:

- base-frame error: RMS over the range of the distance between each frame's stable
  points (after the transform) and the same points in the base frame;
- inter-frame error: RMS of the distance between each frame's stable points and the same
  points in the previous frame (both stabilised);
- stabilisation error: ``base_frame_weighting * base + inter_frame_weighting * inter``.

The stable points of a frame are the ``stable_points_percent`` fraction of its points
closest to their base-frame positions (manual: the selected points).

Examples
--------
>>> rng = np.random.default_rng(0)
>>> head = rng.uniform(-60, 60, (20, 3))
>>> from carapost.algorithms.camera import rodrigues_to_matrix
>>> R = rodrigues_to_matrix(rng.normal(0, 0.01, (50, 3)))
>>> raw = np.einsum("fij,pj->fpi", R, head) + rng.normal(0, 0.5, (50, 1, 3))
>>> st = stabilise_manual(raw, [0, 1, 2, 3], base_frame=0)
>>> bool(np.abs(apply_transforms(st.transforms, raw) - raw[0]).max() < 1e-9)
True
>>> round(st.base_frame_error, 9)
0.0
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import rodrigues_to_matrix
from carapost.algorithms.params import param, validate

__all__ = [
    "STABILIZATION",
    "StabilisationResult",
    "StabilizationParameters",
    "alignment_transform",
    "apply_transforms",
    "parse_axes",
    "stabilisation_errors",
    "stabilise_assisted",
    "stabilise_manual",
]

log = logging.getLogger("carapost.algorithms")

#: The Properties pane section of :class:`StabilizationParameters`.
STABILIZATION = "Stabilization Parameters"

Progress = Callable[[int, int], bool] | None


@dataclass(frozen=True)
class StabilizationParameters:
    """Stabilization Parameters (assisted and automatic stabilisation).

    Attributes
    ----------
    stabilization_use_brim_points : bool
        Use Brim Points: brim markers may join the stable set (only if the brim sits
        still on the head).
    base_frame_weighting : float
        Weight of the base-frame error in the stabilisation error.
    inter_frame_weighting : float
        Weight of the inter-frame error (frame-to-frame jitter).
    stable_points_percent : float
        Fraction (0-1) of the points of each frame taken as stable.
    max_processing_iterations : int
        Most iterations of the optimisation.
    tolerance : float
        The optimisation stops when an iteration lowers the stabilisation error by less
        than this fraction of it.
    """

    stabilization_use_brim_points: bool = param(
        False, label="Use Brim Points", section=STABILIZATION,
        help="Include brim markers in the stabilising set (only if the brim sits still on "
             "the head).")
    base_frame_weighting: float = param(
        1.0, label="Base Frame Weighting", section=STABILIZATION, min=0.0, max=1000.0,
        help="Weight of drift relative to the base frame in the stabilisation cost."
             " Upper bound is our choice.")
    inter_frame_weighting: float = param(
        1.0, label="Inter Frame Weighting", section=STABILIZATION, min=0.0, max=1000.0,
        help="Weight of frame-to-frame jitter in the stabilisation cost."
             " Upper bound is our choice.")
    stable_points_percent: float = param(
        0.25, label="Stable Points Percent", section=STABILIZATION, unit="0-1",
        min=0.0, max=1.0,
        help="Expected fraction of points that stay still in each frame; lower it for very "
             "expressive takes.")
    max_processing_iterations: int = param(
        50, label="Max Processing Iterations", section=STABILIZATION, min=1, max=10_000,
        help="Iteration cap of the stabilisation optimiser; more is slower but may fit "
             "better. Range is our choice.")
    tolerance: float = param(1e-4, min=0.0, max=1.0, min_exclusive=True)

    def __post_init__(self) -> None:
        validate(self)
        if self.base_frame_weighting + self.inter_frame_weighting <= 0:
            raise ValueError("Base Frame Weighting and Inter Frame Weighting cannot both "
                             "be 0")


@dataclass
class StabilisationResult:
    """Per-frame rigid transforms and their stabilisation errors.

    Attributes
    ----------
    transforms : ndarray, shape (F, 4, 4), float64
        Raw -> stabilised, NaN for frames not stabilised.
    base_frame : int
        Frame index (into the input) mapped onto itself.
    points : ndarray of intp
        Columns of the seed set (manual: the selection; auto: the chosen stable set).
    stable : ndarray of bool, shape (F, P)
        The stable points of each frame (the ones the errors are measured on).
    base_frame_error, inter_frame_error, error : float
        The glossary's errors (mm); ``error`` is their weighted sum.
    iterations : int
        Optimisation iterations run (0 for manual).
    cancelled : bool
        The progress callback stopped the optimisation (the last iterate is returned).
    """

    transforms: NDArray[np.float64]
    base_frame: int
    points: NDArray[np.intp]
    stable: NDArray[np.bool_] = field(repr=False)
    base_frame_error: float = 0.0
    inter_frame_error: float = 0.0
    error: float = 0.0
    iterations: int = 0
    cancelled: bool = False


# ----------------------------------------------------------------------------------------
# transforms
# ----------------------------------------------------------------------------------------
def _to4(R: NDArray, t: NDArray) -> NDArray[np.float64]:
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def apply_transforms(transforms: ArrayLike, positions: ArrayLike) -> NDArray[np.float64]:
    """Map positions by per-frame (or one) rigid transforms.

    Parameters
    ----------
    transforms : array_like, shape (F, 4, 4) or (4, 4)
    positions : array_like, shape (F, P, 3)
        mm; NaN stays NaN, and a frame with a NaN transform becomes NaN.

    Returns
    -------
    ndarray, shape (F, P, 3), float64

    Examples
    --------
    >>> T = np.eye(4); T[:3, 3] = [1.0, 2.0, 3.0]
    >>> apply_transforms(T, np.zeros((1, 1, 3))).tolist()
    [[[1.0, 2.0, 3.0]]]
    """
    T = np.asarray(transforms, np.float64)
    X = np.asarray(positions, np.float64)
    if T.ndim == 2:
        return X @ T[:3, :3].T + T[:3, 3]
    if X.shape[0] * X.shape[1] >= 10_000:  # compiled: numpy's batched 3 x 3 matmul is slow
        from carapost.algorithms._stabilise_jit import transform_points

        return transform_points(np.ascontiguousarray(T), np.ascontiguousarray(X))
    return np.matmul(X, np.swapaxes(T[:, :3, :3], 1, 2)) + T[:, None, :3, 3]


def _weighted_kabsch(A: NDArray, B: NDArray, w: NDArray
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Batched weighted rigid fits ``B ~ A @ R.T + t`` (rows with weight 0 ignored).

    A, B: (F, N, 3) (NaN allowed where w == 0); w: (F, N). Returns R (F, 3, 3), t (F, 3),
    ok (F,): at least 3 weighted rows and a non-degenerate spread.
    """
    w = np.where(np.isfinite(A).all(-1) & np.isfinite(B).all(-1), w, 0.0)
    A = np.nan_to_num(A)
    B = np.nan_to_num(B)
    sw = w.sum(1)
    ok = ((w > 0).sum(1) >= 3) & (sw > 0)
    s = w / np.where(sw > 0, sw, 1.0)[:, None]
    ca = _wsum(s, A)
    cb = _wsum(s, B)
    H = np.swapaxes((A - ca[:, None]) * s[..., None], 1, 2) @ (B - cb[:, None])
    U, S, Vt = np.linalg.svd(H)
    # collinear or coincident points leave the rotation undetermined
    ok &= S[:, 1] > 1e-9 * np.maximum(S[:, 0], 1e-300)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    Vt = Vt.copy()
    Vt[:, 2] *= d[:, None]
    R = np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)
    t = cb - (R @ ca[..., None])[..., 0]
    return R, t, ok


def _wsum(w: NDArray, a: NDArray) -> NDArray:
    """sum_n w[f, n] a[f, n, :] -> (F, 3), as a batched matmul."""
    return (w[:, None, :] @ a)[:, 0]


# ----------------------------------------------------------------------------------------
# errors
# ----------------------------------------------------------------------------------------
def stabilisation_errors(stabilised: NDArray, base_frame: int, stable: NDArray,
                         base_weight: float = 1.0, inter_weight: float = 1.0
                         ) -> tuple[float, float, float]:
    """The glossary's stabilisation errors of stabilised positions.

    Parameters
    ----------
    stabilised : ndarray, shape (F, P, 3)
        Stabilised positions (mm).
    base_frame : int
    stable : ndarray of bool, shape (F, P)
        The stable points of each frame.
    base_weight, inter_weight : float
        Base Frame Weighting and Inter Frame Weighting.

    Returns
    -------
    base, inter, weighted : float
        RMS distances (mm) to the base frame and to the previous frame over the stable
        points, and ``base_weight * base + inter_weight * inter``.
    """
    from carapost.algorithms._stabilise_jit import error_sums

    sb, nb, si, ni = error_sums(np.ascontiguousarray(stabilised, np.float64), int(base_frame),
                                np.ascontiguousarray(stable, np.bool_))
    base = float(np.sqrt(sb / nb)) if nb else 0.0
    inter = float(np.sqrt(si / ni)) if ni else 0.0
    return base, inter, base_weight * base + inter_weight * inter


# ----------------------------------------------------------------------------------------
# manual
# ----------------------------------------------------------------------------------------
def _check(positions: ArrayLike, base_frame: int) -> NDArray[np.float64]:
    X = np.asarray(positions, np.float64)
    if X.ndim != 3 or X.shape[-1] != 3:
        raise ValueError(f"positions must have shape (F, P, 3), got {X.shape}")
    if not 0 <= int(base_frame) < len(X):
        raise ValueError(f"base frame {base_frame} is outside the frames (0-{len(X) - 1})")
    return X


def stabilise_manual(positions: ArrayLike, points: Sequence[int] | NDArray, *,
                     base_frame: int, weights: ArrayLike | None = None
                     ) -> StabilisationResult:
    """Stabilize Data [Manual]: each frame's chosen points onto their base-frame places.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
        Raw positions (mm).
    points : sequence of int
        Columns of the stable points (at least 3, not collinear).
    base_frame : int
        Frame mapped onto itself.
    weights : array_like, shape (len(points),), optional
        Weight of each point in the least-squares fit (default equal).

    Returns
    -------
    StabilisationResult
        Errors measured on the chosen points; frames where fewer than 3 of them exist
        get a NaN transform.

    Raises
    ------
    ValueError
        Fewer than 3 points, or the points are missing or collinear at the base frame.
    """
    X = _check(positions, base_frame)
    cols = np.asarray(points, dtype=np.intp).reshape(-1)
    if len(np.unique(cols)) < 3:
        raise ValueError(f"stabilisation needs at least 3 points, got {len(np.unique(cols))}")
    F, P = X.shape[:2]
    w = np.ones(len(cols)) if weights is None else np.asarray(weights, np.float64)
    A = X[:, cols]
    B = np.broadcast_to(X[base_frame, cols], A.shape)
    if not np.isfinite(B).all():
        raise ValueError(f"every stable point must exist at the base frame {base_frame}")
    R, t, ok = _weighted_kabsch(A, B, np.broadcast_to(w, A.shape[:2]).copy())
    if not ok[base_frame]:
        raise ValueError("the stable points are collinear: they cannot fix a rotation")
    T = _to4(R, t)
    T[base_frame] = np.eye(4)  # exactly the identity, not an SVD round-off of it
    T[~ok] = np.nan
    stable = np.zeros((F, P), dtype=bool)
    stable[:, cols] = True
    # the errors are measured on the chosen points only: map just those
    S = apply_transforms(T, A)
    base, inter, err = stabilisation_errors(S, int(base_frame), np.ones(A.shape[:2], bool))
    return StabilisationResult(T, int(base_frame), cols, stable, base, inter, err)


# ----------------------------------------------------------------------------------------
# assisted
# ----------------------------------------------------------------------------------------
def _stable_mask(d2: NDArray, fraction: float, keep: NDArray) -> NDArray[np.bool_]:
    """Per frame, the ``fraction`` of finite points with the smallest d2 (at least 3),
    plus ``keep`` (the seed points, when present) unless a seed is clearly off: more than
    3 times the frame's median stable distance (a selected point that moves with
    expression after all)."""
    fin = np.isfinite(d2)
    n_fin = fin.sum(1)
    k = np.minimum(np.clip(np.ceil(fraction * n_fin).astype(np.intp), 3, None), n_fin)
    srt = np.sort(np.where(fin, d2, np.inf), axis=1)
    rows = np.arange(len(d2))
    thresh = srt[rows, np.maximum(k - 1, 0)]
    median = srt[rows, np.maximum(k - 1, 0) // 2]
    with np.errstate(invalid="ignore"):
        seeds = keep & fin & (d2 <= 9.0 * median[:, None])
        return (fin & (d2 <= thresh[:, None]) & (k[:, None] > 0)) | seeds


def _cross_matrix(v: NDArray) -> NDArray:
    """[v]x for a stack of vectors (..., 3) -> (..., 3, 3)."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _jtj(w: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """sum_i w_i J(a_i)^T J(b_i) per frame, J(s) = [-[s]x | I] (3 x 6): (F, 6, 6)."""
    F = len(w)
    sw = w.sum(1)
    sa = _wsum(w, a)
    sb = _wsum(w, b)
    wb_ = b * w[..., None]
    ab = (wb_ * a).sum((1, 2))
    ba = np.swapaxes(wb_, 1, 2) @ a
    out = np.zeros((F, 6, 6))
    out[:, :3, :3] = ab[:, None, None] * np.eye(3) - ba
    out[:, :3, 3:] = _cross_matrix(sa)
    out[:, 3:, :3] = -_cross_matrix(sb)
    out[:, 3:, 3:] = sw[:, None, None] * np.eye(3)
    return out


def _jtr(w: NDArray, s: NDArray, r: NDArray) -> NDArray:
    """sum_i w_i J(s_i)^T r_i per frame: (F, 6) (rotation part s x r, then r)."""
    wr = r * w[..., None]
    # sum_n s x (w r) = the antisymmetric part of sum_n (w r) s^T
    M = np.swapaxes(wr, 1, 2) @ s  # (F, 3, 3): M[i, j] = sum w r_i s_j
    rot = np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0],
                    M[:, 1, 0] - M[:, 0, 1]], 1)
    return np.concatenate([rot, wr.sum(1)], 1)


def _gauss_newton_step(S: NDArray, ref: NDArray, stable: NDArray, wb: float, wi: float,
                       fixed: int) -> NDArray[np.float64]:
    """One Gauss-Newton step of the weighted stabilisation cost over all frames at once.

    Each frame's update is a small rigid motion ``s -> s + omega x s + tau`` of its
    stabilised points ``S`` (F, P, 3); the base-frame term couples a frame to ``ref``,
    the inter-frame term couples neighbours, so the normal equations are block
    tridiagonal (6 x 6 blocks) and solved as one banded system. ``fixed`` (the base
    frame) does not move. Returns the updates (F, 6): omega (rad), tau (mm).
    """
    from carapost.algorithms._stabilise_jit import normal_equations

    F = len(S)
    diag, off, g = normal_equations(np.ascontiguousarray(S, np.float64),
                                    np.ascontiguousarray(ref, np.float64),
                                    np.ascontiguousarray(stable, np.float64),
                                    float(wb), float(wi))
    scale = max(float(np.abs(diag).max(initial=0.0)), 1.0)
    diag += 1e-9 * scale * np.eye(6)
    diag[fixed] += 1e6 * scale * np.eye(6)
    g[fixed] = 0.0
    # symmetric banded storage (upper form) of the block tridiagonal matrix
    n = 6 * F
    u = 11
    ab_ = np.zeros((u + 1, n))
    rr, cc = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    base = 6 * np.arange(F)
    rows = (base[:, None, None] + rr).ravel()
    cols = (base[:, None, None] + cc).ravel()
    up = cols >= rows
    ab_[u + rows[up] - cols[up], cols[up]] = diag.ravel()[up]
    if F > 1:
        # block (f-1, f) = off[f-1].T, above the diagonal
        rows = (base[:-1, None, None] + rr).ravel()
        cols = (base[1:, None, None] + cc).ravel()
        ab_[u + rows - cols, cols] = np.swapaxes(off, 1, 2).ravel()
    from scipy.linalg import solveh_banded

    return -solveh_banded(ab_, g.ravel(), check_finite=False).reshape(F, 6)


def stabilise_assisted(positions: ArrayLike, points: Sequence[int] | NDArray, *,
                       base_frame: int, params: StabilizationParameters | None = None,
                       candidates: NDArray[np.bool_] | None = None,
                       reference: NDArray | None = None,
                       point_weights: NDArray | None = None,
                       progress: Progress = None) -> StabilisationResult:
    """Stabilize Data [Assisted]: from a selection, add stable points and minimise the
    weighted stabilisation error.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
        Raw positions (mm), NaN where missing.
    points : sequence of int
        Seed columns (at least 3): the first transforms are those of
        :func:`stabilise_manual` on them, and they stay in every frame's stable set.
    base_frame : int
    params : StabilizationParameters, optional
    candidates : ndarray of bool, shape (P,), optional
        Columns that may join the stable set (default all; the caller leaves brim
        points out unless Use Brim Points).
    reference : ndarray, shape (P, 3), optional
        The shape every frame is fitted to, in base-frame coordinates (default: the base
        frame's positions; automatic stabilisation passes a de-noised median shape).
    point_weights : ndarray, shape (P,), optional
        Weight of each point in the fits (default 1; automatic stabilisation weights
        each point by the inverse of its motion in a first pass).
    progress : callable, optional
        ``progress(iteration, max_iterations)``; False stops (result ``cancelled``).

    Returns
    -------
    StabilisationResult

    Notes
    -----
    Each iteration is one Jacobi step of the weighted cost ``wb * sum ||T_f x_f - x_b||^2
    + wi * sum ||T_f x_f - T_{f-1} x_{f-1}||^2`` over each frame's stable points: the
    terms of frame f are ``(wb + n wi) ||T_f x_f - y_f||^2`` with the target ``y_f`` the
    weighted mean of the base-frame positions and the neighbours' stabilised positions,
    so every frame is one weighted Kabsch fit, all frames in one batched SVD.
    """
    p = params or StabilizationParameters()
    X = _check(positions, base_frame)
    F, P = X.shape[:2]
    seed = np.unique(np.asarray(points, dtype=np.intp).reshape(-1))
    st = stabilise_manual(X, seed, base_frame=base_frame)
    cand = np.ones(P, bool) if candidates is None else np.asarray(candidates, bool).copy()
    cand[seed] = True
    keep = np.zeros((1, P), bool)
    keep[0, seed] = True
    ref = X[base_frame] if reference is None else np.asarray(reference, np.float64)
    usable = cand & np.isfinite(ref).all(-1)
    Xc = np.where(usable[None, :, None], X, np.nan)
    T = np.where(np.isfinite(st.transforms), st.transforms, np.nan)
    wb, wi = float(p.base_frame_weighting), float(p.inter_frame_weighting)
    it = 0
    cancelled = False
    valid = np.isfinite(T).all((1, 2))
    pw = (np.ones(P) if point_weights is None
          else np.nan_to_num(np.asarray(point_weights, np.float64)))[None, :]
    last = np.inf
    S = apply_transforms(T, Xc)
    for it in range(1, int(p.max_processing_iterations) + 1):
        # choose each frame's stable points, then one exact Gauss-Newton step of the
        # weighted cost over all frames together (trimmed least squares: each step
        # lowers the cost on the chosen points)
        stable = _stable_mask(((S - ref) ** 2).sum(-1), p.stable_points_percent, keep)
        err = stabilisation_errors(S, int(base_frame), stable, wb, wi)[2]
        if not np.isfinite(err) or last - err <= p.tolerance * max(err, 1e-3):
            break
        last = err
        step = _gauss_newton_step(S, ref, (stable & valid[:, None]) * pw, wb, wi,
                                  int(base_frame))
        dT = _to4(rodrigues_to_matrix(step[:, :3]), step[:, 3:])
        T = np.where(valid[:, None, None], dT @ T, T)
        T[base_frame] = np.eye(4)  # held by the solve; exact here
        S = apply_transforms(T, Xc)
        if progress is not None and progress(it, int(p.max_processing_iterations)) is False:
            cancelled = True
            break
    S = apply_transforms(T, Xc)
    stable = _stable_mask(((S - ref) ** 2).sum(-1), p.stable_points_percent, keep)
    base, inter, err = stabilisation_errors(S, int(base_frame), stable, wb, wi)
    return StabilisationResult(T, int(base_frame), seed, stable, base, inter, err, it,
                               cancelled)


# ----------------------------------------------------------------------------------------
# alignment
# ----------------------------------------------------------------------------------------
_AXES = {"x": 0, "y": 1, "z": 2}


def parse_axes(axes: str) -> tuple[tuple[int, float], tuple[int, float]]:
    """``"xy"``, ``"-zx"``, ``"x-y"``...: the axis (index, sign) that points from the
    first point towards the second, and the one on whose positive side the third lies.

    Examples
    --------
    >>> parse_axes("xy")
    ((0, 1.0), (1, 1.0))
    >>> parse_axes("-zx")
    ((2, -1.0), (0, 1.0))
    """
    s = str(axes).strip().lower().replace(" ", "")
    out: list[tuple[int, float]] = []
    i = 0
    while i < len(s):
        sign = 1.0
        if s[i] in "+-":
            sign = -1.0 if s[i] == "-" else 1.0
            i += 1
        if i >= len(s) or s[i] not in _AXES:
            raise ValueError(f"axes must be two of x, y, z with optional signs (e.g. 'xy', "
                             f"'-zx'), got {axes!r}")
        out.append((_AXES[s[i]], sign))
        i += 1
    if len(out) != 2 or out[0][0] == out[1][0]:
        raise ValueError(f"axes must name two different axes (e.g. 'xy'), got {axes!r}")
    return out[0], out[1]


def alignment_transform(p1: ArrayLike, p2: ArrayLike, p3: ArrayLike, axes: str = "xy",
                        *, min_angle_deg: float = 1.0) -> NDArray[np.float64]:
    """Align Data: the rigid transform into the frame three points define.

    The origin is ``p1``; the first axis of ``axes`` (default x) points from ``p1``
    towards ``p2``; ``p3`` lies in the plane of the first and second axes (default the
    x-y plane), on the positive side of the second; the third axis completes a
    right-handed frame.

    Parameters
    ----------
    p1, p2, p3 : array_like, shape (3,)
        mm.
    axes : str
        See :func:`parse_axes`.
    min_angle_deg : float
        Smallest angle at ``p1`` between ``p2`` and ``p3`` (and p2 != p1): nearly
        collinear points define no plane.

    Returns
    -------
    ndarray, shape (4, 4)

    Raises
    ------
    ValueError
        Coincident or collinear points, or bad ``axes``.

    Examples
    --------
    >>> A = alignment_transform([1, 1, 1], [3, 1, 1], [1, 5, 1])
    >>> apply_transforms(A, np.array([[[1, 1, 1], [3, 1, 1], [1, 5, 1]]])).round(12).tolist()
    [[[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 4.0, 0.0]]]
    """
    a, b, c = (np.asarray(p, np.float64).reshape(3) for p in (p1, p2, p3))
    if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(c).all()):
        raise ValueError("the three points must all exist at this frame")
    (ia, sa), (ib, sb) = parse_axes(axes)
    u = b - a
    v = c - a
    nu, nv = np.linalg.norm(u), np.linalg.norm(v)
    if nu < 1e-9 or nv < 1e-9:
        raise ValueError("the three points must be distinct")
    u /= nu
    sin = np.linalg.norm(np.cross(u, v / nv))
    if sin < np.sin(np.radians(min_angle_deg)):
        raise ValueError(f"the three points are collinear (the angle at the first point is "
                         f"{np.degrees(np.arcsin(min(sin, 1.0))):.2f} degrees); they define "
                         f"no plane")
    v = v - (v @ u) * u
    v /= np.linalg.norm(v)
    w = np.cross(u, v)
    ea = np.zeros(3)
    ea[ia] = sa
    eb = np.zeros(3)
    eb[ib] = sb
    ec = np.cross(ea, eb)
    R = np.stack([ea, eb, ec], 1) @ np.stack([u, v, w], 0)
    return _to4(R, -R @ a)


_AUTOMATIC = ("AUTO_FIRST_SEEDS", "AUTO_SEEDS", "choose_base_frame", "choose_stable_points",
              "stabilise_auto")


def __getattr__(name: str) -> object:
    # the automatic mode lives in its own module, which builds on this one
    if name in _AUTOMATIC:
        from carapost.algorithms import stabilise_auto

        return getattr(stabilise_auto, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
