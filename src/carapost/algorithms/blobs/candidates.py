"""All blob candidates of one colour in one image: seeds on every pyramid level,
refinement at the blob's own scale, appearance, probability, one copy per blob.

Examples
--------
>>> import numpy as np, cv2
>>> from carapost.algorithms.blobs import BLACK, blob_candidates
>>> img = np.full((64, 64), 200, np.uint8)
>>> _ = cv2.circle(img, (32, 30), 6, 20, -1)
>>> c = blob_candidates(img, BLACK, 4.0, 50.0)
>>> np.round(c.centre[c.score > 0.4]).tolist()
[[32.0, 30.0]]
"""

from __future__ import annotations

import cv2
import numpy as np

from carapost.algorithms.blobs.appearance import (
    CONTEXT_EXTENT,
    PATCH_EXTENT,
    appearance_features,
)
from carapost.algorithms.blobs.detections import BLACK, FEATURE_NAMES, N_REFINED, Candidates
from carapost.algorithms.blobs.image import noise_sigma
from carapost.algorithms.blobs.pyramid import (
    MIN_RADIUS_TOLERANCE,
    area_pyramid,
    level_bands,
    stack_levels,
)
from carapost.algorithms.blobs.refine import REFINE_RADIUS, refine_seeds
from carapost.algorithms.blobs.score import blob_probability
from carapost.algorithms.blobs.seeds import level_seeds, surround

__all__ = ["SATURATED", "blob_candidates"]

#: Grey level from which a pixel counts as saturated.
SATURATED = 250


def blob_candidates(
    image8: np.ndarray,
    colour: int,
    min_radius: float,
    max_radius: float,
    *,
    mask: np.ndarray | None = None,
    noise: float | None = None,
) -> Candidates:
    """All candidate blobs of one colour with their features (before thresholding).

    Seeds come from a small image pyramid (each level judges blobs of its own size
    band against their own surround), then every seed is refined on the finest level
    where it is at most ``REFINE_RADIUS`` level px, and scored.

    Parameters
    ----------
    image8 : ndarray [H, W] uint8
    colour : 0 (black) or 1 (white)
    min_radius, max_radius : float
        Range of the major-axis length (``2 a``, the longest ellipse axis) in px, as
        Min / Max Radius; candidates outside it are dropped.
    mask : ndarray [H, W] bool or uint8, optional
        Only candidates whose centre pixel is non-zero in the mask are kept.
    noise : float, optional
        Image noise sigma in grey levels (estimated when omitted).

    Returns
    -------
    Candidates
    """
    h, w = image8.shape
    sigma = noise_sigma(image8) if noise is None else float(noise)
    a_min, a_max = 0.5 * min_radius, 0.5 * max_radius  # semi-major axis range
    levels = [lv for lv in level_bands(a_min, a_max)
              if h // lv[0] >= 16 and w // lv[0] >= 16]
    # Pyramid of the raw image (each level an area reduction of the previous one); the
    # surround of level f is computed on level 2f.
    raws = area_pyramid(image8, 2 * levels[-1][0] if levels else 1)

    # Contrast image of each level (the inverted image for black blobs).
    pyramid = {f: x if colour != BLACK else cv2.bitwise_not(x) for f, x in raws.items()}

    def surround_source(f: int) -> np.ndarray:
        # Saturated highlights are not a surround level: hide them from the opening so
        # the skin between two highlights keeps its own level (they give no contrast).
        if colour != BLACK:
            return pyramid[f]
        return cv2.max(pyramid[f], cv2.compare(raws[f], SATURATED, cv2.CMP_GE))

    seeds = []
    for f, lo, hi in levels:
        dl = pyramid[f]
        r = hi / f
        if r >= 6 and 2 * f in pyramid:
            bg = surround(surround_source(2 * f), r, dl.shape, 2)
        else:
            bg = surround(surround_source(f), r, dl.shape, 1)
        sx, sy, sa, sb, st, sp, sbg = level_seeds(
            dl, bg, max(0.7, sigma / f), max(lo / f, 1.0), r, fine=f == 1)
        # A level pixel i covers full-res pixels f*i .. f*i + f - 1.
        seeds.append((sx * f + 0.5 * (f - 1), sy * f + 0.5 * (f - 1), sa * f, sb * f, st,
                      np.full(sx.size, f), sp, sbg))
    empty = Candidates(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                       np.zeros((0, len(FEATURE_NAMES))), np.zeros(0, bool), np.zeros(0))
    if not seeds:
        return empty
    cx, cy, a, b, th, lev, split, open_bg = (np.concatenate([s[i] for s in seeds])
                                             for i in range(8))
    if cx.size == 0:
        return empty
    # Refine each seed on the finest level where it is at most REFINE_RADIUS level-px
    # (moments of an area-reduced image equal those of the original, and the pixel
    # variance removed in the moments is that of the reduced pixel).
    g = np.ones(cx.size, np.int64)
    while True:
        up = (a > REFINE_RADIUS * g) & np.isin(2 * g, list(pyramid))
        if not up.any():
            break
        g[up] *= 2
    # All levels in one buffer (shared by the refinement and the appearance sampling),
    # so each patch size is one gather for every level.
    levels = stack_levels(pyramid)
    dbuf = levels.buf
    lw, lh, lb = levels.at(g)
    o = 0.5 * (g - 1)
    sig = np.maximum(0.7, sigma / g)
    sx, sy, sa, sb = (cx - o) / g, (cy - o) / g, a / g, b / g
    cx2, cy2, a2, b2, th2, feats, saturated, ok = refine_seeds(
        dbuf, lw, lh, lb, sig, sx, sy, sa, sb, th, open_bg, colour)
    cx2, cy2, a2, b2 = cx2 * g + o, cy2 * g + o, a2 * g, b2 * g
    ok &= (2 * a2 >= min_radius - MIN_RADIUS_TOLERANCE) & (2 * a2 <= max_radius)
    if mask is not None:
        mc = np.asarray(mask)[np.clip(np.rint(cy2).astype(np.int64), 0, h - 1),
                              np.clip(np.rint(cx2).astype(np.int64), 0, w - 1)]
        ok &= mc.astype(bool)
    idx = np.flatnonzero(ok)
    look = np.zeros((cx2.size, len(FEATURE_NAMES) - N_REFINED - 1))
    # both grids in one call: the candidates twice, ellipse-aligned then context
    m = idx.size
    both = appearance_features(
        levels, sigma, np.tile(np.column_stack([cx2[idx], cy2[idx]]), (2, 1)),
        np.tile(a2[idx], 2), np.concatenate([np.maximum(b2[idx], 1.0), a2[idx]]),
        np.tile(th2[idx], 2), np.repeat([PATCH_EXTENT, CONTEXT_EXTENT], m))
    look[idx] = np.hstack([both[:m], both[m:]])
    feats = np.column_stack([feats, look, split])
    score = blob_probability(feats[idx])
    # The same blob seen on two levels (close and of similar size): keep the copy the
    # model finds more blob-like (the finer level's on a tie).
    if idx.size > 1 and np.unique(lev[idx]).size > 1:
        from scipy.spatial import cKDTree

        pts = np.column_stack([cx2[idx], cy2[idx]])
        pairs = cKDTree(pts).query_pairs(0.5 * float(a2[idx].max()) + 1.0,
                                         output_type="ndarray")
        drop = np.zeros(idx.size, bool)
        if len(pairs):
            i, j = pairs[:, 0], pairs[:, 1]
            dist = np.hypot(*(pts[i] - pts[j]).T)
            same = (lev[idx[i]] != lev[idx[j]]) & (
                dist <= 0.5 * np.minimum(b2[idx[i]], b2[idx[j]]) + 1.0)
            # ... and of a similar size (texture inside a large dot is not the dot).
            same &= np.abs(np.log(a2[idx[i]] / a2[idx[j]])) < 0.4
            pi, pj = score[i], score[j]
            worse = np.where((pi < pj) | ((pi == pj) & (lev[idx[i]] > lev[idx[j]])), i, j)
            drop[worse[same]] = True
        idx, score = idx[~drop], score[~drop]
    return Candidates(
        centre=np.column_stack([cx2, cy2])[idx],
        axes=np.column_stack([a2, b2])[idx],
        angle=th2[idx],
        features=feats[idx],
        saturated=saturated[idx],
        score=score,
    )
