"""Trajectory clean-up: zero-phase low-pass filtering, spike and identity-swap detection.

Arrays in, arrays out, like :mod:`carapost.algorithms.gapfill`:

- :func:`lowpass` filters each point's trajectory with a zero-phase Butterworth low-pass
  (``scipy.signal.butter`` + ``sosfiltfilt``) separately over every run of known
  samples, so the filter never reaches across a gap and never invents samples.
- :func:`find_spikes` finds samples that disagree with the point's own motion and its
  neighbours': in the head frame (the head's rigid motion removed, see
  :func:`carapost.algorithms.gapfill_methods.head_frame`) a spike stands out from the
  running median of its 5-frame window by more than ``spike_threshold_mm`` and by many
  times the point's usual deviation.
- :func:`find_swaps` finds two points whose positions exchange at a frame: in the head
  frame each one's position after the frame is where the other one was before it.

Examples
--------
>>> t = np.arange(400) / 100.0
>>> X = np.stack([np.stack([np.sin(t + i), np.cos(t), t], -1) * 10 + [30.0 * i, 0, 0]
...               for i in range(4)], 1)
>>> Y = X.copy(); Y[200, 1] += [6.0, 0, 0]             # a spike
>>> [(s.point, s.start, s.end) for s in find_spikes(Y)]
[(1, 200, 200)]
>>> Z = X.copy(); Z[250:, [0, 1]] = Z[250:, [1, 0]]     # points 0 and 1 swap at frame 250
>>> [(s.points, s.frame) for s in find_swaps(Z)]
[((0, 1), 250)]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.gapfill import CLEAN_UP, METHODS
from carapost.algorithms.gapfill_methods import head_frame, to_head
from carapost.algorithms.params import param, validate

__all__ = ["CleanupParameters", "FilterParameters", "ProblemParameters", "Spike", "Swap",
           "find_spikes", "find_swaps", "lowpass"]


@dataclass(frozen=True)
class CleanupParameters:
    """The Clean-up Parameters section (ours): gap-filling method and limits, Filter
    Trajectories and Find Problems. The algorithms read these through their own
    parameter classes (:class:`~carapost.algorithms.gapfill.GapFillParameters`,
    :class:`FilterParameters`, :class:`ProblemParameters`), which take the same keys."""

    gap_fill_method: str = param(
        "guide", label="Gap-Filling Method", section=CLEAN_UP, choices=METHODS,
        help="guide (default, the reference workflow's): neighbour prediction; auto "
             "(recommended for faces): per gap, the method with the lowest error on a "
             "hold-out test near it, with an estimated error per sample; lowrank: "
             "all-marker correlations; spline: short gaps.")
    max_gap_frames: int = param(
        0, label="Max Gap Length", section=CLEAN_UP, unit="frames", min=0, max=10_000_000,
        help="Longer gaps are left unfilled; 0 fills every gap. Default is our choice.")
    fill_ends: bool = param(
        True, label="Fill Take Ends", section=CLEAN_UP,
        help="Also fill runs at the start or end of the data, one-sided from the nearest "
             "known sample. Default is our choice.")
    filter_cutoff_hz: float = param(
        10.0, label="Filter Cut-off", section=CLEAN_UP, unit="Hz", min=0.0,
        min_exclusive=True, max=10_000.0,
        help="Filter Trajectories: Butterworth low-pass cut-off (below half the frame "
             "rate). Default is our choice.")
    filter_order: int = param(
        4, label="Filter Order", section=CLEAN_UP, min=1, max=12,
        help="Filter Trajectories: Butterworth order (run forwards and backwards, so the "
             "roll-off is twice this). Default is our choice.")
    spike_threshold_mm: float = param(
        2.0, label="Spike Threshold", section=CLEAN_UP, unit="mm", min=0.0,
        min_exclusive=True, max=1000.0,
        help="Find Problems: a sample further than this from its point's local motion is "
             "a spike. Default is our choice.")
    swap_min_jump_mm: float = param(
        3.0, label="Swap Minimum Jump", section=CLEAN_UP, unit="mm", min=0.0,
        min_exclusive=True, max=1000.0,
        help="Find Problems: two points must jump at least this far at the same frame to "
             "be a suspected swap. Default is our choice.")

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class FilterParameters:
    """Filter Trajectories (keys of the Clean-up Parameters section)."""

    filter_cutoff_hz: float = param(10.0, min=0.0, min_exclusive=True, max=10_000.0)
    filter_order: int = param(4, min=1, max=12)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class ProblemParameters:
    """Find Problems (keys of the Clean-up Parameters section, and internal tunables)."""

    spike_threshold_mm: float = param(2.0, min=0.0, min_exclusive=True, max=1000.0)
    swap_min_jump_mm: float = param(3.0, min=0.0, min_exclusive=True, max=1000.0)
    spike_robust_factor: float = param(8.0, min=1.0, max=100.0)
    swap_tolerance: float = param(0.35, min=0.01, max=1.0)
    max_spike_frames: int = param(2, min=1, max=10)
    recur_min: int = param(3, min=1, max=1000)
    recur_cos: float = param(0.8, min=-1.0, max=1.0)
    smooth_ratio: float = param(0.2, min=0.0, max=10.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass(frozen=True)
class Spike:
    """A spike: frames ``start .. end`` of column ``point``; ``size_mm`` its largest
    distance from the local motion."""

    point: int
    start: int
    end: int
    size_mm: float


@dataclass(frozen=True)
class Swap:
    """A suspected identity swap of the columns ``points`` from ``frame`` on; ``jump_mm``
    how far each jumped, ``mismatch_mm`` how far the exchange is from exact."""

    points: tuple[int, int]
    frame: int
    jump_mm: float
    mismatch_mm: float


def _runs1(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), (np.flatnonzero(d == -1) - 1).tolist(),
                    strict=True))


def lowpass(X: NDArray, rate_hz: float, params: FilterParameters | None = None,
            mask: NDArray[np.bool_] | None = None) -> tuple[NDArray, NDArray[np.bool_]]:
    """Zero-phase Butterworth low-pass of each trajectory, run by run.

    Parameters
    ----------
    X : ndarray, shape (F, P, 3)
        Positions (mm), NaN where none.
    rate_hz : float
        Frame rate.
    params : FilterParameters
    mask : ndarray, shape (F, P) bool, optional
        Samples that may be filtered (default: every finite sample); each run of
        consecutive such samples is filtered on its own.

    Returns
    -------
    out : ndarray, shape (F, P, 3)
        Filtered positions at the changed samples, the input elsewhere.
    changed : ndarray, shape (F, P) bool
        Samples filtered (runs of fewer than 4 samples are left as they are).

    Raises
    ------
    ValueError
        When the cut-off is not below half the frame rate.
    """
    from scipy.signal import butter, sosfiltfilt

    prm = params or FilterParameters()
    nyq = 0.5 * float(rate_hz)
    if not prm.filter_cutoff_hz < nyq:
        raise ValueError(f"the cut-off ({prm.filter_cutoff_hz:g} Hz) must be below half the "
                         f"frame rate ({nyq:g} Hz)")
    sos = butter(prm.filter_order, prm.filter_cutoff_hz / nyq, output="sos")
    pad_default = 3 * (2 * len(sos) + 1)
    X = np.asarray(X)
    out = np.array(X, dtype=np.float64)
    ok = np.isfinite(X).all(-1) if mask is None else (np.asarray(mask, bool)
                                                     & np.isfinite(X).all(-1))
    changed = np.zeros(ok.shape, bool)
    for p in range(X.shape[1]):
        for a, b in _runs1(ok[:, p]):
            n = b - a + 1
            if n < 4:
                continue
            out[a:b + 1, p] = sosfiltfilt(sos, out[a:b + 1, p], axis=0,
                                          padlen=min(pad_default, n - 1))
            changed[a:b + 1, p] = True
    return out, changed


def _head(X: NDArray) -> NDArray:
    known = np.isfinite(X).all(-1)
    R, t, _ = head_frame(np.where(known[..., None], X, 0.0), known)
    Y = to_head(np.where(known[..., None], X, 0.0), R, t)
    Y[~known] = np.nan
    return Y


def _running_median(y: NDArray, half: int = 2) -> NDArray:
    """Median of each sample's 2 half + 1 frame window (ignoring missing samples), y
    (F, p, 3); NaN where the sample itself is missing."""
    import warnings

    pad = np.pad(y, ((half, half), (0, 0), (0, 0)), constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1, axis=0)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win, axis=-1)
    med[~np.isfinite(y)] = np.nan
    return med


def _median_deviation(y: NDArray, half: int = 2) -> NDArray:
    """Distance of each sample of y (F, p, 3) from the median of its 2 half + 1 frame
    window (NaN where fewer than 4 of the window's samples exist)."""
    import warnings

    pad = np.pad(y, ((half, half), (0, 0), (0, 0)), constant_values=np.nan)
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1, axis=0)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(win, axis=-1)
        enough = np.isfinite(win[:, :, 0]).sum(-1) >= 4
    dev = np.linalg.norm(y - med, axis=-1)
    dev[~enough] = np.nan
    return dev


def find_spikes(X: NDArray, params: ProblemParameters | None = None,
                Y: NDArray | None = None) -> list[Spike]:
    """Spikes of every point (see the module). ``Y``: the head-frame positions, if
    already computed. Returns spikes ordered by point then frame.

    A sample is a spike when it stands out from the 5-frame running median both in its
    own head-frame trajectory (by ``spike_threshold_mm``) and in its offset from its
    neighbours (by ``spike_threshold_mm`` and ``spike_robust_factor`` robust standard
    deviations of that offset's usual deviation): fast expressions move the neighbours
    too, so the offset stays smooth where the trajectory alone does not.
    """
    from carapost.algorithms.gapfill_methods import neighbour_table

    prm = params or ProblemParameters()
    Y = _head(np.asarray(X, np.float64)) if Y is None else Y
    F, P, _ = Y.shape
    if F < 5:
        return []
    known = np.isfinite(Y[..., 0])
    nb, nbw = neighbour_table(Y, known, 6)
    # two passes: the second reads each neighbour with the samples the first flagged
    # replaced by its 5-frame running median, so that one point's spike does not make
    # the points around it look spiky
    flags = np.zeros((F, P), bool)
    for p0 in range(0, P, 32):
        flags[:, p0:p0 + 32] = _spike_flags(Y, Y, nb, nbw, p0, prm)[0]
    Yc = Y
    if flags.any():
        Yc = Y.copy()
        for p0 in range(0, P, 32):
            sub = flags[:, p0:p0 + 32]
            if sub.any():
                Yc[:, p0:p0 + 32][sub] = _running_median(Y[:, p0:p0 + 32])[sub]
    out: list[Spike] = []
    shapes: list[tuple[NDArray, float]] = []
    # the point's own history: its events at half the thresholds (start, deviation)
    history: dict[int, list[tuple[int, NDArray]]] = {}
    for p0 in range(0, P, 32):
        flag, dev_y, res, weak = _spike_flags(Y, Yc, nb, nbw, p0, prm)
        for j in range(flag.shape[1]):
            for a, b in _runs1(flag[:, j]):
                if b - a + 1 > prm.max_spike_frames:
                    continue
                vec, ratio = _event_shape(res[:, j], a, b)
                out.append(Spike(p0 + j, a, b, float(np.nanmax(dev_y[a:b + 1, j]))))
                shapes.append((vec, ratio))
            if flag[:, j].any():
                history[p0 + j] = [(a, _event_shape(res[:, j], a, b)[0])
                                   for a, b in _runs1(weak[:, j])
                                   if b - a + 1 <= 2 * prm.max_spike_frames]
    keep = ~_consistent_motion(out, shapes, history, prm)
    return [s for s, k in zip(out, keep, strict=True) if k]


def _spike_flags(Y: NDArray, Ynb: NDArray, nb: NDArray, nbw: NDArray, p0: int,
                 prm: ProblemParameters, block: int = 32
                 ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The spike test of points ``p0 .. p0 + block - 1``, their neighbours read from
    ``Ynb``: flags (F, p) bool, the deviation of the trajectories themselves (F, p) mm
    and the trajectories tested (F, p, 3): offsets from the neighbours, or the
    trajectories where there are no neighbours; and the flags at half the thresholds
    (F, p) bool."""
    import warnings

    y = Y[:, p0:p0 + block]
    dev_y = _median_deviation(y)
    if nb.shape[1]:
        q = nb[p0:p0 + block]                                       # (p, K)
        qq = np.maximum(q, 0)
        vals = Ynb[:, qq]                                           # (F, p, K, 3)
        w = np.where((q >= 0)[None] & np.isfinite(vals[..., 0]), nbw[p0:p0 + block][None],
                     0.0)
        sw = w.sum(-1)
        with np.errstate(all="ignore"):
            mean = np.einsum("fpk,fpki->fpi", w, np.nan_to_num(vals)) / sw[..., None]
        r = y - np.where((sw > 0)[..., None], mean, np.nan)
        dev = _median_deviation(r)
    else:
        r, dev = y, dev_y
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        scale = 1.4826 * np.nanmedian(dev, axis=0)
    thr = np.maximum(prm.spike_threshold_mm, prm.spike_robust_factor * np.nan_to_num(scale))
    flag = (np.nan_to_num(dev) > thr[None]) & (np.nan_to_num(dev_y) > prm.spike_threshold_mm)
    weak = ((np.nan_to_num(dev) > 0.5 * thr[None])
            & (np.nan_to_num(dev_y) > 0.5 * prm.spike_threshold_mm))
    return flag, dev_y, r, weak


def _event_shape(r: NDArray, a: int, b: int) -> tuple[NDArray, float]:
    """Deviation vector (3,) of a candidate spike (frames a..b of the trajectory r
    (F, 3)) from the straight line through the samples two frames outside it, and the
    share of that deviation already present one frame outside it (0 for a sample that
    leaves the trajectory and comes back, about one half for fast but smooth motion
    caught mid-way)."""
    F = len(r)
    lo, hi = a - 2, b + 2
    if lo < 0 or hi >= F or not (np.isfinite(r[lo]).all() and np.isfinite(r[hi]).all()):
        return np.full(3, np.nan), np.nan

    def base(t: int) -> NDArray:
        w = (t - lo) / (hi - lo)
        return (1 - w) * r[lo] + w * r[hi]

    seg = r[a:b + 1] - np.stack([base(t) for t in range(a, b + 1)])
    k = int(np.nanargmax(np.linalg.norm(seg, axis=-1)))
    vec = seg[k]
    size = float(np.linalg.norm(vec))
    side = max(float(np.linalg.norm(r[a - 1] - base(a - 1))),
               float(np.linalg.norm(r[b + 1] - base(b + 1))))
    return vec, side / size if size > 0 else np.nan


def _consistent_motion(spikes: list[Spike], shapes: list[tuple[NDArray, float]],
                       history: dict[int, list[tuple[int, NDArray]]],
                       prm: ProblemParameters) -> NDArray[np.bool_]:
    """Candidates that are the point's own fast but consistent motion (a blink), not
    spikes: the same deviation (direction within ``recur_cos``, size within a factor 3)
    recurs at ``recur_min`` or more other times in the point's history (its events at
    half the spike thresholds), and the motion passes through intermediate positions
    (``smooth_ratio`` of the deviation one frame outside it). A sample that jumps away
    and back, or a jump that does not recur, is kept."""
    out = np.zeros(len(spikes), bool)
    for i, (s, (v, ratio)) in enumerate(zip(spikes, shapes, strict=True)):
        if not ratio >= prm.smooth_ratio:                      # NaN: not smooth
            continue
        past = [(a, u) for a, u in history.get(s.point, [])
                if abs(a - s.start) > 2 * prm.max_spike_frames and np.isfinite(u).all()]
        if len(past) < prm.recur_min:
            continue
        U = np.array([u for _, u in past])
        size = float(np.linalg.norm(v))
        su = np.linalg.norm(U, axis=-1)
        with np.errstate(all="ignore"):
            cos = (U @ v) / (su * size)
            rel = su / size
        like = (cos > prm.recur_cos) & (rel > 1 / 3) & (rel < 3.0)
        out[i] = int(like.sum()) >= prm.recur_min
    return out


def find_swaps(X: NDArray, params: ProblemParameters | None = None,
               Y: NDArray | None = None, window: int = 3) -> list[Swap]:
    """Suspected identity swaps (see the module), ordered by frame.

    Around each frame where two or more points jump (head frame, medians of ``window``
    frames before and from the frame on), a pair is reported when each one's position
    after is within ``swap_tolerance`` of their separation from the other's position
    before.
    """
    prm = params or ProblemParameters()
    Y = _head(np.asarray(X, np.float64)) if Y is None else Y
    F, P, _ = Y.shape
    if F < 2 * window or P < 2:
        return []
    import warnings
    pad = np.pad(Y, ((window, window), (0, 0), (0, 0)), constant_values=np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        win = np.lib.stride_tricks.sliding_window_view(pad, window, axis=0)  # (F+w+1, P, 3, w)
        med = np.nanmedian(win, axis=-1)
    # before[f] = median of frames f-window .. f-1; after[f] = median of f .. f+window-1
    before = med[0:F]
    after = med[window:window + F]
    jump = np.linalg.norm(after - before, axis=-1)                # (F, P)
    cand = np.nan_to_num(jump) > prm.swap_min_jump_mm
    out: list[Swap] = []
    last: dict[tuple[int, int], int] = {}
    for f in np.flatnonzero(cand.sum(1) >= 2):
        pts = np.flatnonzero(cand[f])
        b, a = before[f, pts], after[f, pts]
        sep = np.linalg.norm(b[:, None] - b[None], axis=-1)
        cross = np.linalg.norm(a[:, None] - b[None], axis=-1)     # |after_i - before_j|
        mis = np.maximum(cross, cross.T)
        ok = (mis < prm.swap_tolerance * sep) & (sep > prm.swap_min_jump_mm)
        np.fill_diagonal(ok, False)
        for i, j in zip(*np.nonzero(np.triu(ok)), strict=True):
            pair = (int(pts[i]), int(pts[j]))
            # the medians see one swap over ``window`` frames: keep the frame where the
            # exchange is closest to exact
            prev = last.get(pair)
            item = Swap(pair, int(f), float(min(jump[f, pts[i]], jump[f, pts[j]])),
                        float(mis[i, j]))
            if prev is not None and f - out[prev].frame < 2 * window:
                if item.mismatch_mm < out[prev].mismatch_mm:
                    out[prev] = item
                continue
            last[pair] = len(out)
            out.append(item)
    return out
