"""Stabilize Data [Automatic]: stabilisation without a selection.

The artist's two choices are made from the data:

- the seed set: the points whose distances to each other vary least through the take
  (:func:`choose_stable_points`; distances do not change with the slip);
- the base frame: the most neutral frame (:func:`choose_base_frame`).

The transforms themselves do not depend on the base frame. Every frame is first fitted on
the seeds to their mean shape (generalised Procrustes), then, in a few passes, to the
take's mean stabilised shape of all points with the per-frame trimming of assisted
stabilisation (each frame keeps its Stable Points Percent points closest to the shape):
a single frame's noise or expression never becomes the reference. The seeds of each pass
are the points that moved least in the previous one. Only at the end is the result
expressed relative to the base frame (that frame is exactly the identity), like the
other modes.

Examples
--------
>>> from carapost.algorithms.camera import rodrigues_to_matrix
>>> from carapost.algorithms.stabilise import apply_transforms
>>> rng = np.random.default_rng(0)
>>> head = rng.uniform(-60, 60, (30, 3))
>>> R = rodrigues_to_matrix(rng.normal(0, 0.02, (80, 3)))
>>> raw = np.einsum("fij,pj->fpi", R, head) + rng.normal(0, 1.0, (80, 1, 3))
>>> st = stabilise_auto(raw)
>>> S = apply_transforms(st.transforms, raw)
>>> bool(np.abs(S - S[st.base_frame]).max() < 1e-6)
True
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import rodrigues_to_matrix
from carapost.algorithms.rigid import kabsch
from carapost.algorithms.stabilise import (
    Progress,
    StabilisationResult,
    StabilizationParameters,
    _stable_mask,
    _to4,
    _weighted_kabsch,
    apply_transforms,
    stabilisation_errors,
)

__all__ = ["AUTO_FIRST_SEEDS", "AUTO_PASSES", "AUTO_SEEDS", "choose_base_frame",
           "choose_stable_points", "stabilise_auto"]

log = logging.getLogger("carapost.algorithms")

#: Points of the automatic seed set, kept in every frame's stable set (the rest of each
#: frame's stable points are chosen per frame, as in assisted stabilisation).
AUTO_SEEDS = 6
#: Points of the first choice by rigidity, from which the base frame is chosen.
AUTO_FIRST_SEEDS = 12
#: Passes of "fit to the mean shape, then take the points that moved least as seeds".
AUTO_PASSES = 3


def _sample_frames(F: int, n: int) -> NDArray[np.intp]:
    return np.unique(np.linspace(0, F - 1, min(F, n)).round().astype(np.intp))


def choose_stable_points(positions: ArrayLike, *, fraction: float = 0.25,
                         candidates: NDArray[np.bool_] | None = None, samples: int = 200,
                         min_points: int = 4) -> NDArray[np.intp]:
    """The points whose distances to each other vary least through the take.

    Distances between points are unchanged by the head's slip, so points that move
    with the skull keep them; points that move with expression do not. Over ``samples``
    frames spread through the take, each point scores the median over the current set
    of the spread (MAD) of its distance to the set's points; the set is refined three
    times from all candidates.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
    fraction : float
        Fraction of the candidates returned (at least ``min_points``).
    candidates : ndarray of bool, shape (P,), optional
    samples : int
        Frames used.
    min_points : int

    Returns
    -------
    ndarray of intp
        Columns, most stable first.
    """
    X = np.asarray(positions, np.float64)
    F, P = X.shape[:2]
    cand = np.ones(P, bool) if candidates is None else np.asarray(candidates, bool)
    present = np.isfinite(X[..., 0]).mean(0) >= 0.5
    cols = np.flatnonzero(cand & present)
    if len(cols) < 3:
        raise ValueError(f"only {len(cols)} points are present in at least half of the "
                         "frames; stabilisation needs 3")
    Y = X[_sample_frames(F, samples)][:, cols]
    D = np.linalg.norm(Y[:, :, None] - Y[:, None], axis=-1)  # (S, N, N)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(D, axis=0)
        spread = np.nanmedian(np.abs(D - med), axis=0)  # (N, N) MAD of each distance
    spread = np.where(np.isfinite(spread), spread, np.inf)
    np.fill_diagonal(spread, np.nan)
    n = len(cols)
    k = int(min(n, max(min_points, np.ceil(fraction * n))))
    chosen = np.arange(n)
    for _ in range(4):
        score = np.nanmedian(spread[:, chosen], axis=1)
        chosen = np.argsort(score, kind="stable")[:k]
    score = np.nanmedian(spread[:, chosen], axis=1)
    return cols[np.argsort(score, kind="stable")[:k]]


def choose_base_frame(positions: ArrayLike, points: Sequence[int] | NDArray | None = None,
                      *, samples: int = 120) -> int:
    """The most neutral frame: the one the face shape differs from least in other frames.

    Every sampled frame is rigidly fitted (on ``points``, the stable set) to every
    other, and the face shape difference of a pair is the median distance of all points
    after that fit. The medoid (smallest summed difference) among the sampled frames
    wins; expressions are departures from a shared neutral, so the neutral frame is the
    one closest to all the others.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
    points : sequence of int, optional
        Columns the fits use (default: every point).
    samples : int

    Returns
    -------
    int
        Frame index.
    """
    X = np.asarray(positions, np.float64)
    F, P = X.shape[:2]
    frames = _sample_frames(F, samples)
    full = np.isfinite(X[frames, :, 0]).all(0)
    cols = np.flatnonzero(full)
    if len(cols) < 3:
        # fall back to the frames with most points
        counts = np.isfinite(X[..., 0]).sum(1)
        return int(np.argmax(counts))
    fit_cols = cols if points is None else np.intersect1d(cols, np.asarray(points))
    if len(fit_cols) < 3:
        fit_cols = cols
    Y = X[frames][:, cols]
    fit_idx = np.searchsorted(cols, fit_cols)
    n = len(frames)
    ii, jj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    R, t = kabsch(Y[ii][:, fit_idx], Y[jj][:, fit_idx])
    moved = np.einsum("kij,kpj->kpi", R, Y[ii]) + t[:, None]
    diff = np.median(np.linalg.norm(moved - Y[jj], axis=-1), axis=1).reshape(n, n)
    return int(frames[np.argmin(diff.sum(1))])


def _mean_shape(S: NDArray) -> NDArray[np.float64]:
    """Mean over frames of stabilised positions (P, 3), NaN for points never present."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(S, axis=0)


def _procrustes(X: NDArray, seed: NDArray, iterations: int = 5) -> NDArray[np.float64]:
    """Every frame fitted on the seeds to their mean shape (generalised Procrustes):
    (F, 4, 4), NaN where fewer than 3 seeds exist."""
    Y = X[:, seed]
    complete = np.flatnonzero(np.isfinite(Y).all((1, 2)))
    ref = Y[complete[0]] if len(complete) else _mean_shape(Y)
    T = np.full((len(X), 4, 4), np.nan)
    for _ in range(iterations):
        R, t, ok = _weighted_kabsch(Y, np.broadcast_to(ref, Y.shape),
                                    np.ones(Y.shape[:2]))
        T = _to4(R, t)
        T[~ok] = np.nan
        ref = _mean_shape(apply_transforms(T, Y))
        if not np.isfinite(ref).all():
            break
    return T


def _block_step(S: NDArray, ref: NDArray, weight: NDArray) -> NDArray[np.float64]:
    """One Gauss-Newton step of ``sum_n w ||T_f x - ref||^2`` for every frame on its own
    (no inter-frame term, no frame held): (F, 6) updates, omega (rad) and tau (mm)."""
    from carapost.algorithms._stabilise_jit import normal_equations

    diag, _, g = normal_equations(np.ascontiguousarray(S, np.float64),
                                  np.ascontiguousarray(ref, np.float64),
                                  np.ascontiguousarray(weight, np.float64), 1.0, 0.0)
    scale = np.maximum(np.abs(diag).max((1, 2)), 1.0)
    diag += 1e-9 * scale[:, None, None] * np.eye(6)
    return -np.linalg.solve(diag, g[..., None])[..., 0]


def _residual_scale(S: NDArray, shape: NDArray, cand: NDArray, fraction: float
                    ) -> NDArray[np.float64] | None:
    """Each point's usual squared residual to the shape (P,), relative to the median
    point's: the median over the frames where it is among the ``fraction`` closest
    points (its tracking noise, not its expression), floored at a quarter of the median
    so that no point dominates; None when no point qualifies."""
    d2 = np.where(cand[None], ((S - shape) ** 2).sum(-1), np.nan)
    stable = _stable_mask(d2, fraction, np.zeros((1, d2.shape[1]), bool))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        r2 = np.nanmedian(np.where(stable, d2, np.nan), axis=0)
        m = float(np.nanmedian(r2))
    if not np.isfinite(m) or m <= 0:
        return None
    # a point never among the closest gets the largest scale seen
    return np.where(np.isfinite(r2), np.maximum(r2, 0.25 * m), np.nanmax(r2)) / m


def _fit_to_shape(X: NDArray, seed: NDArray, ref: NDArray, usable: NDArray,
                  params: StabilizationParameters, tick: Progress,
                  noise2: NDArray | None = None
                  ) -> tuple[NDArray[np.float64], bool]:
    """Trimmed least squares of every frame onto ``ref`` (P, 3): each iteration keeps
    each frame's Stable Points Percent points closest to ``ref`` (plus the seeds) and
    takes one Gauss-Newton step. With ``noise2`` (P,), each point's usual squared
    residual, the closest points are chosen in units of it and weighted by
    ``1 / sqrt(noise2)`` (a softened inverse variance: on tracked takes full
    inverse-variance weights lean on too few points). It starts from the fit of the
    seeds onto ``ref`` (the previous pass only chose them), or of all usable points
    where fewer than 3 seeds exist. Returns the transforms and whether ``tick`` cancelled."""
    F, P = X.shape[:2]
    keep = np.zeros((1, P), bool)
    keep[0, seed] = True
    Xc = np.where(usable[None, :, None], X, np.nan)
    Y = X[:, seed]
    R, t, ok = _weighted_kabsch(Y, np.broadcast_to(ref[seed], Y.shape), np.ones(Y.shape[:2]))
    T = _to4(R, t)
    T[~ok] = np.nan
    bad = ~ok
    if bad.any():
        R, t, ok = _weighted_kabsch(Xc[bad], np.broadcast_to(ref, Xc[bad].shape),
                                    np.ones(Xc[bad].shape[:2]))
        T0 = _to4(R, t)
        T0[~ok] = np.nan
        T[bad] = T0
    valid = np.isfinite(T).all((1, 2))
    S = apply_transforms(T, Xc)
    last = np.inf
    for _ in range(int(params.max_processing_iterations)):
        d2 = ((S - ref) ** 2).sum(-1)
        # a point is judged against its own noise: the stable points of a frame are the
        # ones closest to the shape in units of their usual residual
        sel = d2 if noise2 is None else d2 / noise2
        stable = _stable_mask(sel, params.stable_points_percent, keep) & valid[:, None]
        with np.errstate(invalid="ignore"):
            err = float(np.sqrt(d2[stable].mean())) if stable.any() else np.nan
        if not np.isfinite(err) or last - err <= params.tolerance * max(err, 1e-3):
            break
        last = err
        step = _block_step(S, ref, stable if noise2 is None else stable / np.sqrt(noise2))
        dT = _to4(rodrigues_to_matrix(step[:, :3]), step[:, 3:])
        T = np.where(valid[:, None, None], dT @ T, T)
        S = apply_transforms(T, Xc)
        if tick is not None and tick(0, 0) is False:
            return T, True
    return T, False


def stabilise_auto(positions: ArrayLike, *, params: StabilizationParameters | None = None,
                   candidates: NDArray[np.bool_] | None = None, first: int = 0,
                   progress: Progress = None) -> StabilisationResult:
    """Stabilize Data [Automatic]: choose the stable set and the base frame, and fit every
    frame to the take's mean stabilised shape.

    Parameters
    ----------
    positions : array_like, shape (F, P, 3)
        Raw positions (mm), NaN where missing.
    params : StabilizationParameters, optional
        Stable Points Percent, Max Processing Iterations (per pass) and the tolerance
        are used; the Base Frame and Inter Frame Weightings only weight the reported
        stabilisation error (the fit has no inter-frame term: see Notes).
    candidates : ndarray of bool, shape (P,), optional
        Columns that may be stable (the caller leaves the brim out unless Use Brim
        Points).
    first : int
        Unused by the algorithm; kept for callers that report frame numbers.
    progress : callable, optional
        ``progress(iteration, total)``; False stops (the last iterate is returned,
        ``cancelled``).

    Returns
    -------
    StabilisationResult
        ``points`` is the final seed set, ``base_frame`` the chosen frame (its transform
        is exactly the identity).

    Raises
    ------
    ValueError
        Fewer than 3 points present in half of the frames, or no frame that could be
        stabilised.

    Notes
    -----
    The fit minimises the base-frame term alone, to the mean shape rather than to one
    frame. An inter-frame term over trimmed per-frame sets pulls each frame towards its
    neighbours' stable points, and those include points that move with expression
    between the two frames, so it drags the transforms along with the expression; with
    a dozen or more stable points per frame the per-frame fits need no smoothing.
    """
    p = params or StabilizationParameters()
    X = np.asarray(positions, np.float64)
    if X.ndim != 3 or X.shape[-1] != 3:
        raise ValueError(f"positions must have shape (F, P, 3), got {X.shape}")
    F, P = X.shape[:2]
    cand = np.ones(P, bool) if candidates is None else np.asarray(candidates, bool)
    first_seed = choose_stable_points(X, fraction=0.0, candidates=cand,
                                      min_points=AUTO_FIRST_SEEDS)
    seed = first_seed[:AUTO_SEEDS]
    T = _procrustes(X, seed)
    fit = replace(p, inter_frame_weighting=0.0, base_frame_weighting=1.0)
    total = AUTO_PASSES * int(p.max_processing_iterations)
    done = 0
    cancelled = False

    def tick(_a: int, _b: int) -> bool:
        nonlocal done
        done += 1
        return progress is None or progress(min(done, total), total) is not False

    present = np.isfinite(X[..., 0]).mean(0) >= 0.5
    noise2 = None
    for k in range(AUTO_PASSES):
        S = apply_transforms(T, X)
        shape = _mean_shape(S)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            spread = np.sqrt(np.nanmean(((S - shape) ** 2).sum(-1), axis=0))
        ok = cand & present & np.isfinite(shape).all(-1) & np.isfinite(spread)
        if ok.sum() < 3:
            break
        # as an artist would: the points that moved least once stabilised are the seeds
        seed = np.argsort(np.where(ok, spread, np.inf), kind="stable")[:AUTO_SEEDS]
        seed = seed[ok[seed]]
        if k > 0:
            noise2 = _residual_scale(S, shape, cand, p.stable_points_percent)
        T, cancelled = _fit_to_shape(X, seed, shape, cand & np.isfinite(shape).all(-1),
                                     fit, tick, noise2)
        if cancelled:
            break
    valid = np.isfinite(T).all((1, 2))
    if not valid.any():
        raise ValueError("no frame has 3 stable points; the take cannot be stabilised")
    base = choose_base_frame(X, first_seed)
    if not valid[base]:
        counts = np.where(valid, np.isfinite(X[..., 0]).sum(1), -1)
        base = int(np.argmax(counts))
    # express everything relative to the base frame: T_b^-1 T_f (rigid, exact inverse)
    Rb, tb = T[base, :3, :3], T[base, :3, 3]
    inv = _to4(Rb.T, -Rb.T @ tb)
    T = inv @ T
    T[base] = np.eye(4)
    T[~valid] = np.nan
    S = apply_transforms(T, X)
    ref = _mean_shape(S)
    keep = np.zeros((1, P), bool)
    keep[0, seed] = True
    Sc = np.where(cand[None, :, None], S, np.nan)
    stable = _stable_mask(((Sc - ref) ** 2).sum(-1), p.stable_points_percent, keep)
    b_err, i_err, err = stabilisation_errors(S, base, stable, p.base_frame_weighting,
                                             p.inter_frame_weighting)
    log.debug("automatic stabilisation: base frame %d, seeds %s", base, seed.tolist())
    return StabilisationResult(T, int(base), np.sort(seed).astype(np.intp), stable, b_err,
                               i_err, err, done, cancelled)
