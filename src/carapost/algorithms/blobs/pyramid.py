"""The image pyramid of the blob detector: size bands per level, area reductions, and
all levels in one buffer for the compiled kernels.

A level reduced by ``f`` is responsible for blobs whose semi-major axis is up to
``LEVEL_RADIUS`` of its own pixels; neighbouring bands overlap by ``LEVEL_OVERLAP``.

Examples
--------
>>> import numpy as np
>>> from carapost.algorithms.blobs.pyramid import area_pyramid, level_bands, stack_levels
>>> [f for f, _lo, _hi in level_bands(2.0, 25.0)]  # Min / Max Radius 4-50 px
[1, 2, 4]
>>> pyr = area_pyramid(np.zeros((64, 96), np.uint8), 4)
>>> {f: im.shape for f, im in pyr.items()}
{1: (64, 96), 2: (32, 48), 4: (16, 24)}
>>> lv = stack_levels(pyr)
>>> lv.buf.size, lv.start.tolist()
(8064, [0, 6144, 7680])
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

__all__ = ["MIN_RADIUS_TOLERANCE", "LEVEL_RADIUS", "LEVEL_OVERLAP", "level_bands",
           "area_pyramid", "Levels", "stack_levels"]

#: Tolerance (px) below Min Radius on the measured major-axis length (2 a).
MIN_RADIUS_TOLERANCE = 1.0
#: Largest semi-major axis (px of its own level) a pyramid level is responsible for.
LEVEL_RADIUS = 10.0
#: Overlap between neighbouring levels' radius bands (fraction).
LEVEL_OVERLAP = 0.15


def level_bands(a_min: float, a_max: float) -> list[tuple[int, float, float]]:
    """Pyramid levels (factor, lowest, highest semi-major axis in full-res px) for
    semi-major axes ``a_min``-``a_max`` (px)."""
    a_tol = 0.5 * MIN_RADIUS_TOLERANCE
    out = []
    f, lo = 1, 0.0
    while True:
        hi = LEVEL_RADIUS * f
        band_lo = lo * (1 - LEVEL_OVERLAP)
        band_hi = hi * (1 + LEVEL_OVERLAP)
        if band_lo > a_max:
            break
        if band_hi >= a_min - a_tol:
            out.append((f, max(band_lo, a_min - a_tol - 0.5), min(band_hi, a_max + 1.0)))
        lo, f = hi, 2 * f
    return out


def area_pyramid(image8: np.ndarray, top_f: int) -> dict[int, np.ndarray]:
    """Area reductions of ``image8`` by 1, 2, 4, ... up to ``top_f`` ({factor: image}),
    each from the previous one, while a level keeps at least 4 x 4 px."""
    h, w = image8.shape
    raws = {1: image8}
    f = 1
    while 2 * f <= top_f and (h // (2 * f)) >= 4 and (w // (2 * f)) >= 4:
        src = raws[f]
        hh, ww = src.shape[0] // 2, src.shape[1] // 2
        raws[2 * f] = cv2.resize(src[: 2 * hh, : 2 * ww], (ww, hh),
                                 interpolation=cv2.INTER_AREA)
        f *= 2
    return raws


class Levels(NamedTuple):
    """Pyramid levels flattened one after the other into one buffer."""

    buf: np.ndarray  # [sum of level sizes] uint8
    factor: np.ndarray  # [L] reduction factor of each level, ascending
    width: np.ndarray  # [L]
    height: np.ndarray  # [L]
    start: np.ndarray  # [L] offset of each level in buf

    def at(self, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Width, height and buffer offset of the level with factor ``g`` (per item)."""
        i = np.searchsorted(self.factor, g)
        return self.width[i], self.height[i], self.start[i]


def stack_levels(pyramid: dict[int, np.ndarray]) -> Levels:
    """All levels of ``pyramid`` ({factor: image}) in one buffer."""
    factor = sorted(pyramid)
    sizes = [pyramid[f].size for f in factor]
    return Levels(np.concatenate([pyramid[f].reshape(-1) for f in factor]),
                  np.array(factor, np.int64),
                  np.array([pyramid[f].shape[1] for f in factor], np.int64),
                  np.array([pyramid[f].shape[0] for f in factor], np.int64),
                  np.cumsum([0, *sizes[:-1]]).astype(np.int64))
