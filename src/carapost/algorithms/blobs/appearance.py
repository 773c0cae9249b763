"""Appearance features of blob candidates: their surroundings on an ellipse-aligned grid
and on a wider context grid, scaled to the candidate's contrast and folded about both
axes.

Examples
--------
>>> import numpy as np, cv2
>>> from carapost.algorithms.blobs.appearance import appearance_features
>>> from carapost.algorithms.blobs.pyramid import stack_levels
>>> d = np.full((48, 48), 30, np.uint8)              # contrast image (blobs bright)
>>> _ = cv2.circle(d, (24, 24), 5, 220, -1)
>>> look = appearance_features(stack_levels({1: d}), 1.0, np.array([[24.0, 24.0]]),
...                            np.array([5.0]), np.array([5.0]), np.zeros(1), 2.0)
>>> look.shape, round(float(look[0, 0]), 2)           # the centre sample: full contrast
((1, 27), 1.0)
"""

from __future__ import annotations

import numpy as np

from carapost.algorithms.blobs._appearance_jit import sample_fold
from carapost.algorithms.blobs.pyramid import Levels

__all__ = ["PATCH_SIZE", "PATCH_EXTENT", "CONTEXT_EXTENT", "appearance_features"]

#: Appearance grids: PATCH_SIZE x PATCH_SIZE samples spanning +-PATCH_EXTENT semi-axes
#: along each ellipse axis (the minor one at least 1 px), and +-CONTEXT_EXTENT
#: semi-major axes in both directions.
PATCH_SIZE = 9
PATCH_EXTENT = 2.0
CONTEXT_EXTENT = 4.0


def appearance_features(levels: Levels, sigma: float, centre: np.ndarray,
                        su: np.ndarray, sv: np.ndarray, angle: np.ndarray,
                        extent: float | np.ndarray) -> np.ndarray:
    """Appearance features of candidates: their surroundings on an ellipse-aligned grid.

    The contrast image is sampled (bilinear, compiled) at PATCH_SIZE x PATCH_SIZE
    points spanning +-``extent`` x ``su`` along the major axis and +-``extent`` x ``sv``
    along the minor axis, on the pyramid level whose pixels are about the grid spacing
    (so large blobs are not aliased). Samples are scaled to the blob: 0 at the median of
    the grid's outer ring, 1 at the mean of the central 3 x 3 samples (the scale at
    least 3 noise sigmas), clipped to +-1.5. A blob shows as a centred bump; a marker
    running into a crease or a shadow, a motion streak, the end of a hair or a nostril's
    rim each leave their own pattern. The grid is folded about both axes (mean of the
    four mirror images: the 5 x 5 quarter), so the features do not depend on the sign
    of the ellipse angle; the mean absolute difference from the mirror image along each
    axis keeps the asymmetry.

    Parameters
    ----------
    levels : Levels
        The contrast pyramid in one buffer (:func:`~.pyramid.stack_levels`).
    sigma : float
        Noise sigma of the full-resolution image, grey levels.
    centre : ndarray [N, 2]; angle : ndarray [N]
        The refined candidates at full resolution (px, rad).
    su, sv : ndarray [N]
        Grid scale along the major and the minor axis (px).
    extent : float or ndarray [N]
        Half-width of the grid in units of ``su`` / ``sv`` (both grids of the detector
        are sampled in one call, the candidates stacked twice).

    Returns
    -------
    ndarray [N, 27] float64 (one group of appearance features, in FEATURE_NAMES order)
    """
    n, k = len(centre), PATCH_SIZE
    out = np.zeros((n, (k // 2 + 1) ** 2 + 2))
    if n == 0:
        return out
    ext = np.broadcast_to(np.asarray(extent, np.float64), (n,))
    su = ext * np.asarray(su, np.float64)
    sv = ext * np.asarray(sv, np.float64)
    # level whose pixel is at most the grid spacing along the major axis
    spacing = 2.0 * su / (k - 1)
    g = np.ones(n, np.int64)
    for f in levels.factor[1:]:
        g[spacing >= f] = f
    lw, lh, lb = levels.at(g)
    sample_fold(levels.buf, lb, lw, lh, g.astype(np.float64), max(3.0 * sigma, 2.0),
                np.ascontiguousarray(centre[:, 0], np.float64),
                np.ascontiguousarray(centre[:, 1], np.float64), su, sv,
                np.cos(angle).astype(np.float64), np.sin(angle).astype(np.float64), k, out)
    return out
