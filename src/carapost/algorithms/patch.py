"""Patch matching: a grey-level template searched by normalised cross-correlation.

Used by the tracker for point-cameras that found no blob (patch tracking), and meant for
the Target Tracker. The template is the square patch around a point in one image; the
search window is the same patch size plus a radius around the predicted position in the
next image; the score is OpenCV's ``TM_CCOEFF_NORMED`` and the peak is refined to
sub-pixel by a parabola through its neighbours along each axis.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["patch_search"]


def patch_search(prev_image: NDArray[Any], image: NDArray[Any], prev_uv: ArrayLike,
                 pred_uv: ArrayLike, size: int, radius: float
                 ) -> tuple[NDArray[np.float64], float]:
    """Find the patch around ``prev_uv`` of ``prev_image`` near ``pred_uv`` in ``image``.

    Parameters
    ----------
    prev_image, image : ndarray (H, W)
        Grey images of the previous and current frame.
    prev_uv, pred_uv : array_like, shape (2,)
        Patch centre in the previous image, predicted centre in the current one (px).
    size : int
        Patch side (px, made odd).
    radius : float
        Search radius (px).

    Returns
    -------
    uv : ndarray, shape (2,)
        Best match (sub-pixel; NaN when the patch does not fit the images).
    score : float
        Its normalised cross-correlation (-1..1; -1 when not found).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> img = rng.random((60, 80)).astype(np.float32)
    >>> moved = np.roll(img, (2, 3), axis=(0, 1))  # content moves 3 px right, 2 px down
    >>> uv, score = patch_search(img, moved, (40.0, 30.0), (42.0, 31.0), 11, 6.0)
    >>> uv.round(1).tolist(), round(score, 3)
    ([43.0, 32.0], 1.0)
    """
    half = int(size) // 2
    r = int(math.ceil(radius))
    H, W = image.shape[:2]
    px, py = (int(round(v)) for v in prev_uv)
    cx, cy = (int(round(v)) for v in pred_uv)
    nan = np.array([np.nan, np.nan])
    if not (half <= px < W - half and half <= py < prev_image.shape[0] - half):
        return nan, -1.0
    tpl = prev_image[py - half:py + half + 1, px - half:px + half + 1].astype(np.float32)
    x0, x1 = max(cx - r - half, 0), min(cx + r + half + 1, W)
    y0, y1 = max(cy - r - half, 0), min(cy + r + half + 1, H)
    win = image[y0:y1, x0:x1].astype(np.float32)
    if win.shape[0] < tpl.shape[0] or win.shape[1] < tpl.shape[1] or tpl.std() < 1e-3:
        return nan, -1.0
    res = cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED)
    _, best, _, loc = cv2.minMaxLoc(res)
    bx, by = loc
    dx = dy = 0.0
    if 0 < bx < res.shape[1] - 1:
        a, b, c = res[by, bx - 1], res[by, bx], res[by, bx + 1]
        den = a - 2 * b + c
        dx = 0.5 * (a - c) / den if den < 0 else 0.0
    if 0 < by < res.shape[0] - 1:
        a, b, c = res[by - 1, bx], res[by, bx], res[by + 1, bx]
        den = a - 2 * b + c
        dy = 0.5 * (a - c) / den if den < 0 else 0.0
    uv = np.array([x0 + bx + half + dx, y0 + by + half + dy], dtype=np.float64)
    if np.hypot(uv[0] - pred_uv[0], uv[1] - pred_uv[1]) > radius:
        return nan, -1.0
    return uv, float(best)
