"""The 2D noise of an observation from its blob's score and length.

The detector's score and the blob's semi-major axis against the same marker's in the
same camera around the frame say how far a blob's centre may be off: a marker merged
with something beside it, cut by an edge or blurred. `blob_noise_scale` turns them into
a factor of the observation's 2D noise, which multiplies
`carapost.algorithms.uncertainty.width_noise_scale` (docs/algorithms.md, "Per-sample
uncertainty").
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["LENGTH_NOISE", "SCORE_NOISE", "blob_noise_scale", "window_statistic"]

#: Factor of an observation's 2D noise by the detector's score of its blob
#: (`blob_noise_scale`, interpolated between the knots; 1 above the last). On the tuning
#: takes of other renderers (111,000 face observations, error against the truth
#: projection) the RMS error of blobs scored 0.99-0.995 was 2.2 times that of those
#: above 0.995, 2.9 at 0.97-0.98, 4 at 0.9-0.93, 5-6 below 0.8 (docs/benchmarks.md).
SCORE_NOISE = ((0.5, 0.8, 0.9, 0.95, 0.97, 0.98, 0.99, 0.995),
               (6.0, 5.0, 4.0, 3.3, 2.9, 2.6, 2.2, 1.0))
#: ... and by its semi-major axis over the lower quartile of the same point's in the
#: same camera over the frames around it: a blob longer than the marker's usual (merged
#: along one axis with something beside it) or shorter (cut by an edge). Same takes:
#: 2.5 times at 1.08-1.1, 3-3.5 above 1.15, 3 below 0.95.
LENGTH_NOISE = ((0.9, 0.95, 1.05, 1.08, 1.1, 1.15, 1.2),
                (3.0, 1.0, 1.0, 2.0, 2.5, 3.0, 3.5))
#: Half-window (frames) and fewest lengths in it for the length reference.
_LENGTH_HALF, _LENGTH_SUPPORT = 10, 5


def window_statistic(values: ArrayLike, stat: Callable[[NDArray[np.float64]], NDArray],
                     half: int, support: int, chunk: int = 512) -> NDArray[np.float64]:
    """``stat`` over the last axis of each value's window of ``2 half + 1`` frames.

    Parameters
    ----------
    values : array_like, shape (F, ...)
        NaN where none.
    stat : callable
        Reduces an (N, 2 half + 1) array (NaN for the missing) to (N,).
    half, support : int
        Half-window (frames); fewest finite values in a window to be judged.
    chunk : int
        Frames per block (memory ``O(chunk * size * (2 half + 1))``).

    Returns
    -------
    ndarray, same shape
        NaN where the value itself is missing or its window has fewer than ``support``.
    """
    w = np.asarray(values, dtype=np.float64)
    F = w.shape[0]
    out = np.full(w.shape, np.nan)
    for a in range(0, F, chunk):
        b = min(F, a + chunk)
        lo, hi = max(0, a - half), min(F, b + half)
        blk = np.full((b - a + 2 * half,) + w.shape[1:], np.nan)
        blk[lo - (a - half):hi - (a - half)] = w[lo:hi]
        win = np.lib.stride_tricks.sliding_window_view(blk, 2 * half + 1, axis=0)
        judge = np.isfinite(w[a:b]) & (np.isfinite(win).sum(-1) >= support)
        if judge.any():
            part = out[a:b]
            part[judge] = stat(win[judge])
            out[a:b] = part
    return out


def _lower_quartile(win: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.nanpercentile(win, 25, axis=-1)`` (linear), from one sort: NaN sort last, so
    the finite values of each row come first (nanpercentile is ~30 times slower)."""
    srt = np.sort(win, axis=-1)
    n = np.isfinite(win).sum(-1)
    pos = 0.25 * np.maximum(n - 1, 0)
    lo = np.floor(pos).astype(np.intp)
    hi = np.minimum(lo + 1, np.maximum(n - 1, 0))
    rows = np.arange(win.shape[0])
    frac = pos - lo
    return srt[rows, lo] + frac * (srt[rows, hi] - srt[rows, lo])


def blob_noise_scale(major_px: ArrayLike, score: ArrayLike, *, half: int = _LENGTH_HALF,
                     support: int = _LENGTH_SUPPORT) -> NDArray[np.float64]:
    """Factor of each observation's 2D noise from its blob's score and length.

    A blob the detector scores below ~0.995, or one longer or shorter than the same
    marker's usually is in that camera, is a marker merged with something beside it, cut
    by an edge or blurred: its centre is off by several times the noise of a clean blob.
    The factor is the larger of `SCORE_NOISE` at its score and `LENGTH_NOISE` at its
    semi-major axis over the lower quartile of the same point's in the same camera over
    ``half`` frames either side (a quartile, not the median: merged frames can be as many
    as clean ones). It multiplies `width_noise_scale`.

    Parameters
    ----------
    major_px, score : array_like, shape (F, P, C)
        Semi-major axis (px) and score of each observation's blob; NaN where none
        (factor 1 for what is unknown).
    half, support : int
        Half-window (frames) and fewest lengths in it for the length reference.

    Returns
    -------
    ndarray, shape (F, P, C), >= 1

    Examples
    --------
    >>> import numpy as np
    >>> a = np.full((30, 1, 1), 5.0); a[12, 0, 0] = 6.0
    >>> s = np.full((30, 1, 1), 0.999); s[20, 0, 0] = 0.9
    >>> f = blob_noise_scale(a, s)[:, 0, 0]
    >>> [float(f[0]), float(f[12]), float(f[20])]
    [1.0, 3.5, 4.0]
    """
    a = np.asarray(major_px, dtype=np.float64)
    sc = np.asarray(score, dtype=np.float64)
    f_score = np.where(np.isfinite(sc), np.interp(np.nan_to_num(sc, nan=1.0), *SCORE_NOISE),
                       1.0)
    ref = window_statistic(a, _lower_quartile, half, support)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = a / ref
    f_len = np.where(np.isfinite(ratio), np.interp(np.nan_to_num(ratio, nan=1.0),
                                                   *LENGTH_NOISE), 1.0)
    return np.maximum(f_score, f_len)
