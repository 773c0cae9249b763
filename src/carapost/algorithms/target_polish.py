"""The keyframe match's position polished on log grey levels (a marker over darker skin).

A marker's ink darkens the skin under it by a factor: the image is ``skin * (1 - ink)``.
On grey levels the marker therefore looks fainter where it lies over darker skin, and a
marker that slides over a dark line (an upper-lid marker crossing the lid crease and the
lash line as the eye closes) loses contrast on the side that is over the line: the
Lucas-Kanade refinement of :mod:`carapost.algorithms.target_track`, fitting one gain to
the whole pattern, is pulled towards the side that is still over bright skin. On the
synthetic blink take, 3-4 frames before the marker disappears, that is 0.3-0.7 px with a
match score of 0.90-0.98, so nothing tells the artist.

On log grey levels the ink is an additive layer, ``log skin + log(1 - ink)``, whose
look does not depend on the skin under it. :class:`LogPolish` refines the position found
on grey levels once more on ``L = (128 + c) log((g + c) / (128 + c)) + 128`` (``c`` the
Log Offset: the scale is the grey level's at mid-grey, and ``c`` keeps the near-black
pixels finite), against the keyframe patterns sampled the same way. Each pixel of the fit
is weighted by the inverse of its noise variance on that scale, ``((g + c) / (128 +
c))^2`` at the pattern's grey level ``g``: the sensor's noise is in grey levels, and the
log stretches it where the image is dark. Only the position is polished: the search, its
ambiguity and identity checks and the match score stay on grey levels, where a marker on
dark lips and one on pale skin do not look alike.

Only matches scoring below `POLISH_BELOW` are polished. Measured side by side
(``benchmarks/target_track.py --compare-log-offset 16``, docs/benchmarks.md): blink
recovery 0.908 -> 0.920 (held out 0.895 -> 0.902), speech and fast a little more
accurate, noise 5 with motion blur a little less (median 0.055 -> 0.059 px: the log
stretches the noise of the dark pixels more than the weights give back, and a blurred
ink is no longer a factor). Hence ``log_offset`` is 0 (off) by default.

Coordinates are raw pixels with OpenCV's pixel-centre convention, as everywhere in
carapost.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_POLISH_PX", "POLISH_BELOW", "LogPolish", "log_grey"]

#: A polish that moves the grey-level position farther than this (px) is not taken: the
#: two scales found different things.
MAX_POLISH_PX = 1.0
#: Only a keyframe match scoring below this is polished: one at or above it matches the
#: keyframe's look nearly perfectly (a marker on even skin, far from any occlusion), and
#: the polish would cost CPU (about 40 % of a frame) for changes of a few thousandths of
#: a pixel.
POLISH_BELOW = 0.98

_TABLES: dict[float, NDArray[np.float32]] = {}


def log_grey(image: NDArray[Any], offset: float) -> NDArray[np.float32]:
    """Grey levels -> ``(128 + offset) log((g + offset) / (128 + offset)) + 128``.

    Parameters
    ----------
    image : ndarray
        Grey levels (uint8: through a lookup table; any other real dtype: computed).
    offset : float
        The Log Offset ``c`` (grey levels, > 0).

    Returns
    -------
    ndarray, the shape of ``image``, float32
        Equal to ``g`` at mid-grey (128), with slope 1 there.

    Examples
    --------
    >>> log_grey(np.array([0, 128, 255], np.uint8), 16.0).astype(float).round(1).tolist()
    [-188.4, 128.0, 219.1]
    """
    if image.dtype == np.uint8:
        lut = _TABLES.get(offset)
        if lut is None:
            lut = _TABLES[offset] = _formula(np.arange(256, dtype=np.float64), offset)
        return lut[image]
    return _formula(np.asarray(image, dtype=np.float64), offset)


def _formula(g: NDArray[np.float64], c: float) -> NDArray[np.float32]:
    return ((128.0 + c) * np.log(np.maximum(g + c, 1e-6) / (128.0 + c)) + 128.0
            ).astype(np.float32)


class _LogView:
    """An image seen on log grey levels, converted crop by crop (``image[a:b, c:d]``)."""

    def __init__(self, image: NDArray[Any], offset: float) -> None:
        self.image, self.offset, self.shape = image, offset, image.shape

    def __getitem__(self, key: Any) -> NDArray[np.float32]:
        return log_grey(self.image[key], self.offset)


class LogPolish:
    """One run's log-grey-level polish of the keyframe matches (see the module).

    Parameters
    ----------
    get_image : callable
        ``get_image(frame) -> (H, W)`` grey image of the camera.
    keyframes : mapping of int to ndarray (2,)
        The run's keyframe positions (raw px).
    params : TargetTrackerParameters
        Pattern Size, the Gaussian window, the Lucas-Kanade iterations and tolerance,
        and ``log_offset`` (> 0).
    """

    def __init__(self, get_image: Callable[[int], NDArray[Any]],
                 keyframes: Mapping[int, NDArray[np.float64]], params: Any) -> None:
        self.get_image, self.keys, self.params = get_image, keyframes, params
        self.offset = float(params.log_offset)
        self.patterns: dict[int, Any] = {}
        self.raws: dict[int, NDArray[np.float32]] = {}
        self.refiners: dict[tuple[int, int | None, int], Any] = {}

    def _pattern(self, f: int) -> Any:
        from carapost.algorithms.target_track import _make_pattern, sample_patch
        if f not in self.patterns:
            img = self.get_image(f)
            P = self.params.pattern_size
            self.patterns[f] = _make_pattern(_LogView(img, self.offset), self.keys[f], f, P)
            self.raws[f] = sample_patch(img, self.keys[f], P)
        return self.patterns[f]

    def _refiner(self, prev_key: int, next_key: int | None, frame: int) -> Any:
        from carapost.algorithms.target_track import _blend, _Refiner
        rkey = (prev_key, next_key, frame if next_key is not None else 0)
        ref = self.refiners.get(rkey)
        if ref is not None:
            return ref
        pp = self._pattern(prev_key)
        pn = self._pattern(next_key) if next_key is not None else None
        tpl = _blend(pp, pn, frame)
        raw = self.raws[prev_key].astype(np.float64)
        if pn is not None and pn.frame != pp.frame:   # blended like the patterns
            dp, dn = abs(frame - pp.frame), abs(pn.frame - frame)
            w = dp / float(dp + dn)
            raw = (1.0 - w) * raw + w * self.raws[next_key]
        c = self.offset
        noise = (np.maximum(raw + c, 1e-3) / (128.0 + c)) ** 2
        ref = _Refiner(tpl, self.params.weight_fraction * self.params.pattern_size,
                       noise_weight=noise)
        if next_key is None:    # a fixed pattern: kept for the run
            self.refiners[rkey] = ref
        return ref

    def __call__(self, image: NDArray[Any], xy: NDArray[np.float64], score: float,
                 prev_key: int, next_key: int | None, frame: int) -> NDArray[np.float64]:
        """The position ``xy`` (raw px) found on grey levels in ``image`` at ``frame``
        (its match ``score``), polished on log grey levels against the keyframe patterns
        of ``prev_key`` and ``next_key``; ``xy`` itself when the score is at least
        `POLISH_BELOW`, or the polish fails or moves it farther than `MAX_POLISH_PX`."""
        if not score < POLISH_BELOW:
            return xy
        P = self.params.pattern_size
        half = P // 2 + 6
        H, W = image.shape[:2]
        cx, cy = int(round(float(xy[0]))), int(round(float(xy[1])))
        x0, y0 = max(cx - half, 0), max(cy - half, 0)
        x1, y1 = min(cx + half + 1, W), min(cy + half + 1, H)
        if x1 - x0 < P + 6 or y1 - y0 < P + 6:
            return xy
        crop = log_grey(np.asarray(image[y0:y1, x0:x1]), self.offset).astype(np.float64)
        ref = self._refiner(prev_key, next_key, frame)
        p, ncc, _ = ref.refine(crop, (x0, y0), np.array(xy, dtype=np.float64),
                               self.params.max_iterations, self.params.tolerance_px)
        if not (np.all(np.isfinite(p)) and ncc > 0
                and np.hypot(*(p - xy)) <= MAX_POLISH_PX):
            return xy
        return p
