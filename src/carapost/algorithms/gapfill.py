"""Gap filling of 3D marker trajectories, with a measured quality for every filled sample.

Arrays in, arrays out: :func:`fill_gaps` takes the positions of all points over a take
(``(F, P, 3)`` mm), the samples to fill and the samples it may read, and returns the
filled positions, the estimated error of each filled sample and a table of the gaps.
Methods (module :mod:`carapost.algorithms.gapfill_methods`, all in the head frame):

``guide``
    The reference workflow's neighbour prediction: the point's last known position plus
    how its neighbours moved since then, forwards from the frame before the gap and
    backwards from the frame after, blended linearly across the gap
    (Use Forwards / Backwards Prediction).
``lowrank``
    Low-rank completion of the frames x (points x 3) matrix (Gløersen & Federolf 2016),
    iterated; its offset to the data at the gap's ends is blended out as for ``guide``.
``spline``
    A cubic Hermite through the samples beside the gap, for very short gaps.
``auto``
    For each gap, a *hold-out self-test*: stretches of the same length of the same
    point, where it is known, near the gap, are hidden and filled with every method
    that applies; the method with the lowest RMS error there fills the gap, and the
    per-frame RMS error over those stretches is the estimated error of each filled
    sample (``sigma``, mm, the 3D distance). Every method gets this estimate.

A gap is a run of samples to fill. Its anchors are the known samples just before and
just after it; a gap at the start or end of the data has one anchor and is filled
one-sided (``guide`` and ``lowrank`` only) unless ``fill_ends`` is off. Where the
single-sensor option is on and a filled sample has one camera ray (one attached
detection), the filled point is moved to the nearest point of that ray, so it
re-projects onto the detection's centre.

Gaps that cannot be filled are left as they are, each with a message: no anchor on an
allowed side, longer than ``max_gap_frames``, a point known in too few frames for the
method.

Examples
--------
>>> t = np.arange(200) / 100.0
>>> base = np.stack([np.sin(2 * t), np.cos(3 * t), 0.5 * t], -1) * 10   # head motion
>>> X = np.stack([base + [20.0 * i, 5.0 * (i % 2), 0.0] for i in range(5)], 1)
>>> fill = np.zeros((200, 5), bool)
>>> fill[80:110, 2] = True
>>> out = fill_gaps(X, fill, params=GapFillParameters(method="guide"))
>>> float(np.abs(out.positions[80:110, 2] - X[80:110, 2]).max()) < 1e-9
True
>>> str(out.gaps.method[0]), bool(out.filled[80:110, 2].all())
('guide', True)
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms import _gapfill_jit as _jit
from carapost.algorithms.gapfill_methods import (
    gap_samples,
    guide_fill,
    head_frame,
    lowrank_fill,
    neighbour_table,
    spline_fill,
)
from carapost.algorithms.params import param, validate

log = logging.getLogger("carapost.gapfill")

__all__ = ["CLEAN_UP", "GAP_FILLING", "METHODS", "GapFill", "GapFillParameters", "GapTable",
           "fill_gaps", "runs"]

#: Properties sections (display names): the reference guide's, and our own.
GAP_FILLING = "Gap-Filling Parameters"
CLEAN_UP = "Clean-up Parameters"
#: Fill methods; ``auto`` chooses one per gap by the hold-out self-test.
METHODS = ("auto", "guide", "lowrank", "spline")
#: Candidates of auto: besides the methods, "mix" (mean of guide and spline) and "cubic"
#: (the local cubic of the trajectory in the capture frame, no neighbours: for data whose
#: markers do not move with their neighbours, such as a body's).
_SINGLE = ("guide", "lowrank", "spline", "mix", "cubic")

Progress = Callable[[int, int], bool] | None


@dataclass(frozen=True)
class GapFillParameters:
    """Parameters of :func:`fill_gaps`: the Gap-Filling Parameters section, and ``method``,
    ``max_gap_frames``, ``fill_ends`` from the Clean-up Parameters section
    (:class:`carapost.algorithms.cleanup.CleanupParameters`)."""

    overwrite_existing_filled_gaps: bool = param(
        False, label="Overwrite Existing Filled Gaps", section=GAP_FILLING,
        help="Recompute samples filled earlier (interpolated); off leaves earlier fills "
             "alone.")
    use_forwards_prediction: bool = param(
        True, label="Use Forwards Prediction", section=GAP_FILLING,
        help="Predict forwards from the known sample before each gap.")
    use_backwards_prediction: bool = param(
        True, label="Use Backwards Prediction", section=GAP_FILLING,
        help="Predict backwards from the known sample after each gap.")
    allow_single_sensor_gap_filling: bool = param(
        True, label="Allow Single Sensor Tracking Gap-Filling", section=GAP_FILLING,
        help="Where one camera still has a detection attached, put the filled point on "
             "that detection's ray.")
    # set from the Clean-up Parameters section (carapost.algorithms.cleanup)
    method: str = param("guide", key="gap_fill_method", choices=METHODS)
    max_gap_frames: int = param(0, min=0, max=10_000_000)
    fill_ends: bool = param(True)
    spline_max_frames: int = param(10, min=1, max=10_000)
    neighbours: int = param(6, min=1, max=64)
    holdouts: int = param(4, min=0, max=32)
    holdout_search: int = param(24, min=1, max=1000)
    holdout_budget: int = param(1_500_000, min=1, max=10**12)
    min_known_frames: int = param(2, min=1, max=1_000_000)
    lowrank_min_known: int = param(20, min=2, max=1_000_000)
    lowrank_energy: float = param(0.99, min=0.5, max=1.0)
    lowrank_max_rank: int = param(60, min=1, max=1000)
    lowrank_iterations: int = param(3, min=1, max=100)
    lowrank_test_rounds: int = param(4, min=1, max=32)
    lowrank_rounds_max_samples: int = param(2_000_000, min=0, max=10**12)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class GapTable:
    """One row per gap (runs of samples to fill), in point-then-frame order.

    Attributes
    ----------
    point, start, end : ndarray of int, shape (G,)
        Column and inclusive frame span (frames of the arrays given to `fill_gaps`).
    method : ndarray of str, shape (G,)
        Method that filled it, or "" for a gap left unfilled.
    estimate_mm : ndarray of float, shape (G,)
        RMS of the estimated error over the gap (mm); NaN if unknown or unfilled.
    holdouts : ndarray of int, shape (G,)
        Stretches the self-test could use.
    status : list of str
        "" or why the gap was left (or how it was filled, e.g. one-sided).
    errors : dict
        Method -> hold-out RMS error per gap (mm, NaN where it did not apply).
    """

    point: NDArray[np.intp]
    start: NDArray[np.intp]
    end: NDArray[np.intp]
    method: NDArray[np.str_]
    estimate_mm: NDArray[np.float64]
    holdouts: NDArray[np.intp]
    status: list[str]
    errors: dict[str, NDArray[np.float64]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.point)

    @property
    def length(self) -> NDArray[np.intp]:
        """Frames per gap."""
        return self.end - self.start + 1


@dataclass
class GapFill:
    """The outcome of :func:`fill_gaps`.

    Attributes
    ----------
    positions : ndarray, shape (F, P, 3) float64
        Filled positions (mm) at ``filled``, NaN elsewhere.
    filled : ndarray, shape (F, P) bool
    sigma : ndarray, shape (F, P) float32
        Estimated error (mm, 3D distance RMS) of each filled sample; NaN elsewhere or
        where the self-test had no stretch to test on.
    gaps : GapTable
    messages : list of str
        One line per kind of gap left unfilled (for the log and the caller).
    cancelled : bool
    """

    positions: NDArray[np.float64]
    filled: NDArray[np.bool_]
    sigma: NDArray[np.float32]
    gaps: GapTable
    messages: list[str]
    cancelled: bool = False


def nknown_all(known: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Known samples per point, shape (P,)."""
    return known.sum(0)


def runs(mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Runs of True in each column of a (F, P) mask: (column, start, end), inclusive,
    ordered by column then frame.

    Examples
    --------
    >>> m = np.array([[0, 1], [1, 1], [1, 0], [0, 1]], bool)
    >>> [a.tolist() for a in runs(m)]
    [[0, 1, 1], [1, 0, 3], [2, 1, 3]]
    """
    F, P = mask.shape
    pad = np.zeros((F + 2, P), np.int8)
    pad[1:-1] = mask
    d = np.diff(pad, axis=0).T                # (P, F+1)
    ps, ss = np.nonzero(d == 1)
    pe, ee = np.nonzero(d == -1)
    return ps.astype(np.intp), ss.astype(np.intp), (ee - 1).astype(np.intp)


def _holdouts(known: NDArray[np.bool_], point: NDArray, start: NDArray, end: NDArray,
              n: int, search: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Up to ``n`` stretches per gap of the same length of the same point, fully known
    with two known samples either side, nearest the gap first.

    Returns (gap index, start frame) of each hold-out stretch.
    """
    F = known.shape[0]
    if n == 0 or not len(point):
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    L = end - start + 1
    j = np.arange(1, search + 1)
    order = np.stack([j, -j], 1).reshape(-1)                  # +1, -1, +2, -2, ...
    cand = start[:, None] + order[None] * (L[:, None] + 3)    # (G, 2J)
    lo = cand - 2
    hi = cand + L[:, None] + 1
    inside = (lo >= 0) & (hi < F)
    csum = np.concatenate([np.zeros((1, known.shape[1]), np.int64),
                           np.cumsum(known, axis=0, dtype=np.int64)])
    p = np.broadcast_to(point[:, None], cand.shape)
    loc, hic = np.clip(lo, 0, F), np.clip(hi + 1, 0, F)
    full = (csum[hic, p] - csum[loc, p]) == (hi - lo + 1)
    ok = inside & full
    take = ok & (np.cumsum(ok, axis=1) <= n)
    g, col = np.nonzero(take)
    return g.astype(np.intp), cand[g, col].astype(np.intp)


def _ends_blend(fit: NDArray, Y: NDArray, point: NDArray, start: NDArray, end: NDArray,
                left: NDArray, right: NDArray) -> NDArray:
    """Low-rank fit of each gap sample plus its offset to the data at the anchors, blended
    linearly across the gap (one-sided: the one offset)."""
    if not len(point):
        return np.zeros((0, 3))
    return _jit.ends_blend(np.ascontiguousarray(fit), np.ascontiguousarray(Y),
                           *(np.ascontiguousarray(a, np.int64) for a in (point, start, end)),
                           *(np.ascontiguousarray(a, np.bool_) for a in (left, right)))


def _method_fills(name: str, Y: NDArray, known: NDArray, point: NDArray, start: NDArray,
                  end: NDArray, left: NDArray, right: NDArray, nb: NDArray, nbw: NDArray,
                  fit: NDArray | None, world: tuple[NDArray, NDArray, NDArray] | None = None
                  ) -> NDArray:
    if name == "cubic":
        assert world is not None
        Xw, R, t = world
        g, f = gap_samples(start, end)
        # context grows with the gap: 3 samples a side for the shortest, up to 20
        L = end - start + 1
        side = np.select([L <= 5, L <= 15, L <= 40], [3, 6, 12], 20)
        x = np.full((len(g), 3), np.nan)
        for sd in np.unique(side):
            sel = side == sd
            x[sel[g]] = spline_fill(Xw, known, point[sel], start[sel], end[sel], left[sel],
                                    right[sel], side=int(sd))
        return np.einsum("sji,sj->si", R[f], x - t[f])          # to the head frame
    if name == "guide":
        return guide_fill(Y, known, point, start, end, left, right, nb, nbw)
    if name == "spline":
        return spline_fill(Y, known, point, start, end, left, right, nb, nbw)
    if name == "mix":
        return 0.5 * (guide_fill(Y, known, point, start, end, left, right, nb, nbw)
                      + spline_fill(Y, known, point, start, end, left, right, nb, nbw))
    assert fit is not None
    return _ends_blend(fit, Y, point, start, end, left, right)


def _rms_per_gap(err2: NDArray, g: NDArray, n_gaps: int) -> NDArray:
    s = np.bincount(g, weights=np.nan_to_num(err2, nan=0.0), minlength=n_gaps)
    c = np.bincount(g, weights=np.isfinite(err2).astype(float), minlength=n_gaps)
    bad = np.bincount(g, weights=(~np.isfinite(err2)).astype(float), minlength=n_gaps)
    with np.errstate(all="ignore"):
        out = np.sqrt(s / c)
    out[(c == 0) | (bad > 0)] = np.nan
    return out


def fill_gaps(positions: NDArray, fill: NDArray[np.bool_], known: NDArray[np.bool_] | None = None,
              *, params: GapFillParameters | None = None,
              rays: tuple[NDArray, NDArray] | None = None,
              labels: list[str] | None = None, progress: Progress = None) -> GapFill:
    """Fill the gaps of point trajectories.

    Parameters
    ----------
    positions : ndarray, shape (F, P, 3)
        Positions (mm) of every point, NaN where none; points not to fill serve as
        neighbours.
    fill : ndarray, shape (F, P) bool
        Samples to fill (their current positions are ignored).
    known : ndarray, shape (F, P) bool, optional
        Samples the methods may read (default: finite and not in ``fill``).
    params : GapFillParameters, optional
    rays : (origins, directions), each (F, P, 3), optional
        The one camera ray of a sample to fill that has exactly one attached detection
        (NaN elsewhere); used when ``allow_single_sensor_gap_filling``.
    labels : list of str, optional
        Point names for the messages (default "point <column>").
    progress : callable, optional
        ``progress(done, total)``; False cancels (nothing is filled).

    Returns
    -------
    GapFill
    """
    prm = params or GapFillParameters()
    X = np.asarray(positions, dtype=np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"positions must have shape (F, P, 3), got {X.shape}")
    F, P, _ = X.shape
    fill = np.asarray(fill, bool)
    if fill.shape != (F, P):
        raise ValueError(f"fill must have shape {(F, P)}, got {fill.shape}")
    finite = np.isfinite(X).all(-1)
    kn = (finite & ~fill) if known is None else (np.asarray(known, bool) & finite & ~fill)
    names = labels or [f"point {i}" for i in range(P)]
    total = 6

    def tick(i: int) -> bool:
        return progress is None or progress(i, total) is not False

    point, start, end = runs(fill)
    G = len(point)
    F_ = F - 1
    left = (start > 0) & kn[np.clip(start - 1, 0, F_), point]
    right = (end < F_) & kn[np.clip(end + 1, 0, F_), point]
    status = [""] * G
    usable = np.ones(G, bool)

    def refuse(mask: NDArray, why: str) -> None:
        nonlocal usable
        new = mask & usable
        if new.any():
            for i in np.flatnonzero(new):
                status[i] = why
            pts = sorted({names[i] for i in point[new]})
            shown = ", ".join(pts[:5]) + (f" and {len(pts) - 5} more" if len(pts) > 5 else "")
            messages.append(f"{int(new.sum())} gap(s) left unfilled: {why} ({shown})")
        usable &= ~mask

    messages: list[str] = []
    nknown = kn.sum(0)
    refuse(nknown[point] < prm.min_known_frames,
           f"the point has fewer than {prm.min_known_frames} known samples")
    refuse(~(left | right), "no known sample on either side")
    if not prm.use_forwards_prediction and not prm.use_backwards_prediction:
        refuse(np.ones(G, bool), "Use Forwards Prediction and Use Backwards Prediction are "
                                 "both off")
    left &= prm.use_forwards_prediction
    right &= prm.use_backwards_prediction
    refuse(~(left | right), "its only known side is switched off (Use Forwards/Backwards "
                            "Prediction)")
    if prm.max_gap_frames:
        refuse((end - start + 1) > prm.max_gap_frames,
               f"longer than Max Gap Length ({prm.max_gap_frames} frames)")
    if not prm.fill_ends:
        refuse(~(left & right), "at the start or end of the data (Fill Take Ends is off)")
    if not tick(0):
        return _empty(F, P, point, start, end, status, messages, cancelled=True)

    # the head's motion from at most 64 of the most-seen points: as good a rigid fit,
    # a fraction of the work on takes with hundreds of points
    best = np.sort(np.argsort(-nknown_all(kn))[:64])
    kb = kn[:, best]
    Rh, th, _ = head_frame(np.where(kb[..., None], X[:, best], 0.0), kb, zeroed=True)
    # float32 storage halves the memory traffic of the gathers (1.5e-5 mm at 200 mm)
    kn = np.ascontiguousarray(kn)
    Y = _jit.to_head32(np.ascontiguousarray(X), kn, np.ascontiguousarray(Rh),
                       np.ascontiguousarray(th))
    nb, nbw = neighbour_table(Y, kn, prm.neighbours)
    # the capture-frame data, for auto's "cubic" candidate only
    world = ((_jit.to_head32(np.ascontiguousarray(X), kn, np.tile(np.eye(3), (F, 1, 1)),
                             np.zeros((F, 3))), Rh, th)
             if prm.method == "auto" else None)
    if not tick(1):
        return _empty(F, P, point, start, end, status, messages, cancelled=True)

    want = prm.method
    methods = list(_SINGLE) if want == "auto" else [want]
    need_test = want == "auto" or prm.holdouts > 0
    L = end - start + 1
    # which methods may fill which gap
    can = {
        "guide": usable.copy(),
        "spline": usable & left & right & ((L <= prm.spline_max_frames) | (want == "spline")),
        "lowrank": usable & (nknown[point] >= prm.lowrank_min_known) & (P >= 3),
    }
    can["mix"] = can["spline"] & (want == "auto")
    can["cubic"] = usable & left & right & (want == "auto")
    if want == "spline":
        refuse(~can["spline"], "the spline needs known samples on both sides")
    if want == "lowrank":
        refuse(~can["lowrank"], f"the low-rank method needs {prm.lowrank_min_known} known "
                                "samples of the point and 3 points")
    for m in can:
        can[m] &= usable

    # the self-test's work grows with the stretches tested: on big takes fewer per gap
    n_fill = int((L * usable).sum())
    n_hold = min(prm.holdouts, max(1, prm.holdout_budget // max(n_fill, 1)))
    hg, hs = (_holdouts(kn, point, start, end, n_hold, prm.holdout_search)
              if need_test else (np.zeros(0, np.intp), np.zeros(0, np.intp)))
    keep = usable[hg]
    hg, hs = hg[keep], hs[keep]
    hp, he = point[hg], hs + L[hg] - 1
    hl, hr = left[hg], right[hg]
    hgs, hfs = gap_samples(hs, he)
    truth = Y[hfs, hp[hgs]]

    fits: dict[str, NDArray | None] = {}
    if "lowrank" in methods and can["lowrank"].any():
        big = F * P > prm.lowrank_rounds_max_samples
        fit_r = None
        if len(hg):
            # hidden in rounds (the k-th stretch of every gap together), so that the test
            # does not hide much more of a point than its gap does; one round on big takes
            rounds = max(1, min(prm.holdouts, 1 if big else prm.lowrank_test_rounds))
            rank_in_gap = np.arange(len(hg)) - np.searchsorted(hg, hg)
            h_round = rank_in_gap % rounds
            test = np.full((len(hgs), 3), np.nan)
            for r in range(rounds):
                sel = h_round == r
                if not sel.any():
                    continue
                hidden = np.zeros((F, P), bool)
                smp = sel[hgs]
                hidden[hfs[smp], hp[hgs[smp]]] = True
                fit_r = lowrank_fill(Y, kn, hidden | fill, energy=prm.lowrank_energy,
                                     max_rank=prm.lowrank_max_rank,
                                     outer=prm.lowrank_iterations)
                test[smp] = _ends_blend(fit_r, Y, hp[sel], hs[sel], he[sel], hl[sel], hr[sel])
            fits["test"] = test
        if not tick(2):
            return _empty(F, P, point, start, end, status, messages, cancelled=True)
        if big and fit_r is not None:
            # a very big take: the test's completion (fills and stretches hidden) also
            # fills the gaps, instead of a second completion of the whole matrix
            fits["lowrank"] = fit_r
        else:
            fits["lowrank"] = lowrank_fill(Y, kn, fill, energy=prm.lowrank_energy,
                                           max_rank=prm.lowrank_max_rank,
                                           outer=prm.lowrank_iterations)
    if not tick(3):
        return _empty(F, P, point, start, end, status, messages, cancelled=True)

    # the self-test: every method on the hold-out stretches
    errors: dict[str, NDArray] = {}
    err_samples: dict[str, NDArray] = {}
    hold_pred: dict[str, NDArray] = {}
    nhold = np.bincount(hg, minlength=G)
    for m in methods:
        if not can[m].any():
            errors[m] = np.full(G, np.nan)
            continue
        if m == "lowrank" and "test" not in fits:
            errors[m] = np.full(G, np.nan)
            continue
        if m == "lowrank":
            pred = fits["test"]
        elif m == "mix" and "guide" in hold_pred and "spline" in hold_pred:
            pred = 0.5 * (hold_pred["guide"] + hold_pred["spline"])
        else:
            pred = _method_fills(m, Y, kn, hp, hs, he, hl, hr, nb, nbw, None, world)
        hold_pred[m] = pred
        e = np.linalg.norm(pred - truth, axis=-1)
        err_samples[m] = e
        per_hold = _rms_per_gap(e**2, hgs, len(hg))
        s = np.bincount(hg, weights=np.nan_to_num(per_hold**2), minlength=G)
        bad = np.bincount(hg, weights=(~np.isfinite(per_hold)).astype(float), minlength=G)
        with np.errstate(all="ignore"):
            errors[m] = np.sqrt(s / nhold)
        errors[m][(nhold == 0) | (bad > 0) | ~can[m]] = np.nan
    if not tick(4):
        return _empty(F, P, point, start, end, status, messages, cancelled=True)

    # choose per gap
    chosen = np.full(G, "", dtype=object)
    if want == "auto":
        score = np.stack([np.where(np.isfinite(errors[m]), errors[m], np.inf)
                          for m in _SINGLE], 1)
        best = np.argmin(score, 1)
        has = np.isfinite(score).any(1)
        pick = np.array(_SINGLE, dtype=object)[best]
        chosen[:] = np.where(has, pick, "guide")
    else:
        chosen[:] = want
    chosen[~usable] = ""

    # a safeguard for auto: the global method can go wrong where the data near a gap are
    # odd (an outlier pulls a component). The local neighbour prediction is the
    # reference: a low-rank fill far from it, by much more than the two local methods
    # (neighbours, spline) differ from each other, is not trusted and the neighbour
    # prediction fills the gap.
    alt = np.flatnonzero(chosen == "lowrank")
    if want == "auto" and len(alt):
        args = (point[alt], start[alt], end[alt], left[alt], right[alt])
        ga, _ = gap_samples(start[alt], end[alt])
        gp = guide_fill(Y, kn, *args, nb, nbw)
        sp = spline_fill(Y, kn, *args, nb, nbw)
        lr = _method_fills("lowrank", Y, kn, *args, nb, nbw, fits.get("lowrank"))

        def dist(u: NDArray, v: NDArray) -> NDArray:
            return _rms_per_gap(np.sum((u - v) ** 2, -1), ga, len(alt))

        spread = np.maximum(2.0, 3.0 * dist(gp, sp))
        far = dist(lr, gp) > spread                               # NaN compares False
        chosen[alt[far]] = "guide"

    out = np.full((F, P, 3), np.nan)
    sigma = np.full((F, P), np.nan, np.float32)
    filled = np.zeros((F, P), bool)
    gs, fs = gap_samples(start, end)
    for m in _SINGLE:
        sel = chosen == m
        if not sel.any():
            continue
        idx = np.flatnonzero(sel)
        pred = _method_fills(m, Y, kn, point[idx], start[idx], end[idx], left[idx],
                             right[idx], nb, nbw, fits.get("lowrank"), world)
        g2, f2 = gap_samples(start[idx], end[idx])
        gg = idx[g2]
        p2 = point[gg]
        okp = np.isfinite(pred).all(-1)
        y = pred
        # back to the capture frame
        x = np.einsum("sij,sj->si", Rh[f2], y) + th[f2]
        out[f2[okp], p2[okp]] = x[okp]
        filled[f2[okp], p2[okp]] = True
        # per-sample estimate: RMS over the hold-outs at the same offset into the gap
        if m in err_samples and len(hg):
            e = err_samples[m]
            hoff = hfs - hs[hgs]
            key_h = hg[hgs] * (int(L.max()) + 1) + hoff
            ssum = np.bincount(key_h, weights=np.nan_to_num(e**2),
                               minlength=G * (int(L.max()) + 1))
            scnt = np.bincount(key_h, weights=np.isfinite(e).astype(float),
                               minlength=G * (int(L.max()) + 1))
            key = gg * (int(L.max()) + 1) + (f2 - start[gg])
            with np.errstate(all="ignore"):
                est = np.sqrt(ssum[key] / scnt[key])
            sigma[f2[okp], p2[okp]] = est[okp]
    if rays is not None and prm.allow_single_sensor_gap_filling:
        o, d = (np.asarray(a, np.float64) for a in rays)
        has_ray = filled & np.isfinite(o).all(-1) & np.isfinite(d).all(-1)
        if has_ray.any():
            oo, dd = o[has_ray], d[has_ray]
            dd = dd / np.linalg.norm(dd, axis=-1, keepdims=True)
            xx = out[has_ray]
            out[has_ray] = oo + dd * np.einsum("si,si->s", xx - oo, dd)[:, None]
    est = np.full(G, np.nan)
    for m in _SINGLE:
        sel = chosen == m
        if sel.any() and m in errors:
            est[sel] = errors[m][sel]
    unfilled = usable & ~np.bincount(gs, weights=filled[fs, point[gs]], minlength=G).astype(bool)
    for i in np.flatnonzero(unfilled):
        status[i] = status[i] or "the method could not fill it"
        chosen[i] = ""
    for i in np.flatnonzero(usable & ~(left & right)):
        status[i] = status[i] or "one-sided"
    tick(total)
    table = GapTable(point, start, end, chosen.astype(str), est, nhold.astype(np.intp),
                     status, errors)
    return GapFill(out, filled, sigma, table, messages)


def _empty(F: int, P: int, point: NDArray, start: NDArray, end: NDArray, status: list[str],
           messages: list[str], cancelled: bool = False) -> GapFill:
    G = len(point)
    table = GapTable(point, start, end, np.full(G, "", dtype=str), np.full(G, np.nan),
                     np.zeros(G, np.intp), status)
    return GapFill(np.full((F, P, 3), np.nan), np.zeros((F, P), bool),
                   np.full((F, P), np.nan, np.float32), table, messages, cancelled)
