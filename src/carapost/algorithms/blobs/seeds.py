"""Seeds of the blob detector: candidate ellipses of one pyramid level.

On every level the surround is a grey opening with a window just larger than the
level's largest blob, so a blob is judged against the skin right around it; pixels at
least half their local peak contrast form regions whose outlines
(``cv2.findContours``) give the seed ellipses by their area moments, for all outlines
at once. Regions too large for the full-resolution level (a marker joined to a nostril,
a crease or the dark image border) are cut again at stricter fractions of their local
peak contrast; compact parts of the right size become *split* seeds.

Examples
--------
>>> import numpy as np, cv2
>>> from carapost.algorithms.blobs.seeds import level_seeds, surround
>>> d = np.full((48, 48), 20, np.uint8)           # a contrast image: blobs are bright
>>> _ = cv2.circle(d, (20, 24), 4, 200, -1)
>>> cx, cy, a, b, th, split, pedestal = level_seeds(d, surround(d, 11.0, d.shape, 1),
...                                                 1.0, 1.5, 11.0)
>>> np.round([cx[0], cy[0]], 1).tolist(), split.tolist()
([20.0, 24.0], [0.0])
"""

from __future__ import annotations

import math

import cv2
import numba
import numpy as np

__all__ = ["REL_FLOOR", "SEED_NOISE_FACTOR", "MIN_CONTRAST", "SEED_MIN_AREA",
           "SEED_MIN_AREA_FRACTION", "EXTENT_LOW_SCALE", "EXTENT_LOW_SLACK",
           "EXTENT_HIGH_SCALE", "EXTENT_HIGH_SLACK", "SPLIT_SEEDS", "SPLIT_LEVELS",
           "SPLIT_FILL", "surround", "contour_ellipses", "level_seeds"]

#: Minimum contrast of a candidate pixel as a fraction of the surround's headroom.
REL_FLOOR = 0.2
#: Seed floor in units of the image noise sigma (contrast of the smoothed top-hat).
SEED_NOISE_FACTOR = 3.0
#: Smallest peak contrast (grey levels) of a candidate, whatever the noise estimate.
MIN_CONTRAST = 5.0
#: Size filter of seed outlines, in px of their level (``a_lo``-``a_hi`` is the level's
#: band of semi-major axes). The ellipse area ``pi a b`` must reach SEED_MIN_AREA px (one
#: or two noisy pixels never seed) and SEED_MIN_AREA_FRACTION of ``a_lo^2``: a seed of
#: the smallest size may be as thin as about 1:6 (an oblique thin marker), a thinner
#: sliver is a crease or a hair.
SEED_MIN_AREA = 3.0
SEED_MIN_AREA_FRACTION = 0.5
#: The larger side of an outline's bounding box (+1 px) must lie in EXTENT_LOW_SCALE
#: ``a_lo`` - EXTENT_LOW_SLACK ... EXTENT_HIGH_SCALE ``a_hi`` + EXTENT_HIGH_SLACK. That
#: side of a filled ellipse of semi-major axis ``a`` is between about 1.4 ``a`` (a thin
#: ellipse at 45 degrees) and ``2 a + 1``; the bounds leave room for pixelised outlines
#: and reject outlines whose extent does not match their moment ellipse (the degenerate
#: outline of a one-pixel-wide line, a region with long thin branches). Regions above the
#: upper bound are cut again (split seeds).
EXTENT_LOW_SCALE = 1.2
EXTENT_LOW_SLACK = 2.0
EXTENT_HIGH_SCALE = 2.4
EXTENT_HIGH_SLACK = 6.0

_KERNEL_LOCALMAX = cv2.getStructuringElement(cv2.MORPH_RECT, (9, 9))
_KERNEL_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)
#: Seed inside regions of the full-resolution level that are too large for it by cutting
#: them again at stricter fractions of the local peak contrast (see _split_regions).
#: Coarser levels are not split: on carapost.synth their split seeds found no marker
#: that the full-resolution level missed, for ~2 ms per image.
SPLIT_SEEDS = True
SPLIT_LEVELS = (0.75, 0.9)
#: Smallest ratio of a split part's area to the area of its outline ellipse.
SPLIT_FILL = 0.85


def surround(d_small: np.ndarray, radius: float, shape: tuple[int, int],
             factor: int) -> np.ndarray:
    """Surround level: grey opening by a square just larger than a blob of semi-major
    axis ``radius`` (px of the level), computed on ``d_small`` (the level reduced by
    ``factor``, 1 or 2) and brought back to the level's ``shape``."""
    h, w = shape
    k = 2 * int(math.ceil(radius / factor)) + 3
    ker = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg = cv2.morphologyEx(d_small, cv2.MORPH_OPEN, ker, borderType=cv2.BORDER_REPLICATE)
    bg = cv2.blur(bg, (3, 3))
    if factor > 1:
        bg = cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR)
    return bg


def contour_ellipses(contours) -> tuple[np.ndarray, ...]:
    """Area moments of many closed polygons at once (all contours of a level).

    Returns per contour: centroid x, y, semi-axes a, b (``2 sqrt(eigenvalue)`` of the
    area second moments), angle, polygon area, bounding-box extent (px) and the number
    of polygon vertices. The vertices of all contours are joined into one array and
    Green's theorem sums over their edges are taken by :func:`_polygon_sums` (compiled).
    """
    lens = np.fromiter(map(len, contours), np.int64, len(contours))
    pts = np.concatenate(contours).reshape(-1, 2).astype(np.int64, copy=False)
    sums = _polygon_sums(pts, lens)
    area = 0.5 * sums[:, 0]
    sa = np.where(np.abs(area) > 1e-9, area, 1e-9)
    cx = sums[:, 1] / (6 * sa)
    cy = sums[:, 2] / (6 * sa)
    sxx = sums[:, 3] / (12 * sa) - cx * cx
    syy = sums[:, 4] / (12 * sa) - cy * cy
    sxy = sums[:, 5] / (24 * sa) - cx * cy
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0))
    a = 2 * np.sqrt(np.maximum(half_tr + root, 0))
    b = 2 * np.sqrt(np.maximum(half_tr - root, 0))
    th = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    return cx, cy, a, b, th, np.abs(area), sums[:, 6], lens


@numba.njit(cache=True, nogil=True)
def _polygon_sums(pts: np.ndarray, lens: np.ndarray) -> np.ndarray:  # pragma: no cover - jit
    """Green's theorem sums of closed polygons stored one after the other in ``pts``
    [N, 2] (``lens`` vertices each): twice the signed area, then the area moments
    x, y, x^2, y^2, xy (times 6, 6, 12, 12, 24 the signed area), and the larger side of
    the bounding box plus one (px). [n, 7]."""
    out = np.zeros((lens.size, 7))
    start = 0
    for k in range(lens.size):
        m = lens[k]
        s0 = s1 = s2 = s3 = s4 = s5 = 0.0
        xmin = xmax = pts[start, 0]
        ymin = ymax = pts[start, 1]
        for i in range(m):
            x, y = float(pts[start + i, 0]), float(pts[start + i, 1])
            nxt = start + i + 1 if i + 1 < m else start  # closes on its first vertex
            x1, y1 = float(pts[nxt, 0]), float(pts[nxt, 1])
            cr = x * y1 - x1 * y
            s0 += cr
            s1 += (x + x1) * cr
            s2 += (y + y1) * cr
            s3 += (x * (x + x1) + x1 * x1) * cr
            s4 += (y * (y + y1) + y1 * y1) * cr
            s5 += (x * y1 + 2 * (x * y + x1 * y1) + x1 * y) * cr
            xmin = min(xmin, pts[start + i, 0])
            xmax = max(xmax, pts[start + i, 0])
            ymin = min(ymin, pts[start + i, 1])
            ymax = max(ymax, pts[start + i, 1])
        o = out[k]
        o[0], o[1], o[2], o[3], o[4], o[5] = s0, s1, s2, s3, s4, s5
        o[6] = max(xmax - xmin, ymax - ymin) + 1
        start += m
    return out


def _in_band(a: np.ndarray, b: np.ndarray, ext: np.ndarray, a_lo: float, a_hi: float
             ) -> np.ndarray:
    """Outlines whose ellipse (semi-axes ``a``, ``b``) and bounding-box extent ``ext``
    fit the band ``a_lo``-``a_hi`` (see SEED_MIN_AREA and EXTENT_LOW_SCALE)."""
    ok = (a >= a_lo - 0.5) & (a <= a_hi) & (
        math.pi * a * b >= max(SEED_MIN_AREA, SEED_MIN_AREA_FRACTION * a_lo * a_lo))
    ok &= (ext >= EXTENT_LOW_SCALE * a_lo - EXTENT_LOW_SLACK) & (ext <= _extent_high(a_hi))
    return ok


def _extent_high(a_hi: float) -> float:
    """Largest bounding-box extent of a seed outline of the band up to ``a_hi``."""
    return EXTENT_HIGH_SCALE * a_hi + EXTENT_HIGH_SLACK


def level_seeds(d: np.ndarray, bg: np.ndarray, sigma: float, a_lo: float, a_hi: float,
                fine: bool = True) -> tuple[np.ndarray, ...]:
    """Seed ellipses of one pyramid level (all in that level's pixels).

    ``bg`` is the surround (an opening with a window just larger than ``a_hi``), so a
    blob is judged against skin right around it (a marker on the dark side of a shading
    edge does not merge with the dark skin). Candidates are connected regions at half
    their local peak contrast; the area moments of their outlines give the seeds.

    Parameters
    ----------
    d : ndarray [h, w] uint8
        Contrast image of the level (blobs are bright).
    bg : ndarray [h, w] uint8
        Its surround level (:func:`surround`).
    sigma : float
        Noise sigma of the level, grey levels.
    a_lo, a_hi : float
        Band of semi-major axes of the level (px of the level).
    fine : bool
        The full-resolution level: smoothed before the half-contrast test, and its
        over-size regions are cut again (``SPLIT_SEEDS``).

    Returns
    -------
    cx, cy, a, b, theta : ndarray [n]
        Seed centres, semi-axes (px) and angles (rad).
    split : ndarray [n]
        1.0 for seeds cut from an over-size region, else 0.0.
    pedestal : ndarray [n]
        Surround level under each seed centre (grey levels).
    """
    top = cv2.subtract(d, bg)
    t_low = max(MIN_CONTRAST, SEED_NOISE_FACTOR * sigma)
    # Light smoothing keeps pixel noise from shattering regions; reduced levels are
    # already smooth (and blurring them would join neighbouring dots of a dense grid).
    top_s = cv2.GaussianBlur(top, (5, 5), 1.0) if fine else top
    local_max = cv2.dilate(top_s, _KERNEL_LOCALMAX)
    half = cv2.compare(cv2.add(top_s, top_s), local_max, cv2.CMP_GE)
    floor = cv2.max(cv2.convertScaleAbs(cv2.bitwise_not(bg), alpha=REL_FLOOR), int(t_low))
    cand = cv2.bitwise_and(half, cv2.compare(top_s, floor, cv2.CMP_GE))
    contours, _ = cv2.findContours(cand, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return tuple(np.zeros(0) for _ in range(7))
    cx, cy, a, b, th, _area, ext, _nv = contour_ellipses(contours)
    # The outline runs through the centres of the region's border pixels, half a pixel
    # inside the region's edge.
    a, b = a + 0.5, b + 0.5
    ok = _in_band(a, b, ext, a_lo, a_hi)
    seeds = (cx[ok], cy[ok], a[ok], b[ok], th[ok], np.zeros(int(ok.sum())))
    if SPLIT_SEEDS and fine:
        big = np.flatnonzero((a > a_hi) | (ext > _extent_high(a_hi)))
        if big.size:
            # Cut on the unsmoothed contrast (a thin marker stays whole where the 5x5
            # blur spreads a crease over it) and on the smoothed one (at high noise the
            # unsmoothed cut breaks a thin marker into pieces that fail the fill test).
            extra = _split_regions([(top, None), (top_s, local_max)], cand,
                                   [contours[i] for i in big], a_lo, a_hi)
            seeds = tuple(np.concatenate([p, q]) for p, q in zip(seeds, extra, strict=True))
    # Surround level (the opening) under each seed centre: a blob sitting on a darker
    # pedestal (a pupil in its iris) has its ring plane well above it.
    h, w = d.shape
    sx = np.clip(np.rint(seeds[0]).astype(np.int64), 0, w - 1)
    sy = np.clip(np.rint(seeds[1]).astype(np.int64), 0, h - 1)
    return (*seeds, bg[sy, sx].astype(np.float64))


def _split_regions(sources, cand: np.ndarray, contours, a_lo: float, a_hi: float
                   ) -> tuple[np.ndarray, ...]:
    """Seeds inside regions too large for their level (a marker joined to a nostril, a
    crease or the dark image border by its half-contrast region).

    The pixels of those regions are cut again at stricter fractions (``SPLIT_LEVELS``)
    of their local peak contrast, on each contrast image of ``sources`` ((contrast,
    its 9x9 local maximum or None) pairs): the neck of partly dark pixels joining a
    marker to the dark feature falls below them before the marker's core does. Compact
    parts whose outline ellipse fits the level's size band and fills its ellipse are
    seeds (flag 1); the same part found several times is kept once, the first found.
    Only the bounding box of the rejected regions is processed.
    """
    pts = np.concatenate(contours).reshape(-1, 2)
    x0, y0 = int(pts[:, 0].min()), int(pts[:, 1].min())
    x1, y1 = int(pts[:, 0].max()) + 1, int(pts[:, 1].max()) + 1
    region = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(region, contours, -1, 255, -1, offset=(-x0, -y0))
    cv2.bitwise_and(region, cand[y0:y1, x0:x1], region)
    found = []
    for top, local_max in sources:
        # Contrast as a fraction of the local peak, in 1/255 steps.
        tb = top[y0:y1, x0:x1]
        lm = (cv2.dilate(tb, _KERNEL_LOCALMAX) if local_max is None
              else local_max[y0:y1, x0:x1])
        ratio = cv2.divide(tb, lm, scale=255)
        for q in SPLIT_LEVELS:
            sub = cv2.bitwise_and(region, cv2.compare(ratio, 255 * q, cv2.CMP_GE))
            # Isolated pixels (no 8-neighbour) are outlines of zero area, which no
            # filter below accepts; tracing them costs more than this.
            cv2.bitwise_and(sub, cv2.dilate(sub, _KERNEL_NEIGHBOURS), sub)
            cs, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE,
                                     offset=(x0, y0))
            found.extend(cs)
    if not found:
        return tuple(np.zeros(0) for _ in range(6))
    cx, cy, a, b, th, area, ext, _nv = contour_ellipses(found)
    a, b = a + 0.5, b + 0.5
    ok = _in_band(a, b, ext, a_lo, a_hi)
    # A marker's part is a filled ellipse; a crease or band cut into pieces is not.
    ok &= area >= SPLIT_FILL * math.pi * (a - 0.5) * (b - 0.5)
    i = np.flatnonzero(ok)
    cx, cy, a, b, th = cx[i], cy[i], a[i], b[i], th[i]
    if i.size > 1:
        # The same part found several times: keep the first copy.
        from scipy.spatial import cKDTree

        pairs = cKDTree(np.column_stack([cx, cy])).query_pairs(
            0.5 * float(b.max()) + 1.0, output_type="ndarray")
        keep = np.ones(cx.size, bool)
        if len(pairs):
            pi, pj = pairs.min(axis=1), pairs.max(axis=1)
            close = np.hypot(cx[pi] - cx[pj], cy[pi] - cy[pj]) <= (
                0.5 * np.minimum(b[pi], b[pj]) + 1.0)
            keep[pj[close]] = False
        cx, cy, a, b, th = cx[keep], cy[keep], a[keep], b[keep], th[keep]
    return cx, cy, a, b, th, np.ones(cx.size)
