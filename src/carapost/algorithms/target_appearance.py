"""Target tracking through a changing appearance: the frames next to an occlusion.

The keyframe patterns of :mod:`carapost.algorithms.target_track` describe the marker as
it looked at its keyframes. Two things make a marker look different from them while it
is still visible, and the keyframe match fails there although the artist can see the
marker:

- *Next to an occlusion* (an eyelid closing, a lip rolling in), the marker moves fast
  relative to what surrounds it: an eye's lash line, the iris and the lid crease enter
  the pattern box, and the disc foreshortens as the lid turns. The whole-pattern match
  falls below the Break Threshold one to three frames before the marker disappears.
- *A fading marker* (sweat, a smudge, a grazing light): its contrast against the skin
  falls, the skin's texture does not, so the pattern taken at full contrast stops
  matching a few frames into the fade. This step does **not** follow it: a marker whose
  contrast has left 0.8-1.25 times its keyframe's (`MIN_CONTRAST`) is refused, since
  following a faint disc frame to frame drifts; the artist keys it on a faded frame.

:func:`follow_appearance` is the step the tracker takes when the keyframe match of a
frame fails after a tracked frame (a keyframe match or an earlier appearance step). It
matches the *appearance* of the marker in the previous frame (the patch at the previous
tracked position: one frame of change, not the many since the keyframe), with a robust
Lucas-Kanade refinement whose Tukey weights drop the pixels that changed (the lash line
sliding in, the lid's edge). The position is then refined once more, robustly, against
the keyframe pattern itself (in the tracker's window, or where that fails in a window
narrowed to the disc, `ANCHOR_SIGMA`), so that the chain of appearances cannot walk away
from the marker frame by frame; and the step is accepted only while the keyframe pattern's centre
(the marker disc, weighted like the tracker's own score) still matches at the new place
above the Anchor Score. When the marker disappears, the disc the previous appearance
shows is missing: the centre no longer matches the keyframe and the robust match of the
appearance falls, so the track still stops at the first hidden frame.

Coordinates are raw pixels with OpenCV's pixel-centre convention, as in
:mod:`carapost.algorithms.target_track`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.target_refine import gaussian_window, shift_patch

__all__ = ["appearance_step", "follow_appearance", "keyframe_contrast", "robust_refine",
           "robust_score", "window_contrast"]

#: Tukey's biweight constant, in robust standard deviations of the residual: pixels whose
#: residual after the fit is beyond it get no weight (what changed in the pattern).
TUKEY_C = 3.0
#: Floor of the residual's robust scale (grey levels), so that a noiseless patch does not
#: reject the interpolation error of its own pixels.
SCALE_FLOOR = 0.5
#: Floor of the residual's robust scale as a fraction of the pattern's contrast.
RELATIVE_FLOOR = 0.03
#: The appearance's and the keyframe's positions of an appearance step must agree within
#: this (px): farther, the keyframe refinement found something else than the chain.
AGREE_PX = 0.5
#: An appearance step needs the marker's contrast (window-weighted standard deviation of
#: the patch) within this fraction of the keyframe's and its inverse.
MIN_CONTRAST = 0.8
#: Where the keyframe refinement of an appearance step fails in the tracker's window, it
#: is tried once more in a window this much narrower, on the disc: one or two frames before
#: a blink the lid crease and lash line fill the box's rim and pull the wide fit away from
#: the appearance's position, while the disc itself is still whole. Only a fallback: as the
#: first choice the narrow fit is 0.3-0.4 px off on frames the wide one gets right.
ANCHOR_SIGMA = 0.7
#: Reweighting iterations before :func:`robust_refine` may stop on a small step.
MIN_REWEIGHTS = 3


def _window(size: int, sigma: float) -> NDArray[np.float64]:
    w = gaussian_window(size, sigma).ravel()  # the tracker's score window, sum 1
    return w / w.sum()


def _weighted_ncc(w: NDArray[np.float64], t: NDArray[np.float64],
                  wt: NDArray[np.float64]) -> float:
    s = float(wt.sum())
    if s <= 0:
        return 0.0
    wt = wt / s
    wc, tc = w - wt @ w, t - wt @ t
    den = math.sqrt(float(wt @ (wc * wc)) * float(wt @ (tc * tc)))
    return float(wt @ (wc * tc)) / den if den > 1e-12 else 0.0


def robust_refine(crop: NDArray[np.float64], origin: tuple[int, int],
                  tpl: NDArray[Any], xy0: Any, *, weight_sigma: float,
                  iterations: int = 20, tol: float = 2e-4, max_move: float = 6.0
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Robust Lucas-Kanade: the pattern's translation with gain, bias and shading, IRLS.

    The model is the tracker's (``I(x + p) = a T(x - d) + b + c_x u + c_y v``), solved by
    iteratively reweighted least squares: each iteration weighs every pixel by the
    Gaussian window times Tukey's biweight of its residual at the previous iteration
    (scale: the weighted median absolute residual), so the part of the pattern that
    changed (an edge sliding in, the background a faded disc no longer hides) stops
    pulling the position.

    Parameters
    ----------
    crop : ndarray (h, w) float64
        The image around the marker; ``(0, 0)`` of the crop is ``origin`` (raw px).
    origin : tuple of int
        Raw pixel coordinates (x, y) of the crop's first pixel.
    tpl : ndarray (P, P)
        The pattern (any scale: it is normalised here).
    xy0 : array_like, shape (2,)
        Starting position (raw px).
    weight_sigma : float
        Sigma of the Gaussian window (px; 0: uniform).
    iterations : int
        Iterations at most.
    tol : float
        Stop when a step is below this (px).
    max_move : float
        A position farther than this from ``xy0`` failed (px).

    Returns
    -------
    xy : ndarray, shape (2,)
        Refined position (raw px); NaN when the fit failed (the patch left the crop, the
        contrast vanished or inverted, the position moved too far).
    weights : ndarray, shape (P * P,)
        The final per-pixel weights (window times biweight), summing to 1.
    ncc : float
        The normalised cross-correlation of the pattern and the image patch at ``xy``
        under ``weights`` (the match of the part that did not change), in [-1, 1].

    Examples
    --------
    A dark disc whose pattern box has a dark band sliding in from below; the band does
    not pull the robust position:

    >>> yy, xx = np.mgrid[0:41, 0:41].astype(float)
    >>> def img(cx, cy, band):
    ...     disc = 120 / (1 + np.exp((np.hypot(xx - cx, yy - cy) - 3) * 1.5))
    ...     return 160 - disc - 80 * (yy > band)
    >>> tpl = img(20.0, 20.0, 60)[10:31, 10:31]
    >>> xy, wt, ncc = robust_refine(img(20.4, 20.3, 25), (0, 0), tpl, (20.0, 20.0),
    ...                             weight_sigma=3.8)
    >>> bool(np.hypot(xy[0] - 20.4, xy[1] - 20.3) < 0.02), ncc > 0.99
    (True, True)
    """
    t = np.asarray(tpl, dtype=np.float64)
    size = t.shape[0]
    h = size // 2
    tn = (t - t.mean()) / max(float(t.std()), 1e-9)
    gy, gx = np.gradient(tn)
    g = (np.arange(size) - h) / max(h, 1)
    J = np.stack([-gx.ravel(), -gy.ravel(), tn.ravel(), np.ones(size * size),
                  np.tile(g, size), np.repeat(g, size)])             # (6, N)
    win = _window(size, weight_sigma)
    ox, oy = origin
    lo, hi_x, hi_y = h + 1, crop.shape[1] - h - 3, crop.shape[0] - h - 3
    start = np.asarray(xy0, dtype=np.float64).reshape(2)
    p = start.copy()
    nan = np.array([np.nan, np.nan])
    wt = win.copy()
    w = np.zeros(size * size)
    for it in range(iterations):
        cx, cy = p[0] - ox, p[1] - oy
        if not (lo <= cx <= hi_x and lo <= cy <= hi_y):
            return nan, wt / wt.sum(), 0.0
        w = shift_patch(crop, cx, cy, size).ravel()
        JW = J * wt
        try:
            sol = np.linalg.solve(JW @ J.T, JW @ w)
        except np.linalg.LinAlgError:
            return nan, wt / wt.sum(), 0.0
        a = sol[2]
        if not a > 1e-6:               # contrast inverted or gone: no marker here
            return nan, wt / wt.sum(), 0.0
        # the residual of the photometric fit at this position sets the new weights
        r = w - sol[2:] @ J[2:]
        wt = _biweight(r, wt, win, a)
        if wt.sum() < 1e-3 * win.sum():
            return nan, win, 0.0
        d = sol[:2] / a
        p = p + d
        if np.hypot(*(p - start)) > max_move:
            return nan, wt / wt.sum(), 0.0
        # the first steps fit the weights as much as the position: at least three
        if it >= MIN_REWEIGHTS and float(d @ d) < tol * tol:
            break
    cx, cy = p[0] - ox, p[1] - oy
    if not (lo <= cx <= hi_x and lo <= cy <= hi_y):
        return nan, wt / wt.sum(), 0.0
    w = shift_patch(crop, cx, cy, size).ravel()
    return p, wt / wt.sum(), _weighted_ncc(w, tn.ravel(), wt)


def robust_score(w: NDArray[np.float64], tpl: NDArray[np.float64],
                 win: NDArray[np.float64], iterations: int = 4) -> float:
    """The NCC of ``tpl`` and the patch ``w`` over the pixels that match.

    The gain, bias and shading of ``tpl`` are fitted to ``w`` by IRLS with Tukey's
    biweight (as in :func:`robust_refine`, at a fixed position); the NCC is weighted by
    the Gaussian window ``win`` times the final biweight.

    Parameters
    ----------
    w, tpl : ndarray, shape (N,)
        The image patch and the pattern (flattened P x P).
    win : ndarray, shape (N,)
        The window weights.
    iterations : int
        Reweighting iterations.

    Returns
    -------
    float
        In [-1, 1].
    """
    n = int(round(math.sqrt(w.size)))
    h = n // 2
    g = (np.arange(n) - h) / max(h, 1)
    A = np.stack([tpl, np.ones(w.size), np.tile(g, n), np.repeat(g, n)])   # (4, N)
    wt = win.copy()
    for _ in range(iterations):
        AW = A * wt
        try:
            sol = np.linalg.solve(AW @ A.T, AW @ w)
        except np.linalg.LinAlgError:
            return 0.0
        r = w - sol @ A
        wt = _biweight(r, wt, win, abs(float(sol[0])) * float(tpl.std()))
        if wt.sum() < 1e-3 * win.sum():
            return 0.0
    return _weighted_ncc(w, tpl, wt)


def _biweight(r: NDArray[np.float64], wt: NDArray[np.float64], win: NDArray[np.float64],
              contrast: float) -> NDArray[np.float64]:
    """The window times Tukey's biweight of the residuals ``r`` (grey levels).

    The scale is the weighted median absolute deviation of ``r`` under the current
    weights ``wt``, at least `SCALE_FLOOR` and `RELATIVE_FLOOR` of the pattern's fitted
    ``contrast`` (its standard deviation in the image, grey levels): on a noiseless
    patch the interpolation error at a sharp rim is not a change of the pattern.
    """
    dev = np.abs(r - _wmedian(r, wt))
    s = max(1.4826 * _wmedian(dev, wt), SCALE_FLOOR, RELATIVE_FLOOR * contrast)
    z = r / (TUKEY_C * s)
    return win * np.where(np.abs(z) < 1.0, (1.0 - z * z) ** 2, 0.0)


def _wmedian(v: NDArray[np.float64], wt: NDArray[np.float64]) -> float:
    """Weighted median of ``v``."""
    order = np.argsort(v)
    c = np.cumsum(wt[order])
    return float(v[order][np.searchsorted(c, 0.5 * c[-1])])


def follow_appearance(image: NDArray[Any], prev_image: NDArray[Any], prev_xy: Any,
                      predicted: Any, key_tpl: NDArray[Any], *, pattern_size: int,
                      weight_sigma: float, anchor_score: float, max_move: float,
                      max_anchor_px: float = 1.5, key_contrast: float | None = None
                      ) -> tuple[NDArray[np.float64], float]:
    """One tracking step against the marker's appearance in the previous frame.

    Parameters
    ----------
    image, prev_image : ndarray (H, W)
        This frame's and the previous (confidently tracked) frame's grey images.
    prev_xy : array_like, shape (2,)
        The marker's position in ``prev_image`` (raw px).
    predicted : array_like, shape (2,)
        Predicted position in ``image`` (raw px): the start of the refinement.
    key_tpl : ndarray (P, P)
        The keyframe pattern of this frame (the blend of the keyframes around it).
    pattern_size : int
        P (px).
    weight_sigma : float
        Sigma of the Gaussian window of the refinements and the scores (px).
    anchor_score : float
        The keyframe pattern's centre-weighted NCC at the new position must reach this,
        or the step failed (the marker the keyframe shows is no longer there).
    max_move : float
        A position farther than this from ``predicted`` failed (px).
    max_anchor_px : float
        The keyframe refinement may move the appearance's position by this much at most
        (px); farther, the two disagree and the step failed.
    key_contrast : float, optional
        The marker's contrast at its keyframe (:func:`window_contrast`, grey levels):
        where the patch found has less than `MIN_CONTRAST` of it, or more than its
        inverse, the step failed. The step follows a marker whose surroundings change,
        not one that fades (or comes back from a fade): a faint marker is matched less
        accurately than the keyframe match would need, and the track stops there as it
        would without the step.

    Returns
    -------
    xy : ndarray, shape (2,)
        Position (raw px), NaN when the step failed.
    score : float
        The robust match of the previous appearance at ``xy`` in [0, 1] (0 when the step
        failed); at most the keyframe anchor's match when that is below
        ``anchor_score``.
    """
    from carapost.algorithms.target_track import sample_patch

    nan = np.array([np.nan, np.nan])
    P = int(pattern_size)
    prev = np.asarray(sample_patch(prev_image, prev_xy, P), dtype=np.float64)
    if prev.std() < 1e-3:
        return nan, 0.0
    pred = np.asarray(predicted, dtype=np.float64).reshape(2)
    H, W = image.shape[:2]
    half = P // 2 + int(math.ceil(max_move)) + 4
    cx, cy = int(round(pred[0])), int(round(pred[1]))
    x0, y0 = max(cx - half, 0), max(cy - half, 0)
    x1, y1 = min(cx + half + 1, W), min(cy + half + 1, H)
    if x1 - x0 < P + 6 or y1 - y0 < P + 6:
        return nan, 0.0
    crop = np.asarray(image[y0:y1, x0:x1], dtype=np.float64)
    xa, wa, ncc_a = robust_refine(crop, (x0, y0), prev, pred, weight_sigma=weight_sigma,
                                  max_move=max_move)
    if not np.all(np.isfinite(xa)):
        return nan, 0.0
    # anchored to the keyframe: the appearance only brings the start near enough
    xk, _, _ = robust_refine(crop, (x0, y0), key_tpl, xa, weight_sigma=weight_sigma,
                             max_move=max_anchor_px)
    if not np.all(np.isfinite(xk)):   # the rim pulled it off: on the disc alone
        xk, _, _ = robust_refine(crop, (x0, y0), key_tpl, xa,
                                 weight_sigma=weight_sigma * ANCHOR_SIGMA,
                                 max_move=max_anchor_px)
    if not np.all(np.isfinite(xk)) or np.hypot(*(xk - pred)) > max_move:
        return nan, 0.0
    ox, oy = xk[0] - x0, xk[1] - y0
    w = shift_patch(crop, ox, oy, P).ravel()
    if key_contrast is not None and not (
            MIN_CONTRAST <= window_contrast(w, weight_sigma) / max(key_contrast, 1e-9)
            <= 1.0 / MIN_CONTRAST):
        return nan, 0.0
    key = np.asarray(key_tpl, dtype=np.float64).ravel()
    win = _window(P, weight_sigma)
    anchor = _weighted_ncc(w, key, win)
    # the appearance's robust match at the anchored position, its weights re-fitted there
    ncc_a = robust_score(w, prev.ravel(), win)
    score = min(max(ncc_a, 0.0), 1.0)
    if anchor < anchor_score:
        score = min(score, max(anchor, 0.0))
    return xk, score


def appearance_step(image: NDArray[Any], prev_image: NDArray[Any], prev_xy: Any,
                    predicted: Any, key_tpl: NDArray[Any], params: Any,
                    key_contrast: float | None = None,
                    failed: tuple[NDArray[np.float64], float] | None = None
                    ) -> tuple[NDArray[np.float64], float]:
    """:func:`follow_appearance` with the settings of a ``TargetTrackerParameters``.

    ``key_contrast`` (:func:`keyframe_contrast` of the keyframe behind) is the marker's
    contrast as keyed: a step where the marker shows less than `MIN_CONTRAST` of it (or
    more than its inverse) fails.
    ``failed`` is what the keyframe match found, returned when the step fails too (so
    the frame keeps the keyframe match's score).
    """
    xy, score = follow_appearance(
        image, prev_image, prev_xy, predicted, key_tpl, pattern_size=params.pattern_size,
        weight_sigma=params.weight_fraction * params.pattern_size,
        anchor_score=params.anchor_score, max_move=max(float(params.near_px), 2.0),
        max_anchor_px=AGREE_PX, key_contrast=key_contrast)
    if failed is not None and not (np.all(np.isfinite(xy)) and score >= failed[1]):
        return failed
    return xy, score


def keyframe_contrast(image: NDArray[Any], xy: Any, params: Any) -> float:
    """The marker's contrast at a keyframe (:func:`window_contrast` of its pattern), for
    :func:`appearance_step`; a run computes it once per keyframe."""
    from carapost.algorithms.target_track import sample_patch
    return window_contrast(sample_patch(image, xy, params.pattern_size),
                           params.weight_fraction * params.pattern_size)


def window_contrast(patch: NDArray[Any], weight_sigma: float) -> float:
    """The window-weighted standard deviation of a patch (grey levels): its contrast."""
    w = np.asarray(patch, dtype=np.float64).ravel()
    win = _window(int(round(math.sqrt(w.size))), weight_sigma)
    wc = w - win @ w
    return math.sqrt(float(win @ (wc * wc)))
