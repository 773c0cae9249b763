"""Target tracking: one marker in one camera, followed from keyframes by patch matching.

The Target Tracker is the artist's tool for what the automatic tracker cannot do:
eyelid markers that go in and out of occlusion, lips in extreme curl, markers the blob
detector misses. :func:`track_target` follows one marker through the frames of one
camera:

1. The *pattern* (the blue box: a square of ``pattern_size`` px) is sampled around the
   marker at the previous keyframe and, when there is one ahead in the tracking
   direction, at the next keyframe. The two patterns are blended by distance in frames
   (the nearer keyframe weighs more), each normalised to zero mean and unit variance.
2. The blended pattern is searched by normalised cross-correlation
   (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``) in the *search region* (the green cross:
   a square of ``search_size`` px) centred on the position predicted from the last two
   tracked frames. A small penalty on the distance from the prediction breaks near-ties
   in favour of the expected place.
3. The integer peak is refined by Lucas-Kanade on the patch with a gain and a bias term
   (the image is resampled with 6-point cubic convolution; the fit weighs the marker blob
   and a rim around it, see :mod:`carapost.algorithms.target_refine`; the pattern's gradients are
   fixed, so the 4 x 4 normal matrix is inverted once per pattern).
4. The score is the normalised cross-correlation between the pattern and the image patch
   at the refined position, clipped to [0, 1]. Tracking stops when it falls below the
   Break Threshold, at the next keyframe (Stop On Next Keyframe), after N frames (Stop
   after N Frames), at ``stop``, or when ``progress`` returns False.

Every frame is matched against the keyframe patterns, never against the previous
frame's patch, so errors do not accumulate: a track cannot drift slowly away; when the
marker disappears (a blink) the match score drops and the track stops.

Coordinates are raw pixels with OpenCV's pixel-centre convention (pixel ``(i, j)`` has
its centre at ``x = j``, ``y = i``), as everywhere in carapost.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.algorithms import target_appearance, target_disc, target_fade
from carapost.algorithms.params import TARGET_TRACKER, param, validate
from carapost.algorithms.target_identity import consistent_backwards as _consistent_backwards
from carapost.algorithms.target_identity import first_step as _assigned_step
from carapost.algorithms.target_polish import LogPolish
from carapost.algorithms.target_refine import (
    denoise_pattern,
    gaussian_window,
    marker_weight,
    shift_patch,
)

__all__ = [
    "STOP_CANCELLED",
    "STOP_END",
    "STOP_KEYFRAME",
    "STOP_LIMIT",
    "STOP_REASONS",
    "STOP_THRESHOLD",
    "TargetTrackResult",
    "TargetTrackerParameters",
    "check_keyframe",
    "match_patch",
    "sample_patch",
    "track_target",
]

#: Why a run stopped.
STOP_THRESHOLD = "threshold"   # the score fell below the Break Threshold (marker lost)
STOP_KEYFRAME = "keyframe"     # reached the next keyframe (Stop On Next Keyframe)
STOP_LIMIT = "limit"           # tracked N frames (Stop after N Frames)
STOP_END = "end"               # reached ``stop``
STOP_CANCELLED = "cancelled"   # ``progress`` returned False
STOP_REASONS = (STOP_THRESHOLD, STOP_KEYFRAME, STOP_LIMIT, STOP_END, STOP_CANCELLED)

_OURS = " Default is our choice (the guide gives none)."


@dataclass(frozen=True)
class TargetTrackerParameters:
    """The Target Tracker settings (Tracker pane) and the pattern and search sizes.

    The settings keep the property keys of the Tracker pane (``tracker_*``). The
    pattern box and search region sizes belong to each target track (the guide edits
    them with handles on the track), so they are not Tracker pane settings; the
    fields without a section are the defaults and the matcher's internal tunables.
    """

    stop_after_n_frames: bool = param(
        False, label="Stop after N Frames", section=TARGET_TRACKER,
        key="tracker_stop_after_n_frames",
        help="Limit each track forward/backward run to N frames." + _OURS)
    n_frames: int = param(
        10, label="N", section=TARGET_TRACKER, key="tracker_n_frames", unit="frames",
        min=1, max=1_000_000,
        help="Number of frames a limited run covers." + _OURS + " Range is our choice.")
    overwrite_existing_tracks: bool = param(
        False, label="Overwrite Existing Tracks", section=TARGET_TRACKER,
        key="tracker_overwrite_existing_tracks",
        help="Replace 2D data the selected points already have while tracking." + _OURS)
    auto_add_keyframes: bool = param(
        True, label="Automatically Add Keyframes", section=TARGET_TRACKER,
        key="tracker_auto_add_keyframes",
        help="Key the selected points at the current frame before tracking, in every "
             "camera where they have no keyframe yet." + _OURS)
    stop_on_next_keyframe: bool = param(
        True, label="Stop On Next Keyframe", section=TARGET_TRACKER,
        key="tracker_stop_on_next_keyframe",
        help="Stop when any selected point reaches a keyframe in any camera." + _OURS)
    allow_single_sensor_tracking: bool = param(
        True, label="Allow Single Sensor Tracking", section=TARGET_TRACKER,
        key="tracker_allow_single_sensor_tracking",
        help="Reconstruct a target-tracked point from one camera by keeping it on that "
             "camera's ray." + _OURS)
    break_threshold: float = param(
        0.9, label="Break Threshold", section=TARGET_TRACKER,
        key="tracker_break_threshold", unit="0-1", min=0.0, max=1.0,
        help="Minimum match between the tracked patch and the keyframe patches; higher "
             "stops sooner but drifts less.")
    pattern_size: int = param(
        21, unit="px", min=5, max=255,
        help="Side of the pattern box (blue) around the marker: about two to three "
             "marker diameters." + _OURS + " Range is our choice.")
    search_size: int = param(
        81, unit="px", min=5, max=1023,
        help="Side of the search region (green cross) in which the pattern is looked for "
             "in the next frame; larger follows faster motion, smaller is faster and "
             "less likely to swap onto a neighbour." + _OURS + " Range is our choice.")
    # --- internal tunables ----------------------------------------------------------
    max_iterations: int = param(12, min=1, max=100,
                                help="Lucas-Kanade iterations at most per frame.")
    tolerance_px: float = param(2e-4, min=0.0, min_exclusive=True,
                                help="Lucas-Kanade stops when a step is below this.")
    distance_penalty: float = param(
        0.05, min=0.0, max=1.0,
        help="NCC subtracted per (half search size) squared of distance from the "
             "prediction, to break near-ties towards the expected place.")
    weight_fraction: float = param(
        0.18, min=0.0,
        help="Gaussian weight of the refinement and the score around the pattern centre, "
             "sigma as a fraction of the Pattern Size (0: uniform).")
    near_px: int = param(
        6, min=0, max=100, unit="px",
        help="First search this far around the prediction (0: always the whole search "
             "region); a clear match inside it is taken.")
    ambiguity_margin: float = param(
        0.05, min=0.0, max=1.0,
        help="A match whose second-best peak (another place in the search region) is "
             "within this NCC of the best is ambiguous: the track stops there.")
    check_step_px: float = param(
        2.0, min=0.0, unit="px",
        help="Steps longer than this are checked backwards (the patch found must lead "
             "back to the previous position): a step onto a neighbour fails the check.")
    confirm_frames: int = param(
        5, min=0, max=1000, unit="frames",
        help="A run that loses the marker within this many frames of its first step "
             "(taken before the motion is known, scoring below Confirm Score) keeps none "
             "of them: that step may have been onto a neighbour.")
    confirm_score: float = param(
        0.97, min=0.0, max=1.0,
        help="A first step scoring at least this needs no confirmation (a near-perfect "
             "match of the keyframe pattern is the marker itself).")
    max_refine_px: float = param(
        1.5, min=0.0, min_exclusive=True,
        help="A refinement moving farther than this from the integer peak failed.")
    assign_first_step: bool = param(
        True, help="Check a run's first step against every disc like the marker around "
                   "it (carapost.algorithms.target_identity); ambiguous: stop.")
    denoise_pattern: bool = param(False, help=(
        "Make the keyframe pattern point-symmetric about the keyframe position inside the "
        "marker weight (a disc is; the odd part there is the pattern's noise)."))
    follow_appearance: bool = param(True, help=(
        "Where the keyframe match fails after a tracked frame, match the marker's look "
        "in that frame (robust, anchored to the keyframe; algorithms/target_appearance)."))
    anchor_score: float = param(0.7, min=0.0, max=1.0, help=(
        "An appearance step holds while the keyframe pattern's centre matches this well."))
    log_offset: float = param(0.0, min=0.0, unit="grey levels", help=(
        "The keyframe match's position is polished on log(grey + this) (0: not), where "
        "a marker's ink darkens whatever skin is under it by the same factor: a marker "
        "sliding over a darker lid crease keeps its look (algorithms/target_polish)."))

    def __post_init__(self) -> None:
        validate(self)
        if self.search_size < self.pattern_size:
            raise ValueError(
                f"Search Size ({self.search_size} px) must be at least the Pattern Size "
                f"({self.pattern_size} px): the pattern is searched inside the region")


@dataclass
class TargetTrackResult:
    """What :func:`track_target` visited and found.

    Attributes
    ----------
    frames : ndarray, shape (N,) int64
        The frames visited in tracking order, the start frame first.
    xy : ndarray, shape (N, 2) float64
        Marker position (raw px); NaN where it did not track (the frame where the score
        fell below the threshold).
    score : ndarray, shape (N,) float64
        Match score in [0, 1] (1 for a keyframe).
    keyframe : ndarray, shape (N,) bool
        The frame is a keyframe (its position is the keyframe's, not tracked).
    reason : str
        Why it stopped: one of :data:`STOP_REASONS`.
    """

    frames: NDArray[np.int64]
    xy: NDArray[np.float64]
    score: NDArray[np.float64]
    keyframe: NDArray[np.bool_]
    reason: str

    @property
    def tracked(self) -> NDArray[np.bool_]:
        """Frames given a new tracked position (not keyframes, not failed)."""
        return ~self.keyframe & np.isfinite(self.xy[:, 0])


@dataclass
class _Pattern:
    """A keyframe's pattern, ready for search and refinement."""

    frame: int
    norm: NDArray[np.float32]          # (P, P) zero mean, unit variance
    grads: NDArray[np.float64] = field(repr=False, default=None)  # (2, P, P)
    raw: NDArray[np.float32] = field(repr=False, default=None)    # (P, P) grey levels


def check_keyframe(xy: Any, shape: tuple[int, ...], pattern_size: int) -> None:
    """Raise ValueError unless the pattern box around ``xy`` lies inside the image.

    Parameters
    ----------
    xy : array_like, shape (2,)
        Keyframe position (raw px).
    shape : tuple
        Image shape (H, W).
    pattern_size : int
        Side of the pattern box (px).

    Examples
    --------
    >>> check_keyframe((5.0, 50.0), (100, 200), 21)
    Traceback (most recent call last):
    ...
    ValueError: the pattern box (21 px) around (5, 50) does not fit in the 200 x 100 image
    """
    x, y = (float(v) for v in xy)
    h = pattern_size // 2 + 2   # two more pixels for the resampling and gradients
    H, W = shape[:2]
    if not (np.isfinite(x) and np.isfinite(y) and h <= x <= W - 1 - h
            and h <= y <= H - 1 - h):
        raise ValueError(f"the pattern box ({pattern_size} px) around ({x:g}, {y:g}) does "
                         f"not fit in the {W} x {H} image")


def sample_patch(image: NDArray[Any], xy: Any, size: int) -> NDArray[np.float32]:
    """The ``size`` x ``size`` patch centred on sub-pixel ``xy`` (6-point cubic convolution).

    Parameters
    ----------
    image : ndarray (H, W)
        Grey image (any real dtype).
    xy : array_like, shape (2,)
        Centre (raw px).
    size : int
        Side (px, odd).

    Returns
    -------
    ndarray, shape (size, size) float32
        Pixels outside the image repeat the border.

    Examples
    --------
    >>> img = np.arange(100, dtype=np.float32).reshape(10, 10)
    >>> sample_patch(img, (4.5, 3.0), 3).round(2).tolist()[1]
    [33.5, 34.5, 35.5]
    """
    h = size // 2
    x, y = float(xy[0]), float(xy[1])
    ix, iy = int(math.floor(x)), int(math.floor(y))
    x0, y0 = ix - h - 2, iy - h - 2
    n = size + 5
    H, W = image.shape[:2]
    crop = image[max(y0, 0):min(y0 + n, H), max(x0, 0):min(x0 + n, W)]
    crop = np.asarray(crop, dtype=np.float64)
    if crop.shape != (n, n):   # at the border: pad by repeating it
        crop = np.pad(crop, ((max(-y0, 0), n - crop.shape[0] - max(-y0, 0)),
                             (max(-x0, 0), n - crop.shape[1] - max(-x0, 0))), mode="edge")
    return shift_patch(crop, x - x0, y - y0, size).astype(np.float32)


def _normalise(p: NDArray[np.float32]) -> NDArray[np.float32] | None:
    s = float(p.std())
    if s < 1e-3:
        return None
    return ((p - p.mean()) / s).astype(np.float32)


def _make_pattern(image: NDArray[Any], xy: Any, frame: int, size: int,
                  weight_sigma: float = 0.0, denoise: bool = False) -> _Pattern:
    big = sample_patch(image, xy, size + 2)
    raw = big[1:-1, 1:-1]
    norm = _normalise(raw)
    if norm is None:
        raise ValueError(f"the pattern at frame {frame} around ({float(xy[0]):g}, "
                         f"{float(xy[1]):g}) is flat: nothing to track")
    if denoise:   # the odd part's noise shrunk inside the marker weight
        out = _normalise(denoise_pattern(image, xy, raw, norm, weight_sigma
                                         ).astype(np.float32))
        norm = norm if out is None else out
    return _Pattern(frame, norm, raw=raw)


def _blend(prev: _Pattern, nxt: _Pattern | None, frame: int) -> NDArray[np.float32]:
    """The pattern at ``frame``: the keyframe patterns weighted by nearness in frames."""
    if nxt is None or nxt.frame == prev.frame:
        return prev.norm
    dp, dn = abs(frame - prev.frame), abs(nxt.frame - frame)
    w = dp / float(dp + dn)
    out = _normalise((1.0 - w) * prev.norm + w * nxt.norm)
    return prev.norm if out is None else out


class _Refiner:
    """Lucas-Kanade refinement of a translation with gain, bias and shading on one pattern.

    The model is ``I(x + p) = a T(x - d) + b + c_x u + c_y v`` (``u, v`` in [-1, 1]
    across the box); linearised at ``d = 0`` the unknowns ``(a dx, a dy, a, b, c_x,
    c_y)`` solve a 6 x 6 system whose matrix depends on the pattern only, so it is
    factored once per pattern. The shading ramp absorbs the change of the skin's shading
    under the marker as the face turns: without it a shading gradient that slides under
    the pattern pulls the position towards the brighter side (a bias of 0.1-0.2 px on
    curved skin such as the nose tip).
    """

    def __init__(self, tpl: NDArray[np.float32], weight_sigma: float = 0.0,
                 shading: bool = True, marker: bool = True,
                 noise_weight: NDArray[np.float64] | None = None) -> None:
        gy, gx = np.gradient(tpl.astype(np.float64))
        self.size = n = tpl.shape[0]
        g = (np.arange(n) - n // 2) / max(n // 2, 1)
        cols = [-gx.ravel(), -gy.ravel(), tpl.ravel().astype(np.float64), np.ones(tpl.size)]
        if shading:   # a shading ramp across the box (skin curving away from the light)
            cols += [np.tile(g, n), np.repeat(g, n)]
        J = np.stack(cols)                                        # (4 or 6, N)
        wt = gaussian_window(n, weight_sigma)  # the marker at the centre over its surroundings
        self.wt = wt.ravel() / wt.sum()   # the score's window
        # the fit weighs the marker blob and its rim, not the lid or lip edges around it
        fit = marker_weight(tpl, weight_sigma).ravel() if marker else self.wt
        if noise_weight is not None:   # per-pixel inverse noise variance (log images)
            fit = fit * noise_weight.ravel()
        JW = J * (fit / fit.sum())
        self.J = JW
        self.Hinv = np.linalg.pinv(JW @ J.T)
        t = tpl.ravel().astype(np.float64)
        tc = t - self.wt @ t
        self.tpl_w = self.wt * tc / math.sqrt(float(self.wt @ (tc * tc)))
        tu = t - t.mean()
        self.tpl_u = tu / math.sqrt(float(tu @ tu))

    def refine(self, crop: NDArray[np.float64], origin: tuple[int, int], xy0: NDArray,
               iterations: int, tol: float) -> tuple[NDArray[np.float64], float, bool]:
        """Refine ``xy0`` (raw px) on the float image ``crop`` whose (0, 0) is ``origin``.

        Returns the refined position, the NCC there and whether it converged (NaN
        position when the patch leaves the crop).
        """
        size = self.size
        h = size // 2
        p = np.array(xy0, dtype=np.float64)
        ox, oy = origin
        lo, hi_x, hi_y = h + 1, crop.shape[1] - h - 3, crop.shape[0] - h - 3
        converged = False
        for _ in range(iterations):
            cx, cy = p[0] - ox, p[1] - oy
            if not (lo <= cx <= hi_x and lo <= cy <= hi_y):
                return np.array([np.nan, np.nan]), 0.0, False
            w = shift_patch(crop, cx, cy, size).ravel()
            sol = self.Hinv @ (self.J @ w)       # (a dx, a dy, a, b)
            a = sol[2]
            self.last_gain = float(a)
            if not a > 1e-6:                      # contrast inverted or gone: no marker
                return p, 0.0, False
            d = sol[:2] / a
            p += d
            if float(d @ d) < tol * tol:
                converged = True
                break
        cx, cy = p[0] - ox, p[1] - oy
        if not (lo <= cx <= hi_x and lo <= cy <= hi_y):
            return np.array([np.nan, np.nan]), 0.0, False
        # the score: the lower of the NCC over the whole pattern (the surroundings match,
        # not a look-alike neighbour) and the NCC weighted to the centre like the
        # refinement (the marker itself is there: one that vanishes from an unchanged
        # background scores low)
        w = shift_patch(crop, cx, cy, size).ravel()
        wc = w - self.wt @ w
        den = math.sqrt(float(self.wt @ (wc * wc)))
        ncc_w = float(self.tpl_w @ wc) / den if den > 1e-9 else 0.0
        wu = w - w.mean()
        den = math.sqrt(float(wu @ wu))
        ncc_u = float(self.tpl_u @ wu) / den if den > 1e-9 else 0.0
        self.last_ncc_w = ncc_w
        return p, min(ncc_w, ncc_u), converged


def match_patch(image: NDArray[Any], tpl: NDArray[np.float32], predicted: Any,
                params: TargetTrackerParameters, refiner: _Refiner | None = None
                ) -> tuple[NDArray[np.float64], float]:
    """Find the normalised pattern ``tpl`` near ``predicted`` in ``image``.

    Parameters
    ----------
    image : ndarray (H, W)
        Grey image.
    tpl : ndarray (P, P) float32
        The pattern, zero mean and unit variance (P = ``params.pattern_size``).
    predicted : array_like, shape (2,)
        Centre of the search region (raw px).
    params : TargetTrackerParameters
    refiner : optional
        The refiner of ``tpl`` (made here when not given).

    Returns
    -------
    xy : ndarray, shape (2,)
        Refined position (raw px), NaN when the pattern was not found.
    score : float
        NCC at ``xy`` clipped to [0, 1] (0 when not found).
    """
    if refiner is None:
        refiner = _Refiner(tpl, params.weight_fraction * params.pattern_size)
    small = params.pattern_size + 2 * params.near_px
    if params.near_px > 0 and small < params.search_size:
        # most frames move little: search near the prediction first and accept a clear
        # match that is not on the small region's edge; otherwise the whole region
        xy, score, edge = _search(image, tpl, predicted, params, refiner, small)
        if not edge and np.isfinite(xy[0]) and score >= params.break_threshold:
            return xy, score
    xy, score, _ = _search(image, tpl, predicted, params, refiner, params.search_size)
    return xy, score


def _search(image: NDArray[Any], tpl: NDArray[np.float32], predicted: Any,
            params: TargetTrackerParameters, refiner: _Refiner, S: int
            ) -> tuple[NDArray[np.float64], float, bool]:
    """One search of :func:`match_patch` in a region of side ``S``; also returns whether
    the integer peak lies on the region's edge (the marker may be beyond it)."""
    P = params.pattern_size
    hp, hs = P // 2, S // 2
    H, W = image.shape[:2]
    cx, cy = int(round(float(predicted[0]))), int(round(float(predicted[1])))
    nan = np.array([np.nan, np.nan])
    # the search crop, with 3 px more on each side for the sub-pixel refinement
    m = 3
    x0, x1 = max(cx - hs - m, 0), min(cx + hs + m + 1, W)
    y0, y1 = max(cy - hs - m, 0), min(cy + hs + m + 1, H)
    if x1 - x0 < P + 2 * m or y1 - y0 < P + 2 * m:
        return nan, 0.0, False
    crop = np.asarray(image[y0:y1, x0:x1], dtype=np.float32)
    win = crop[m:-m, m:-m]
    crop = crop.astype(np.float64)
    res = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
    if params.distance_penalty > 0 and S > P:
        # centres of the candidates relative to the prediction, in half search sizes
        norm = max(params.search_size // 2 - hp, 1)
        ux = (np.arange(res.shape[1]) + x0 + m + hp - predicted[0]) / norm
        uy = (np.arange(res.shape[0]) + y0 + m + hp - predicted[1]) / norm
        res = res - np.float32(params.distance_penalty) * (
            uy[:, None] ** 2 + ux[None, :] ** 2).astype(np.float32)
    _, best, _, (bx, by) = cv2.minMaxLoc(res)
    edge = bx in (0, res.shape[1] - 1) or by in (0, res.shape[0] - 1)
    peak = np.array([x0 + m + bx + hp, y0 + m + by + hp], dtype=np.float64)
    xy, ncc, _ = refiner.refine(crop, (x0, y0), peak, params.max_iterations,
                                params.tolerance_px)
    if params.ambiguity_margin > 0 and res.size > 1:
        # a second peak about as good, a pattern radius away or more: another marker (or
        # the same edge further along) could be the one. Scored like the best (refined,
        # centre-weighted), a clear loser is ignored; a near-tie stops the track
        r = max(hp // 2, 2)
        peaks = (res >= cv2.dilate(res, np.ones((3, 3), np.uint8))) & (
            res > best - params.ambiguity_margin)
        peaks[max(by - r, 0):by + r + 1, max(bx - r, 0):bx + r + 1] = False
        for sy, sx in zip(*np.nonzero(peaks), strict=True):
            other = np.array([x0 + m + sx + hp, y0 + m + sy + hp], dtype=np.float64)
            _, ncc2, _ = refiner.refine(crop, (x0, y0), other, params.max_iterations,
                                        params.tolerance_px)
            if ncc2 > ncc - params.ambiguity_margin:
                return nan, 0.0, edge
    if (not np.all(np.isfinite(xy)) or np.hypot(*(xy - peak)) > params.max_refine_px
            or not (hp + 1 <= xy[0] <= W - hp - 2 and hp + 1 <= xy[1] <= H - hp - 2)):
        return nan, 0.0, edge
    return xy, min(max(ncc, 0.0), 1.0), edge


ProgressFn = Callable[[int, int], "bool | None"] | None


def track_target(get_image: Callable[[int], NDArray[Any]],
                 keyframes: Mapping[int, Any], *, start: int, stop: int, direction: int,
                 params: TargetTrackerParameters | None = None,
                 start_xy: Any = None, start_velocity: Any = None,
                 progress: ProgressFn = None,
                 on_frame: Callable[[int, NDArray[np.float64], float], None] | None = None
                 ) -> TargetTrackResult:
    """Track one marker in one camera from ``start`` towards ``stop``.

    Parameters
    ----------
    get_image : callable
        ``get_image(frame) -> (H, W) grey image`` of this camera.
    keyframes : mapping of int to (x, y)
        Keyframe positions (raw px) by frame; at least one.
    start, stop : int
        First frame (its position is ``keyframes[start]`` or ``start_xy``) and the last
        frame tracking may reach (inclusive; tracking never passes it).
    direction : int
        +1 (forwards) or -1 (backwards).
    params : TargetTrackerParameters, optional
        Break Threshold, Stop On Next Keyframe, Stop after N Frames, pattern and search
        sizes (default: the defaults).
    start_xy : array_like, shape (2,), optional
        Position at ``start`` when it is not a keyframe (the previous run's result).
    start_velocity : array_like, shape (2,), optional
        Motion per frame in the tracking direction at ``start`` (px), for the first
        prediction (default: from the frame before ``start`` when it is a keyframe,
        else none).
    progress : callable, optional
        ``progress(done, total)`` after each frame; returning False cancels.
    on_frame : callable, optional
        ``on_frame(frame, xy, score)`` after each frame given a position (tracked or a
        keyframe passed through), before ``progress``: for showing a run as it goes.

    Returns
    -------
    TargetTrackResult

    Raises
    ------
    ValueError
        No keyframe; ``direction`` not +-1; ``stop`` behind ``start``; no position at
        ``start``; a keyframe whose pattern box does not fit in the image, or whose
        pattern is flat; a search region or pattern larger than the image.

    Examples
    --------
    A dark disc moving 0.37 px right per frame on a textured background:

    >>> yy, xx = np.mgrid[0:64, 0:96]
    >>> rng = np.random.default_rng(1)
    >>> bg = cv2.GaussianBlur(rng.normal(140, 20, (64, 96)), (0, 0), 1.5)
    >>> def image(f):
    ...     r = np.hypot(xx - (30 + 0.37 * f), yy - 31.6)
    ...     return np.clip(bg - 90 / (1 + np.exp((r - 4) * 3)), 0, 255).astype(np.uint8)
    >>> res = track_target(image, {0: (30.0, 31.6)}, start=0, stop=20, direction=1,
    ...                    params=TargetTrackerParameters(search_size=41))
    >>> res.reason, len(res.frames), bool(abs(res.xy[-1, 0] - 37.4) < 0.1)
    ('end', 21, True)
    """
    params = params if params is not None else TargetTrackerParameters()
    if direction not in (1, -1):
        raise ValueError(f"direction must be +1 or -1 (got {direction!r})")
    if not keyframes:
        raise ValueError("target tracking needs at least one keyframe")
    start, stop = int(start), int(stop)
    if (stop - start) * direction < 0:
        raise ValueError(f"stop frame {stop} is behind start frame {start} "
                         f"for direction {direction:+d}")
    keys = {int(f): np.asarray(xy, dtype=np.float64).reshape(2) for f, xy in keyframes.items()}
    if start in keys:
        pos = keys[start].copy()
    elif start_xy is not None and np.all(np.isfinite(np.asarray(start_xy, float))):
        pos = np.asarray(start_xy, dtype=np.float64).reshape(2).copy()
    else:
        raise ValueError(f"frame {start} is not a keyframe and no start position was given")
    key_frames = np.array(sorted(keys), dtype=np.int64)

    patterns: dict[int, _Pattern] = {}
    shape: list[tuple[int, ...]] = []

    def pattern(f: int) -> _Pattern:
        if f not in patterns:
            img = get_image(f)
            if not shape:
                shape.append(img.shape[:2])
                _check_sizes(img.shape[:2], params)
            check_keyframe(keys[f], img.shape, params.pattern_size)
            patterns[f] = _make_pattern(img, keys[f], f, params.pattern_size,
                                        params.weight_fraction * params.pattern_size,
                                        params.denoise_pattern)
        return patterns[f]

    polish = None if params.log_offset <= 0 else LogPolish(get_image, keys, params)

    def behind(f: int) -> int | None:   # the keyframe at or behind f (tracking order)
        cand = key_frames[key_frames <= f] if direction > 0 else key_frames[key_frames >= f]
        if not len(cand):
            return None
        return int(cand[-1] if direction > 0 else cand[0])

    def ahead(f: int) -> int | None:    # the first keyframe strictly ahead of f
        cand = key_frames[key_frames > f] if direction > 0 else key_frames[key_frames < f]
        if not len(cand):
            return None
        return int(cand[0] if direction > 0 else cand[-1])

    # the keyframe patterns are built first, so bad keyframes are refused up front
    prev_key = behind(start)
    if prev_key is None:   # tracking away from every keyframe: the nearest one
        prev_key = int(key_frames[np.argmin(np.abs(key_frames - start))])
    pattern(prev_key)
    next_key = ahead(start)
    if next_key is not None:
        pattern(next_key)

    total = abs(stop - start)
    if params.stop_after_n_frames:
        total = min(total, params.n_frames)
    frames = [start]
    xys = [pos.copy()]
    scores = [1.0 if start in keys else float("nan")]
    is_key = [start in keys]
    velocity = np.zeros(2)
    if start_velocity is not None and np.all(np.isfinite(np.asarray(start_velocity, float))):
        velocity = np.asarray(start_velocity, dtype=np.float64).reshape(2).copy()
    reason = STOP_END if total == abs(stop - start) else STOP_LIMIT
    refiners: dict[tuple[int, int | None, int], _Refiner] = {}
    key_contrast: dict[int, float] = {}   # per keyframe, for the appearance step
    # per keyframe, its skin and disc apart (the disc step); the skin's last shift
    disc_models: dict[int, target_disc.DiscModel | None] = {}
    disc_shift = np.zeros(2)

    def disc_model(k: int) -> target_disc.DiscModel | None:
        if k not in disc_models:
            disc_models[k] = target_disc.disc_model(get_image(k), keys[k], params.pattern_size)
        return disc_models[k]
    # keyframe pairs of different contrast: the fit's weights (None: not a fade)
    fades: dict[tuple[int, int], NDArray[np.float64] | None] = {}
    back_params = replace(params, distance_penalty=0.0, ambiguity_margin=0.0, near_px=0)
    back_params_first = replace(params, near_px=0, distance_penalty=0.0)
    # the previous frame, for the backwards check of long steps: the start frame too (a
    # keyframe's image is already decoded; get_image is the caller's cache)
    prev_frame = start
    # the motion is known once a step has been tracked (or given); until then the
    # prediction is a guess and the first step is checked strictly
    moving = start_velocity is not None and bool(np.any(velocity != 0))
    first_step: int | None = None   # index of the step taken while the motion was unknown
    prev_img = None
    f = start
    for done in range(1, total + 1):
        f = start + done * direction
        if f in keys:
            if params.stop_on_next_keyframe:
                reason = STOP_KEYFRAME
                break
            new = keys[f]
            velocity = new - pos
            pos = new.copy()
            prev_frame, prev_img = f, None
            frames.append(f)
            xys.append(pos.copy())
            scores.append(1.0)
            is_key.append(True)
            prev_key, next_key = f, ahead(f)
            pattern(f)
            if next_key is not None:
                pattern(next_key)
        else:
            img = get_image(f)
            if not shape:
                shape.append(img.shape[:2])
                _check_sizes(img.shape[:2], params)
            pp = patterns[prev_key]
            pn = patterns[next_key] if next_key is not None else None
            tpl = _blend(pp, pn, f)
            # the blend changes every frame between two keyframes; with one it is fixed
            rkey = (pp.frame, None if pn is None else pn.frame, f if pn is not None else 0)
            ref = refiners.get(rkey)
            if ref is None:
                ref = _Refiner(tpl, params.weight_fraction * params.pattern_size)
                if pn is None:
                    refiners[rkey] = ref
            # until the motion is known, the whole search region (and its ambiguity check)
            xy, score = match_patch(img, tpl, pos + velocity,
                                    params if moving else back_params_first, ref)
            if not moving and params.assign_first_step:
                prev_img = get_image(prev_frame) if prev_img is None else prev_img
                xy, score = _assigned_step(img, prev_img, tpl, ref, pos, velocity, xy, score,
                                           back_params)
            if np.all(np.isfinite(xy)) and (not moving
                                            or np.hypot(*(xy - pos)) > params.check_step_px):
                if prev_img is None:
                    prev_img = get_image(prev_frame)
                if not _consistent_backwards(img, prev_img, xy, pos, back_params,
                                             strict=not moving):
                    xy, score = np.array([np.nan, np.nan]), 0.0
            if pn is not None:   # a fade keyed as painted and as faded: a mixture
                xy, score = target_fade.fade_step(img, (pp.frame, pp.raw), (pn.frame, pn.raw),
                                                  f, pos + velocity, (xy, score), params,
                                                  fades)
            if polish is not None and np.all(np.isfinite(xy)):
                xy = polish(img, xy, score, pp.frame, None if pn is None else pn.frame, f)
            # this frame is one of those that confirm a first step taken with the
            # motion unknown: by the keyframe match alone (the disc fallbacks would
            # carry on a track whose first step found the wrong place, a fast lip
            # marker), and a loss here unmakes the whole run
            confirming = (first_step is not None
                          and len(frames) - first_step <= params.confirm_frames)
            if (params.follow_appearance and moving and not confirming
                    and np.all(np.isfinite(xy))
                    and params.break_threshold <= score < target_disc.POLISH_BELOW
                    and np.hypot(*velocity) >= target_disc.POLISH_SPEED_PX):
                # the keyframe match holds, but the disc may have slid onto a crease
                # that pulls it: the disc's own position where that differs
                xy_d, disc_shift = target_disc.disc_polish(
                    img, disc_model(pp.frame), xy, shift0=disc_shift)
                if xy_d is not None:
                    xy = xy_d
            if params.follow_appearance and moving and not score >= params.break_threshold:
                prev_img = get_image(prev_frame) if prev_img is None else prev_img
                if pp.frame not in key_contrast:
                    key_contrast[pp.frame] = target_appearance.keyframe_contrast(
                        get_image(pp.frame), keys[pp.frame], params)
                xy, score = target_appearance.appearance_step(
                    img, prev_img, pos, pos + velocity, tpl, params,
                    key_contrast[pp.frame], (xy, score))
                if not score >= params.break_threshold and not confirming:
                    # the marker sliding over its skin: the disc alone, the skin apart
                    xy_d, score_d, disc_shift = target_disc.disc_step(
                        img, disc_model(pp.frame), pos + velocity, shift0=disc_shift)
                    if score_d > score:
                        xy, score = xy_d, score_d
            prev_frame, prev_img = f, img
            frames.append(f)
            is_key.append(False)
            scores.append(score)
            if not np.all(np.isfinite(xy)) or score < params.break_threshold:
                xys.append(np.array([np.nan, np.nan]))
                reason = STOP_THRESHOLD
                if confirming:
                    # the track failed soon after its first step, taken with the motion
                    # unknown: that step is not confirmed. A neighbour that moved into
                    # the marker's place (or that a fast marker's first step found
                    # instead of it) passes every check of one frame and loses the match
                    # a few frames later; the run ends at the first step instead
                    del frames[first_step + 1:], is_key[first_step + 1:]
                    del scores[first_step + 1:], xys[first_step + 1:]
                    xys[first_step] = np.array([np.nan, np.nan])
                    scores[first_step] = 0.0
                break
            if not moving and score < params.confirm_score:
                first_step = len(frames) - 1
            velocity = xy - pos
            pos = xy
            moving = True
            xys.append(xy.copy())
        if on_frame is not None:
            on_frame(f, xys[-1], scores[-1])
        if progress is not None and progress(done, total) is False:
            reason = STOP_CANCELLED if f != start + total * direction else reason
            break
    return TargetTrackResult(np.array(frames, dtype=np.int64), np.array(xys, dtype=np.float64),
                             np.array(scores, dtype=np.float64), np.array(is_key, dtype=bool),
                             reason)


def _check_sizes(shape: tuple[int, ...], params: TargetTrackerParameters) -> None:
    H, W = shape[:2]
    if params.pattern_size + 4 > min(H, W):
        raise ValueError(f"the Pattern Size ({params.pattern_size} px) is larger than the "
                         f"{W} x {H} image")
