"""Target tracking between keyframes of different contrast: a marker that fades.

A marker whose ink fades (sweat, a smudge, a grazing light) keeps its place on the skin
and its shape; only the depth of its disc changes. The image around it is then, to the
noise, a *mixture* of two looks of the same patch: where the marker is painted on skin
``S`` with coverage ``D``, ``I = S (1 - s D)`` for an ink strength ``s``, so two
keyframes of strengths ``s1`` and ``s2`` give every frame in between as
``I = a1 T1 + a2 T2`` with ``a1 + a2 = 1`` in the ideal case (the skin cancels out: no
estimate of the skin under the disc is needed). The tracker's blend of the keyframe
patterns by distance in frames (`carapost.algorithms.target_track`) assumes the look
changes linearly in time; a fade does not (it ramps down in a few frames and stays).

:func:`mixture_refine` fits the two keyframe patterns' gains freely, with the
translation, a bias and a shading ramp, by Gauss-Newton (the model is bilinear in the
gains and the shift), and scores the window-weighted NCC of the image with the fitted
mixture. The tracker uses it between two keyframes whose contrasts differ by more than
`CONTRAST_RATIO` (the artist keyed the marker once as painted and once faded) where
the distance blend does not match: between keyframes of one look (a blink) nothing
changes.

Coordinates are raw pixels with OpenCV's pixel-centre convention, as in
:mod:`carapost.algorithms.target_track`.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.target_refine import gaussian_window, marker_weight, shift_patch

__all__ = ["CONTRAST_RATIO", "contrasts_differ", "disc_depth", "fade_step", "mixture_refine"]

#: Two keyframes whose marker contrasts (window-weighted standard deviation of their
#: patterns) differ by more than this factor are a fade: their frames are fitted as a
#: mixture of both patterns.
CONTRAST_RATIO = 1.5
#: A mixture gain below this (relative to a pattern's own scale) is a negative amount of
#: a look: the fit failed.
MIN_GAIN = -0.15
#: The fitted mixture must match the image over the disc (the fit's weights) at least
#: this well, or the disc is not there. Lower than the Break Threshold: a disc faded to
#: a few grey levels on dark skin is matched through the sensor noise (NCC 0.6-0.8 over
#: the disc at 20 % contrast and noise 2), so the run's score is the match over the
#: whole pattern window (the marker's surroundings, which move with it).
MIN_DISC_NCC = 0.5


def disc_depth(tpl: NDArray[Any]) -> float:
    """The depth of the disc at a pattern's centre (grey levels): the larger of the
    black and the white top-hat there (a disc half the pattern's side, as
    :func:`carapost.algorithms.target_refine.marker_weight` isolates the marker), so
    that the skin's structure around the marker (a lip line, a shadow) does not count.

    >>> yy, xx = np.mgrid[0:21, 0:21]
    >>> skin = np.where(xx > 15, 160.0, 110.0)
    >>> disc = np.hypot(xx - 10, yy - 10) < 3
    >>> round(disc_depth(skin - 40.0 * disc)), round(disc_depth(skin - 8.0 * disc))
    (40, 8)
    """
    t = np.ascontiguousarray(tpl, dtype=np.float32)
    n = t.shape[0]
    c = n // 2
    k = max(int(n * 0.5) | 1, 3)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    centre = np.s_[c - 1:c + 2, c - 1:c + 2]
    black = cv2.morphologyEx(t, cv2.MORPH_BLACKHAT, disc)[centre].max()
    white = cv2.morphologyEx(t, cv2.MORPH_TOPHAT, disc)[centre].max()
    return float(max(black, white))


def contrasts_differ(t1: NDArray[Any], t2: NDArray[Any]) -> bool:
    """Whether two keyframe patterns (raw grey levels, P x P) show the marker's disc at
    depths (:func:`disc_depth`) more than `CONTRAST_RATIO` apart."""
    c1, c2 = disc_depth(t1), disc_depth(t2)
    lo, hi = min(c1, c2), max(c1, c2)
    return bool(hi > 1e-6 and hi > CONTRAST_RATIO * lo)


def mixture_refine(image: NDArray[Any], t1: NDArray[Any], t2: NDArray[Any], xy0: Any,
                   w1: float, *, weight_sigma: float, weights: NDArray[Any] | None = None,
                   iterations: int = 15, tol: float = 2e-4, max_move: float = 1.5
                   ) -> tuple[NDArray[np.float64], float]:
    """Refine the marker's position as a free mixture of two keyframe patterns.

    The model is ``I(x + p) = a1 T1(x - d) + a2 T2(x - d) + b + c_x u + c_y v``; each
    Gauss-Newton step solves for ``(d, a1, a2, b, c_x, c_y)`` at the current gains,
    weighted by the Gaussian window.

    Parameters
    ----------
    image : ndarray (H, W)
        This frame's grey image.
    t1, t2 : ndarray (P, P)
        The two keyframe patterns in grey levels (not normalised: their contrasts are
        what differs).
    xy0 : array_like, shape (2,)
        Start (raw px): the prediction or the distance blend's match.
    w1 : float
        Start value of ``a1`` (the distance blend's weight of ``t1``); ``a2 = 1 - w1``.
    weight_sigma : float
        Sigma of the Gaussian window (px).
    weights : ndarray (P, P), optional
        Weights of the fit and the score (default: the Gaussian window); the tracker
        passes the marker weight of the contrasted keyframe
        (:func:`carapost.algorithms.target_refine.marker_weight`): the skin around a
        marker stretches as the face moves, the disc is what marks its centre.
    iterations, tol : int, float
        Gauss-Newton steps at most; stop when a step is below ``tol`` px.
    max_move : float
        A position farther than this from ``xy0`` failed (px).

    Returns
    -------
    xy : ndarray, shape (2,)
        Refined position (raw px), NaN when the fit failed (left the image, moved too
        far, a gain negative: not a mixture of the two looks).
    score : float
        The window-weighted NCC of the image patch and the fitted mixture, in [0, 1].

    Examples
    --------
    A dark disc fading to 30 % on a textured skin that moves with it, between a
    keyframe as painted and one faded:

    >>> yy, xx = np.mgrid[0:80, 0:80].astype(float)
    >>> rng = np.random.default_rng(2)
    >>> skin = 120 + 8 * np.sin(xx / 2.3 + yy / 3.1) + 5 * np.cos(xx / 1.7 - yy / 2.9)
    >>> def img(cx, s):
    ...     x = xx - (cx - 40)
    ...     sk = 120 + 8 * np.sin(x / 2.3 + yy / 3.1) + 5 * np.cos(x / 1.7 - yy / 2.9)
    ...     return sk * (1 - s * 0.84 / (1 + np.exp((np.hypot(x - 40, yy - 40) - 4) * 2)))
    >>> from carapost.algorithms.target_track import sample_patch
    >>> t1 = sample_patch(img(40.0, 1.0), (40.0, 40.0), 21)
    >>> t2 = sample_patch(img(40.0, 0.2), (40.0, 40.0), 21)
    >>> xy, score = mixture_refine(img(40.6, 0.45), t1, t2, (41.0, 40.2), 0.5,
    ...                            weight_sigma=3.8)
    >>> bool(np.hypot(xy[0] - 40.6, xy[1] - 40.0) < 0.02), score > 0.99
    (True, True)
    """
    nan = np.array([np.nan, np.nan])
    T1 = np.asarray(t1, dtype=np.float64)
    T2 = np.asarray(t2, dtype=np.float64)
    n = T1.shape[0]
    h = n // 2
    g1y, g1x = np.gradient(T1)
    g2y, g2x = np.gradient(T2)
    g = (np.arange(n) - h) / max(h, 1)
    win = (gaussian_window(n, weight_sigma) if weights is None
           else np.asarray(weights, dtype=np.float64)).ravel()
    win = win / win.sum()
    base = np.stack([T1.ravel(), T2.ravel(), np.ones(n * n), np.tile(g, n), np.repeat(g, n)])
    start = np.asarray(xy0, dtype=np.float64).reshape(2)
    p = start.copy()
    a1, a2 = float(w1), 1.0 - float(w1)
    H, W = image.shape[:2]
    half = h + int(math.ceil(max_move)) + 6
    cx, cy = int(round(p[0])), int(round(p[1]))
    x0, y0 = cx - half, cy - half
    if x0 < 0 or y0 < 0 or cx + half + 1 > W or cy + half + 1 > H:
        return nan, 0.0
    crop = np.asarray(image[y0:cy + half + 1, x0:cx + half + 1], dtype=np.float64)
    w = np.zeros(n * n)
    for _ in range(iterations):
        w = shift_patch(crop, p[0] - x0, p[1] - y0, n).ravel()
        gx = (a1 * g1x + a2 * g2x).ravel()
        gy = (a1 * g1y + a2 * g2y).ravel()
        J = np.concatenate([np.stack([-gx, -gy]), base])      # (7, N)
        JW = J * win
        try:
            sol = np.linalg.solve(JW @ J.T, JW @ w)
        except np.linalg.LinAlgError:
            return nan, 0.0
        a1, a2 = float(sol[2]), float(sol[3])
        if a1 < MIN_GAIN or a2 < MIN_GAIN or a1 + a2 <= 1e-6:
            return nan, 0.0
        d = sol[:2]
        p = p + d
        if np.hypot(*(p - start)) > max_move:
            return nan, 0.0
        if float(d @ d) < tol * tol:
            break
    w = shift_patch(crop, p[0] - x0, p[1] - y0, n).ravel()
    model = a1 * base[0] + a2 * base[1]
    # the disc must be there (its weighted match), the score is the pattern's window
    if _ncc(w, model, win) < MIN_DISC_NCC:
        return nan, 0.0
    gauss = gaussian_window(n, weight_sigma).ravel()
    return p, min(max(_ncc(w, model, gauss / gauss.sum()), 0.0), 1.0)


def _ncc(w: NDArray[np.float64], m: NDArray[np.float64], win: NDArray[np.float64]) -> float:
    wc, mc = w - win @ w, m - win @ m
    den = math.sqrt(float(win @ (wc * wc)) * float(win @ (mc * mc)))
    return float(win @ (wc * mc)) / den if den > 1e-12 else 0.0


def fade_step(image: NDArray[Any], prev_key: tuple[int, NDArray[Any]],
              next_key: tuple[int, NDArray[Any]], frame: int, predicted: NDArray,
              found: tuple[NDArray[np.float64], float], params: Any,
              fades: dict[tuple[int, int], NDArray[np.float64] | None]
              ) -> tuple[NDArray[np.float64], float]:
    """One tracking step between two keyframes, as a mixture where they are a fade.

    The tracker's distance blend assumes the look changes evenly from one keyframe to
    the next; a fade ramps in a few frames and then holds, so on the faded frames the
    blend is the wrong pattern and can still score above the Break Threshold, off the
    centre (by 1-2 px on a mouth corner, following the skin's stretch rather than the
    disc). Between two keyframes whose discs differ in depth (:func:`contrasts_differ`)
    the frame is fitted by :func:`mixture_refine`, weighted to the disc of the more
    contrasted keyframe, and that fit is the frame's match (no position where it
    fails). Between keyframes of one look nothing changes.

    Parameters
    ----------
    image : ndarray (H, W)
        This frame's grey image.
    prev_key, next_key : tuple of (int, ndarray (P, P))
        Frame and raw pattern (grey levels) of the keyframes behind and ahead.
    frame : int
        This frame.
    predicted : ndarray, shape (2,)
        The predicted position (raw px).
    found : tuple of (ndarray (2,), float)
        What the distance blend's match found (position, NaN if none; score).
    params : TargetTrackerParameters
    fades : dict
        The run's cache of the keyframe pairs: the fit's weights, None where the pair
        is not a fade.

    Returns
    -------
    xy : ndarray, shape (2,)
    score : float
    """
    (f1, t1), (f2, t2) = prev_key, next_key
    xy, score = found
    sigma = params.weight_fraction * params.pattern_size
    if (f1, f2) not in fades:
        fades[f1, f2] = None
        if contrasts_differ(t1, t2):
            # the disc of the keyframe where it shows best weighs the fit
            vivid = max((t1, t2), key=disc_depth)
            v = np.asarray(vivid, dtype=np.float64)
            fades[f1, f2] = marker_weight((v - v.mean()) / max(float(v.std()), 1e-9), sigma)
    weights = fades[f1, f2]
    if weights is None:
        return xy, score
    d1, d2 = abs(frame - f1), abs(f2 - frame)
    # from the prediction, not from the blend's match (that may be off by more than a
    # refinement's reach: 1.7 px on a mouth corner), and no farther from it than a
    # refinement may move: on skin that does not move with the marker the mixture is
    # not exact, and 6 px of reach let a chain of frames walk 3 px off a mouth corner
    xm, sm = mixture_refine(
        image, t1, t2, predicted, d2 / float(d1 + d2), weight_sigma=sigma,
        weights=weights, iterations=params.max_iterations, tol=params.tolerance_px,
        max_move=params.max_refine_px)
    if not np.all(np.isfinite(xm)):
        # no mixture fits: the blend's match is no fallback (it follows the skin, not
        # the disc: 6-10 px off within 20 frames on a mouth corner of the default
        # renders, at scores above 0.93), so the frame has no position
        return np.array([np.nan, np.nan]), 0.0
    return xm, sm
