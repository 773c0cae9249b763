"""Target tracking on the disc alone: the keyframe's skin subtracted, the marker fitted.

Next to a blink an eyelid marker slides over its own skin: in the last one or two
frames before it disappears (and the first after it reappears) it moves 2-4 px a frame
onto the lid crease and the lash line, which move with the head, not with the marker.
The disc is still whole, but most of the pattern box around it is skin that has moved
relative to it since the keyframe, so the keyframe match (the whole box) and the
appearance step (the previous frame's box) both fail there although the artist sees the
marker.

A painted marker darkens the skin under it by a factor (its ink's reflectance):
``I(X) = B(X) (1 - K(X - p))`` for the skin ``B`` and the disc's ink ``K``.
:func:`disc_model` takes the two apart at the keyframe: the skin with the disc filled in
from its surroundings, and the ink (``1 - I / B`` on the disc only). In a later frame
the skin is the keyframe's moved with the head (a shift ``s``) under a gain ``G`` (with a
ramp), and the marker is the ink at its new place, so

    ``I_t(X) = B_k(X + s) G(X) (1 - a K(X - p))``

is fitted by Gauss-Newton with Tukey weights (:func:`fit_disc`; a neighbouring marker,
which moves by its own motion, drops out): the crease and lash line are explained by
the skin instead of pulling the position. ``a`` is how much of the keyframe's ink is
there: near 1 while the disc is whole, lower where part of it is covered, near 0 once it
is hidden. The score (:func:`disc_step`) is the correlation of the darkening the skin
does not explain with the disc's, over the disc's support, so a hidden marker, whose
frame shows skin only, scores low and the track stops. :func:`disc_polish` uses the same
fit where the keyframe match holds but the crease pulls it.

Coordinates are raw pixels with OpenCV's pixel-centre convention, as in
:mod:`carapost.algorithms.target_track`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.target_appearance import _biweight
from carapost.algorithms.target_refine import shift_patch

__all__ = ["DiscModel", "disc_model", "disc_polish", "disc_step", "fit_disc", "rekey"]

#: Grey levels added before the log of the black-hat that finds the keyframe's disc (the
#: dark disc core's noise is not amplified).
LOG_OFFSET = 16.0
#: Half side of the fitted window around the predicted position (px).
FIT_HALF = 12
#: The disc is the part of the keyframe's black-hat above this fraction of its value at
#: the centre, connected to it; grown by `DISC_GROW` px for the ink's blurred rim.
DISC_LEVEL = 0.6
#: Radius of the black-hat's disc as a fraction of the Pattern Size (px).
DISC_KERNEL = 0.15
DISC_GROW = 2
#: Iterations of the fit at most; it stops on a step below `TOL_PX`.
ITERATIONS = 15
TOL_PX = 5e-3
#: A disc step holds where the darkening the skin leaves correlates with the keyframe's
#: disc at least this much ...
MIN_NCC = 0.95
#: ... and its amplitude (the ink relative to the keyframe's: the share of the disc that
#: is there) is within this range. A disc an eyelid fold covers by more than about 15 %
#: fails it (and the track stops, the artist is told); at 0.7 the step followed partly
#: covered discs further (eyelid fold seed 0: tracked 0.352 -> 0.398 of the covered
#: frames) for one more blink frame.
AMPLITUDE = (0.85, 1.4)
#: A keyframe match scoring below this is checked against the disc fit
#: (:func:`disc_polish`) ...
POLISH_BELOW = 0.985
#: ... on a marker moving at least this fast in the image (px per frame: a lid closing;
#: the fit costs some milliseconds, on slow markers it is not tried) ...
POLISH_SPEED_PX = 0.4
#: ... where the disc has slid this far over its skin since the keyframe (px) ...
POLISH_SLID_PX = 1.0
#: ... and replaced by it where they are this far apart (px) ...
POLISH_PX = 0.25
#: ... and where the disc's correlation there is higher by this than at the keyframe
#: match (on speech takes, 379 of 382 fits that differed had less, 13 of them nearer the
#: truth; next to a blink 17 of 27, all nearer) ...
POLISH_GAIN = 0.02
#: ... the disc fit searched this far around the keyframe match (px).
POLISH_MOVE_PX = 1.5


@dataclass
class DiscModel:
    """A keyframe taken apart into skin and disc.

    Attributes
    ----------
    skin : ndarray (h, w) float64
        The keyframe around the marker (grey levels), the disc filled in from around it.
    disc : ndarray (h, w) float64
        The disc's ink: ``1 - I / skin`` on the disc (the fraction of the skin's light
        it takes, about 0.84 at a painted marker's core), 0 off it.
    support : ndarray (h, w) bool
        The disc's pixels (the ink's support).
    origin : tuple of int
        Raw pixel coordinates (x, y) of the crops' first pixel.
    xy : ndarray, shape (2,)
        The keyframe position (raw px).
    energy : float
        Sum of squares of ``disc`` (the disc's strength).
    radius : float
        The disc's support's reach from the keyframe position (px).
    """

    skin: NDArray[np.float64]
    disc: NDArray[np.float64]
    support: NDArray[np.bool_]
    origin: tuple[int, int]
    xy: NDArray[np.float64]
    energy: float
    radius: float


def _log(image: NDArray[Any]) -> NDArray[np.float64]:
    return np.log(np.asarray(image, dtype=np.float64) + LOG_OFFSET)


def _fill(img: NDArray[np.float64], mask: NDArray[np.bool_], iterations: int = 200
          ) -> NDArray[np.float64]:
    """``img`` with the pixels under ``mask`` replaced by the harmonic fill of their
    surroundings (Laplace's equation, Jacobi iterations started from the mean of the
    mask's rim): the skin under a small disc, interpolated smoothly from around it."""
    out = img.copy()
    rim = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & ~mask
    out[mask] = float(img[rim].mean()) if rim.any() else float(img.mean())
    ys, xs = np.nonzero(mask)
    for _ in range(iterations):
        out[ys, xs] = 0.25 * (out[ys - 1, xs] + out[ys + 1, xs] + out[ys, xs - 1]
                              + out[ys, xs + 1])
    return out


def disc_model(image: NDArray[Any], xy: Any, pattern_size: int) -> DiscModel | None:
    """Take a keyframe apart into the skin around the marker and the disc's ink.

    Parameters
    ----------
    image : ndarray (H, W)
        The keyframe's grey image.
    xy : array_like, shape (2,)
        The keyframe position (raw px).
    pattern_size : int
        The Pattern Size (px): the disc is looked for within a quarter of it.

    Returns
    -------
    DiscModel or None
        None where there is no dark disc at the centre, or too near the border.
    """
    p = np.asarray(xy, dtype=np.float64).reshape(2)
    half = FIT_HALF + pattern_size // 2 + 8
    cx, cy = int(round(p[0])), int(round(p[1]))
    H, W = image.shape[:2]
    if not (half <= cx < W - half and half <= cy < H - half):
        return None
    x0, y0 = cx - half, cy - half
    lin = np.asarray(image[y0:y0 + 2 * half + 1, x0:x0 + 2 * half + 1], dtype=np.float64)
    lg = _log(lin)
    r = max(int(round(pattern_size * DISC_KERNEL)), 2)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    hat = cv2.morphologyEx(lg.astype(np.float32), cv2.MORPH_BLACKHAT, k).astype(np.float64)
    c = half
    peak = float(hat[c - 1:c + 2, c - 1:c + 2].max())
    if not peak > 0.1:   # no dark blob at the centre (a tenth in log: 10 % darker)
        return None
    n, lab = cv2.connectedComponents((hat > DISC_LEVEL * peak).astype(np.uint8), 8)
    ids = np.unique(lab[c - 1:c + 2, c - 1:c + 2])
    ids = ids[ids > 0]
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1]
    # the component at the centre, within the black-hat's reach (a crease it touches
    # is not the disc)
    blob = np.isin(lab, ids) & (np.hypot(xx, yy) <= r + 1)
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * DISC_GROW + 1,) * 2)
    support = cv2.dilate(blob.astype(np.uint8), grow).astype(bool)
    skin = _fill(lin, support)
    # the ink: the fraction of the skin's light the disc takes (0 off it)
    disc = np.where(support, np.clip(1.0 - lin / np.maximum(skin, 1.0), -0.5, 1.0), 0.0)
    ys, xs = np.nonzero(blob)
    radius = float(np.hypot(xs + x0 - p[0], ys + y0 - p[1]).max())
    return DiscModel(skin, disc, support, (x0, y0), p, float((disc * disc).sum()), radius)


def fit_disc(image: NDArray[Any], model: DiscModel, predicted: Any, *,
             shift0: Any = (0.0, 0.0), max_move: float = 3.0
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
    """Fit the keyframe's skin (moved) times its disc (moved on its own) to a frame.

    The model of the frame's window is ``I(X) = B(X + s) G(X) (1 - a K(X - p))``:
    the keyframe's skin ``B`` shifted by ``s``, a gain ``G = g + r_x u + r_y v`` (the
    light on the skin as the face turns), the disc's ink ``K`` at ``p`` with the
    amplitude ``a``. Stages: the skin's shift and gain with the disc's neighbourhood
    left out; the disc's integer place in what the skin does not explain (correlation
    with the ink within ``max_move`` of the prediction), refined by a parabola; then
    all of them together. Both fits are robust Gauss-Newton (Tukey weights: a
    neighbouring marker, which moves by its own motion, drops out) with steps of at
    most half a pixel (the disc is 2-4 px across: a longer linearised step
    overshoots). Where the disc has left its keyframe place on the skin, the skin
    under the keyframe's disc is seen in this frame: the keyframe is taken apart again
    with it (its skin was interpolated, wrongly where the disc sat on a crease's edge)
    and the joint fit repeated.

    Parameters
    ----------
    image : ndarray (H, W)
        The frame's grey image.
    model : DiscModel
        The keyframe taken apart (:func:`disc_model`).
    predicted : array_like, shape (2,)
        Where the marker is expected (raw px): the window's centre and the start.
    shift0 : array_like, shape (2,)
        Start of the skin's shift (px; keyframe position of a frame's pixel minus the
        pixel).
    max_move : float
        A position farther than this from ``predicted`` failed (px).

    Returns
    -------
    xy : ndarray, shape (2,)
        The disc's position (raw px), NaN where the fit failed.
    shift : ndarray, shape (2,)
        The skin's shift (px).
    amplitude : float
        The disc's ink relative to the keyframe's (1: as keyed, 0: gone).
    ncc : float
        Correlation of the darkening the skin does not explain and the fitted disc's
        over the disc's support, in [-1, 1] (low where no disc is there).
    """
    return _fit_disc(image, model, predicted, shift0, max_move)[:4]


def _fit_disc(image: NDArray[Any], model: DiscModel, predicted: Any, shift0: Any,
              max_move: float, compare: Any = None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float, float]:
    """:func:`fit_disc`, and the correlation of the disc put at ``compare`` instead
    (same skin shift and gain; 0 without ``compare``)."""
    nan = np.array([np.nan, np.nan])
    pred = np.asarray(predicted, dtype=np.float64).reshape(2)
    s = np.asarray(shift0, dtype=np.float64).reshape(2).copy()
    if not np.all(np.isfinite(pred)):
        return nan, s, 0.0, 0.0, 0.0
    H, W = image.shape[:2]
    cx, cy = int(round(pred[0])), int(round(pred[1]))
    m = FIT_HALF + 4
    s = np.asarray(shift0, dtype=np.float64).reshape(2).copy()
    if not (m <= cx < W - m and m <= cy < H - m):
        return nan, s, 0.0, 0.0, 0.0
    fit = _Fit(image, model, cx, cy)
    # 1. the skin alone, away from where the disc may be
    reach = max_move + model.radius + 2.0
    away = (np.hypot(fit.X - pred[0], fit.Y - pred[1]) > reach).astype(float)
    out = fit.skin_only(s, away)
    if out is None:
        return nan, s, 0.0, 0.0, 0.0
    s, gain = out
    # 2. the disc's place: the ink correlated with the darkening the skin leaves
    p = fit.place(model, s, gain, pred, max_move)
    if p is None:
        return nan, s, 0.0, 0.0, 0.0
    # 3. skin and disc together
    out = fit.joint(model, s, p, gain, pred, max_move)
    if out is None:
        return nan, s, 0.0, 0.0, 0.0
    p, s, a, gain, wt = out
    kx, ky = model.xy
    if np.hypot(p[0] + s[0] - kx, p[1] + s[1] - ky) > 2.0 * model.radius + 2.0:
        again = rekey(model, image, s, gain, (cx, cy))
        if again is not None:
            out = fit.joint(again, s, p, gain, pred, max_move)
            if out is not None:
                model = again
                p, s, a, gain, wt = out
    amp, ncc = fit.evidence(model, s, p, gain)
    other = 0.0
    if compare is not None:
        other = fit.evidence(model, s, np.asarray(compare, dtype=np.float64), gain)[1]
    return p, s, amp, ncc, other


def rekey(model: DiscModel, image: NDArray[Any], shift: NDArray[np.float64],
          gain: NDArray[np.float64], centre: tuple[int, int]) -> DiscModel | None:
    """The keyframe taken apart again with the skin under its disc as seen in ``image``.

    ``image``'s pixel ``X`` shows the keyframe's skin at ``X + shift`` times the gain
    (``gain`` over the fit window around ``centre``); the keyframe's disc support,
    moved there, must be clear of the frame's own disc (the caller's check).
    """
    S = model.skin.shape[0]
    ox, oy = model.origin
    m = 6
    fx0, fy0 = ox - m, oy - m
    H, W = image.shape[:2]
    if fx0 < 0 or fy0 < 0 or fx0 + S + 2 * m > W or fy0 + S + 2 * m > H:
        return None
    crop = np.asarray(image[fy0:fy0 + S + 2 * m, fx0:fx0 + S + 2 * m], dtype=np.float64)
    h = S // 2
    seen = shift_patch(crop, h + m - shift[0], h + m - shift[1], S)
    # the gain at those pixels (its ramp is across the fit window around centre)
    g = np.arange(S) - h
    u = (ox + h - shift[0] + g - centre[0]) / FIT_HALF
    v = (oy + h - shift[1] + g - centre[1]) / FIT_HALF
    G = gain[0] + gain[1] * u[None, :] + gain[2] * v[:, None]
    if not np.all(G > 0):
        return None
    skin_seen = seen / G
    sup = model.support
    skin = model.skin.copy()
    skin[sup] = skin_seen[sup]
    lin = model.skin * (1.0 - model.disc)   # the keyframe's own pixels (support and off)
    disc = np.where(sup, np.clip(1.0 - lin / np.maximum(skin, 1.0), -0.5, 1.0), 0.0)
    return DiscModel(skin, disc, sup, model.origin, model.xy,
                     float((disc * disc).sum()), model.radius)


class _Fit:
    """The frame's window around ``(cx, cy)`` and the stages of :func:`fit_disc`."""

    def __init__(self, image: NDArray[Any], model: DiscModel, cx: int, cy: int) -> None:
        N = self.N = 2 * FIT_HALF + 1
        self.model = model
        self.cx, self.cy = cx, cy
        wx0, wy0 = cx - FIT_HALF, cy - FIT_HALF
        self.obs = np.asarray(image[wy0:wy0 + N, wx0:wx0 + N], dtype=np.float64).ravel()
        g = np.arange(N) - FIT_HALF
        self.X, self.Y = np.tile(g + cx, N).astype(float), np.repeat(g + cy, N).astype(float)
        self.gu, self.gv = np.tile(g / FIT_HALF, N), np.repeat(g / FIT_HALF, N)
        self.ones = np.ones(N * N)
        self.lo, self.hi = N // 2 + 2, model.skin.shape[0] - N // 2 - 4
        # grey levels of the skin, for the robust weights' floor
        self.scale = max(float(np.median(self.obs)), 1.0)

    def _at(self, arr: NDArray[np.float64], x: float, y: float
            ) -> NDArray[np.float64] | None:
        if not (self.lo <= x <= self.hi and self.lo <= y <= self.hi):
            return None
        return shift_patch(arr, x, y, self.N)

    def skin(self, model: DiscModel, s: NDArray[np.float64]) -> NDArray[np.float64] | None:
        ox, oy = model.origin
        return self._at(model.skin, self.cx + s[0] - ox, self.cy + s[1] - oy)

    def disc(self, model: DiscModel, p: NDArray[np.float64],
             arr: NDArray[np.float64] | None = None) -> NDArray[np.float64] | None:
        ox, oy = model.origin
        kx, ky = model.xy
        return self._at(model.disc if arr is None else arr,
                        self.cx - p[0] + kx - ox, self.cy - p[1] + ky - oy)

    def _gain(self, gain: NDArray[np.float64]) -> NDArray[np.float64]:
        return gain[0] + gain[1] * self.gu + gain[2] * self.gv

    def skin_only(self, s: NDArray[np.float64], away: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The skin's shift and gain (unknowns ds (2), g, r_x, r_y), ``away`` weighed."""
        obs, wt = self.obs, away.copy()
        gain = np.array([1.0, 0.0, 0.0])
        for it in range(ITERATIONS):
            b = self.skin(self.model, s)
            if b is None:
                return None
            bgy, bgx = np.gradient(b)
            G, bb = self._gain(gain), b.ravel()
            J = np.stack([bgx.ravel() * G, bgy.ravel() * G, bb, bb * self.gu, bb * self.gv])
            JW = J * wt
            try:
                sol = np.linalg.solve(JW @ J.T + 1e-9 * np.eye(5), JW @ obs)
            except np.linalg.LinAlgError:
                return None
            step = _clip(sol[:2])
            s, gain = s + step, sol[2:]
            if it >= 1:
                wt = _biweight(obs - J.T @ np.concatenate([step, gain]), wt, away,
                               self.scale)
            if np.hypot(*s) > 6.0 or wt.sum() < 0.2 * away.sum() or not gain[0] > 0:
                return None
            if it >= 3 and float(step @ step) < TOL_PX ** 2:
                break
        return s, gain

    def place(self, model: DiscModel, s: NDArray[np.float64], gain: NDArray[np.float64],
              pred: NDArray[np.float64], max_move: float) -> NDArray[np.float64] | None:
        """The disc's place in the darkening the skin leaves (integer peak, parabola)."""
        b = self.skin(model, s)
        if b is None:
            return None
        N = self.N
        e = (b.ravel() * self._gain(gain) - self.obs).reshape(N, N).astype(np.float32)
        r = int(math.ceil(model.radius)) + 1
        ox, oy = model.origin
        tpl = shift_patch(model.disc, model.xy[0] - ox, model.xy[1] - oy,
                          2 * r + 1).astype(np.float32)
        res = cv2.matchTemplate(e, tpl, cv2.TM_CCORR)   # centres r .. N-1-r
        cen = np.arange(res.shape[0]) + r - FIT_HALF   # offsets from (cx, cy)
        ux, uy = self.cx + cen - pred[0], self.cy + cen - pred[1]
        res[(uy[:, None] ** 2 + ux[None, :] ** 2) > max_move ** 2] = -np.inf
        _, best, _, (bx, by) = cv2.minMaxLoc(res)
        if not np.isfinite(best) or best <= 0:
            return None
        p = np.array([self.cx + cen[bx], self.cy + cen[by]], dtype=np.float64)
        if 0 < bx < res.shape[1] - 1 and 0 < by < res.shape[0] - 1:
            for k, (lo, mid, hi) in enumerate(((res[by, bx - 1], best, res[by, bx + 1]),
                                               (res[by - 1, bx], best, res[by + 1, bx]))):
                den = lo - 2 * mid + hi
                if np.isfinite(den) and den < 0:
                    p[k] += float(np.clip(0.5 * (lo - hi) / den, -0.5, 0.5))
        return p

    def joint(self, model: DiscModel, s: NDArray[np.float64], p: NDArray[np.float64],
              gain: NDArray[np.float64], pred: NDArray[np.float64], max_move: float
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], float,
                         NDArray[np.float64], NDArray[np.float64]] | None:
        """Skin and disc together: unknowns ds (2), dp (2), a, g, r_x, r_y."""
        obs, win = self.obs, self.ones
        wt = win.copy()
        a = 1.0
        for it in range(ITERATIONS):
            b = self.skin(model, s)
            d = self.disc(model, p)
            if b is None or d is None:
                return None
            bgy, bgx = np.gradient(b)
            dgy, dgx = np.gradient(d)
            bb, dd = b.ravel(), d.ravel()
            G = self._gain(gain)
            Q = 1.0 - a * dd
            BG = bb * G
            # the disc's gradient at the last amplitude (a dp ~ a_last dp)
            J = np.stack([bgx.ravel() * G * Q, bgy.ravel() * G * Q,
                          BG * a * dgx.ravel(), BG * a * dgy.ravel(),
                          -BG * dd, bb * Q, bb * Q * self.gu, bb * Q * self.gv])
            # the model is linear in (a, g, r_x, r_y) given the positions: solved for
            # them outright, for the positions' steps
            base = BG * Q - J[4:].T @ np.concatenate([[a], gain])
            JW = J * wt
            try:
                sol = np.linalg.solve(JW @ J.T + 1e-9 * np.eye(8), JW @ (obs - base))
            except np.linalg.LinAlgError:
                return None
            ds, dp = _clip(sol[0:2]), _clip(sol[2:4])
            s, p = s + ds, p + dp
            fitted = base + J.T @ np.concatenate([ds, dp, sol[4:]])
            a, gain = float(sol[4]), sol[5:].copy()
            if it >= 1:
                wt = _biweight(obs - fitted, wt, win, self.scale)
            if np.hypot(*(p - pred)) > max_move or not a > 0.05 or not gain[0] > 0:
                return None
            if it >= 3 and float(dp @ dp) < TOL_PX ** 2:
                break
        return p, s, a, gain, wt

    def evidence(self, model: DiscModel, s: NDArray[np.float64], p: NDArray[np.float64],
                 gain: NDArray[np.float64]) -> tuple[float, float]:
        """The disc's amplitude and correlation in the darkening the skin leaves."""
        b = self.skin(model, s)
        d = self.disc(model, p)
        sup = self.disc(model, p, model.support.astype(np.float64))
        if b is None or d is None or sup is None:
            return 0.0, 0.0
        bg = b.ravel() * self._gain(gain)
        on = sup.ravel() > 0.5
        ev = (bg - self.obs)[on]        # the darkening the skin does not explain
        dv = (bg * d.ravel())[on]       # the keyframe's disc's darkening there
        den = math.sqrt(float(dv @ dv) * float(ev @ ev))
        ncc = float(dv @ ev) / den if den > 1e-12 else 0.0
        return float(dv @ ev) / max(float(dv @ dv), 1e-12), ncc


def _clip(step: NDArray[np.float64], most: float = 0.5) -> NDArray[np.float64]:
    n = float(np.hypot(*step))
    return step * (most / n) if n > most else step


def _holds(xy: NDArray[np.float64], amp: float, ncc: float) -> bool:
    """Whether a disc fit found the whole disc: a position, the darkening correlated
    with the keyframe's disc by `MIN_NCC` or more, its amplitude within `AMPLITUDE`."""
    return bool(np.all(np.isfinite(xy)) and ncc >= MIN_NCC
                and AMPLITUDE[0] <= amp <= AMPLITUDE[1])


def disc_polish(image: NDArray[Any], model: DiscModel | None, xy: Any, *,
                shift0: Any = (0.0, 0.0)) -> tuple[NDArray[np.float64] | None,
                                                    NDArray[np.float64]]:
    """The disc's own position near a keyframe match that holds, where it differs.

    Where the marker has slid over its skin since the keyframe (by `POLISH_SLID_PX` or
    more), the keyframe match, which weighs the skin around the disc too, is pulled
    by the skin's edges that came into its box (a lid crease). The disc fit is taken
    instead where it holds (:func:`disc_step`'s checks), is `POLISH_PX` or more away
    (nearer, the keyframe match stands), and explains the darkening the skin leaves
    clearly better than the disc put at the keyframe match (its correlation higher by
    `POLISH_GAIN`): on markers whose keyframe match is right, the disc fit, less
    accurate, is off by as much with about the same correlation.

    Returns the position to use instead (None: keep the keyframe match) and the skin's
    shift.
    """
    if model is None:
        return None, np.zeros(2)
    p, s, amp, ncc, there = _fit_disc(image, model, xy, shift0, POLISH_MOVE_PX, compare=xy)
    if not (_holds(p, amp, ncc) and ncc - there >= POLISH_GAIN):
        return None, s
    slid = np.hypot(p[0] + s[0] - model.xy[0], p[1] + s[1] - model.xy[1])
    if slid < POLISH_SLID_PX or np.hypot(*(p - np.asarray(xy, float))) < POLISH_PX:
        return None, s
    return p, s


def disc_step(image: NDArray[Any], model: DiscModel | None, predicted: Any, *,
              shift0: Any = (0.0, 0.0), max_move: float = 3.0
              ) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """One tracking step on the disc alone (:func:`fit_disc`), with its score.

    The step holds where the darkening the skin leaves correlates with the keyframe's
    disc at least `MIN_NCC` and its amplitude is within `AMPLITUDE` of the keyframe's:
    the whole disc is there. Its score is that correlation.

    Returns
    -------
    xy : ndarray, shape (2,)
        Position (raw px), NaN when the step failed.
    score : float
        In [0, 1]; 0 when the step failed.
    shift : ndarray, shape (2,)
        The skin's shift (px), the start of the next step's.
    """
    nan = np.array([np.nan, np.nan])
    if model is None:
        return nan, 0.0, np.zeros(2)
    xy, s, amp, ncc = fit_disc(image, model, predicted, shift0=shift0, max_move=max_move)
    if not _holds(xy, amp, ncc):
        return nan, 0.0, s
    return xy, min(max(ncc, 0.0), 1.0), s
