"""Blob (painted marker) detection in camera images.

The detector turns one grey image into a table of elliptical blob detections, each with
a sub-pixel centre, semi-axes, angle, colour (black / white) and a calibrated
probability ``score`` that it is really a blob centre. All steps work on whole images
with OpenCV or on all candidates at once with numpy (no Python loop per pixel or blob):

1. Polarity: black blobs are found on the inverted image, so blobs are always bright
   peaks ``d`` on a darker surround.
2. Seeds per scale: a small pyramid (1x, 2x, 4x, ... reduced copies) gives each level a
   band of blob sizes (semi-major axis up to ~10 px of that level). On every level the
   surround is a grey opening with a window just larger than the band's largest blob,
   so a blob is judged against the skin right around it (the opening runs on the next
   coarser level); pixels at least half their local peak contrast form regions whose
   outlines (``cv2.findContours``) give the seed ellipses by their area moments, for
   all outlines at once. Regions too large for the full-resolution level (a marker
   joined to a nostril, a crease or the dark image border) are cut again at stricter
   fractions of their local peak contrast; compact parts of the right size become
   *split* seeds.
3. Refinement at the blob's own scale: per seed, a plane fitted (twice, the second time
   without ring pixels far above the first plane) to a ring of pixels around the seed
   ellipse is the local background, which removes shading gradients; each pixel's
   coverage is its contrast over the plane divided by the peak contrast, clipped to
   0-1, inside the seed ellipse grown by 1.5 px. Its centroid is the sub-pixel centre
   and its second moments the ellipse (``a = 2 sqrt(lambda_1)``). Seeds larger than
   ~14 px are refined on a reduced copy (moments survive area reduction). Seeds are
   grouped by patch size; within a group all pixel sums and quadratic forms are
   products with one fixed design matrix.
4. Probability: a logistic model over scale-free features (signal-to-noise, contrast
   relative to the surround, how well the coverage fills its ellipse, ring roughness,
   symmetry, axis ratio, how much of the ring is as dark as the blob, how far the ring
   plane sits above the surround) gives the probability that the candidate is a blob
   centre; split seeds have a model of their own. It was fitted on synthetic images
   with known truth by ``scripts/train_blob_model.py`` (weights in
   ``carapost/resources/blob_model.json``). Candidates whose semi-major axis is outside
   the radius range, or whose score is below the threshold, are dropped; the same blob
   seen on two levels is kept once.

Fully saturated regions (255) have no contrast against their surround and give no
detections; white candidates that are mostly saturated are rejected.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import math
import sys
import threading
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from functools import cache, lru_cache
from importlib import resources
from typing import NamedTuple

import cv2
import numpy as np

__all__ = [
    "BlobParameters",
    "BlobDetections",
    "detect_blobs",
    "detect_blobs_batch",
    "preview_blobs",
    "blob_candidates",
    "FEATURE_NAMES",
]

BLACK = 0
WHITE = 1

#: Names of the per-candidate features fed to the probability model (in order).
FEATURE_NAMES = (
    "log_snr",
    "rel_contrast",
    "fill_dev",
    "half_fill_dev",
    "ring_roughness",
    "asymmetry",
    "axis_ratio",
    "ring_fill",
    "pedestal",
    "split",
)
#: Features measured by the refinement (the last one, ``split``, comes from the seed).
_N_REFINED = len(FEATURE_NAMES) - 1


@dataclass(frozen=True)
class BlobParameters:
    """The Blob Parameters section of the properties (names and defaults of the guide).

    Attributes
    ----------
    find_black_blobs, find_white_blobs : bool
        Which marker colours to search for (default black only).
    black_min_radius, black_max_radius, white_min_radius, white_max_radius : float
        Accepted range of the semi-major axis (longest ellipse radius) in px
        (default 4-50).
    black_threshold, white_threshold : float
        Minimum probability (0-1) that a candidate is a blob centre (default 0.4):
        0 accepts almost anything, 1 only perfect blobs.

    Raises
    ------
    ValueError
        If a radius is not positive and finite, min > max, or a threshold is
        outside 0-1 (the message names the parameter).
    """

    find_black_blobs: bool = True
    find_white_blobs: bool = False
    black_min_radius: float = 4.0
    black_max_radius: float = 50.0
    black_threshold: float = 0.4
    white_min_radius: float = 4.0
    white_max_radius: float = 50.0
    white_threshold: float = 0.4

    def __post_init__(self) -> None:
        for colour in ("black", "white"):
            lo = getattr(self, f"{colour}_min_radius")
            hi = getattr(self, f"{colour}_max_radius")
            th = getattr(self, f"{colour}_threshold")
            for name, val in ((f"{colour}_min_radius", lo), (f"{colour}_max_radius", hi)):
                if not isinstance(val, int | float) or not math.isfinite(val) or val <= 0:
                    raise ValueError(f"BlobParameters.{name} must be a positive number of "
                                     f"pixels, got {val!r}")
                if val > 1000:
                    raise ValueError(f"BlobParameters.{name} must be at most 1000 px, "
                                     f"got {val!r}")
            if lo > hi:
                raise ValueError(f"BlobParameters.{colour}_min_radius ({lo}) must not exceed "
                                 f"{colour}_max_radius ({hi})")
            if not isinstance(th, int | float) or not (0.0 <= th <= 1.0):
                raise ValueError(f"BlobParameters.{colour}_threshold must be in 0-1, got {th!r}")
        for name in ("find_black_blobs", "find_white_blobs"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ValueError(f"BlobParameters.{name} must be a bool, "
                                 f"got {getattr(self, name)!r}")


class BlobDetections(NamedTuple):
    """Blob detections of one image (all arrays of length N, possibly 0).

    Attributes
    ----------
    centre : ndarray [N, 2] float32
        Sub-pixel centre (x, y) in px; the centre of the top-left pixel is (0, 0).
    axes : ndarray [N, 2] float32
        Semi-axes in px, major first.
    angle : ndarray [N] float32
        Direction of the major axis in radians, from +x towards +y, in [-pi/2, pi/2).
    colour : ndarray [N] int8
        0 = black blob, 1 = white blob.
    score : ndarray [N] float32
        Probability (0-1) that the detection is a blob centre.
    """

    centre: np.ndarray
    axes: np.ndarray
    angle: np.ndarray
    colour: np.ndarray
    score: np.ndarray

    @staticmethod
    def empty() -> BlobDetections:
        """No detections."""
        return BlobDetections(
            np.zeros((0, 2), np.float32),
            np.zeros((0, 2), np.float32),
            np.zeros(0, np.float32),
            np.zeros(0, np.int8),
            np.zeros(0, np.float32),
        )

    def __len__(self) -> int:  # noqa: D105 - number of detections, not of fields
        return int(self.centre.shape[0])

    @staticmethod
    def concatenate(parts: Sequence[BlobDetections]) -> BlobDetections:
        """Join several detection tables into one."""
        if not parts:
            return BlobDetections.empty()
        return BlobDetections(*(np.concatenate([p[i] for p in parts]) for i in range(5)))


class Candidates(NamedTuple):
    """All blob candidates of one polarity before the probability threshold.

    ``features`` is [N, len(FEATURE_NAMES)] float64; other fields as in
    :class:`BlobDetections`.
    """

    centre: np.ndarray
    axes: np.ndarray
    angle: np.ndarray
    features: np.ndarray
    saturated: np.ndarray


# --------------------------------------------------------------------------- model


#: The two models of ``blob_model.json``: candidates from ordinary seeds and candidates
#: from seeds found by splitting an over-size region (indexed by the ``split`` feature),
#: with the number of leading FEATURE_NAMES each one uses. ``pedestal`` (a blob on a
#: darker plateau, such as a pupil in its iris) only matters for split seeds: an ordinary
#: seed's region already ends where its surround begins.
MODEL_KINDS = ("seed", "split")
MODEL_INPUTS = {"seed": 8, "split": 9}


@lru_cache(maxsize=1)
def _model() -> tuple[tuple[np.ndarray, float, np.ndarray, np.ndarray], ...]:
    """Load the logistic models (weights, bias, feature mean, feature scale), one per
    entry of MODEL_KINDS."""
    text = resources.files("carapost").joinpath("resources/blob_model.json").read_text()
    m = json.loads(text)
    if tuple(m.get("features", ())) != FEATURE_NAMES or set(m.get("models", {})) != set(
            MODEL_KINDS):
        raise RuntimeError("carapost/resources/blob_model.json does not match FEATURE_NAMES; "
                           "re-run scripts/train_blob_model.py")
    out = []
    for kind in MODEL_KINDS:
        k = m["models"][kind]
        if len(k["weights"]) != len(expand_features(np.zeros((1, len(FEATURE_NAMES))),
                                                    MODEL_INPUTS[kind])[0]):
            raise RuntimeError(f"carapost/resources/blob_model.json: model {kind!r} has the "
                               "wrong number of weights; re-run scripts/train_blob_model.py")
        out.append((np.asarray(k["weights"], np.float64), float(k["bias"]),
                    np.asarray(k["mean"], np.float64), np.asarray(k["scale"], np.float64)))
    return tuple(out)


def expand_features(features: np.ndarray, n: int) -> np.ndarray:
    """Model inputs: the first ``n`` features, their squares and pairwise products.

    Parameters
    ----------
    features : ndarray [N, F] (F = len(FEATURE_NAMES))
    n : int
        Number of leading features used (MODEL_INPUTS of the model).

    Returns
    -------
    ndarray [N, n + n (n + 1) / 2]
    """
    f = np.asarray(features, np.float64)[:, :n]
    iu, ju = np.triu_indices(f.shape[1])
    return np.hstack([f, f[:, iu] * f[:, ju]])


def blob_probability(features: np.ndarray) -> np.ndarray:
    """Calibrated probability that each candidate is a blob centre.

    Candidates from split seeds (``split`` feature 1) have their own model: they are
    rarer, and a dark feature next to them changes what their other features mean.

    Parameters
    ----------
    features : ndarray [N, len(FEATURE_NAMES)]

    Returns
    -------
    ndarray [N] float64 in 0-1
    """
    features = np.asarray(features, np.float64)
    kind = (features[:, -1] > 0.5).astype(np.int64)
    z = np.zeros(len(features))
    for k, (w, b, mean, scale) in enumerate(_model()):
        sel = kind == k
        if sel.any():
            x = expand_features(features[sel], MODEL_INPUTS[MODEL_KINDS[k]])
            z[sel] = ((x - mean) / scale) @ w + b
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))


# --------------------------------------------------------------------------- memory


@lru_cache(maxsize=1)
def _keep_freed_memory() -> bool:
    """Let glibc's malloc reuse freed image-sized buffers instead of returning them to
    the kernel after every image.

    The detector makes ~40 image-sized temporaries per image (OpenCV outputs, numpy
    patch stacks). With glibc's defaults every one above 128 KB is a fresh ``mmap``
    whose pages fault in on first touch, which cost ~40 % of the detector's CPU time
    (measured: 13.9 -> 8.1 ms per 1280x720 image). Raising the mmap threshold to
    16 MB and the trim threshold to 128 MB keeps such buffers in the heap (the price:
    the process keeps up to ~128 MB of freed memory for reuse). Called once, on the
    first detection; a no-op (False) on platforms without glibc ``mallopt``.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_mmap_threshold, 16 << 20)) and bool(
        mallopt(m_trim_threshold, 128 << 20))


# --------------------------------------------------------------------------- input


def _as_uint8(image: np.ndarray) -> np.ndarray:
    """Validate the image and bring it to 8 bits (uint16 is shifted to its bit depth)."""
    if not isinstance(image, np.ndarray):
        raise TypeError(f"image must be a numpy array, got {type(image).__name__}")
    if image.ndim != 2:
        raise ValueError(f"image must be a 2-D grey image [H, W], got shape {image.shape}")
    if image.shape[0] < 8 or image.shape[1] < 8:
        raise ValueError(f"image is too small for blob detection: {image.shape}")
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    if image.dtype == np.uint16:
        # Keep the 8 most significant bits of the bits actually used, so a 10- or
        # 12-bit image keeps its full range and its saturation maps to 255.
        top = int(image.max())
        bits = max(8, top.bit_length())
        return np.ascontiguousarray((image >> (bits - 8)).astype(np.uint8))
    raise TypeError(f"image must be uint8 or uint16, got {image.dtype}")


def _noise_sigma(img: np.ndarray) -> float:
    """Robust noise level (grey levels) from horizontal neighbour differences."""
    sub = img[::8, :]
    m = sub.shape[1] // 2  # the pairs (0, 1), (2, 3), ...
    d = cv2.absdiff(sub[:, 1:2 * m:2], sub[:, 0:2 * m:2])
    # Median from a histogram (exactly np.median of the uint8 differences, 10x faster).
    cum = np.cumsum(np.bincount(d.ravel(), minlength=256))
    n = int(cum[-1])
    lo = int(np.searchsorted(cum, (n - 1) // 2, side="right"))
    hi = int(np.searchsorted(cum, n // 2, side="right"))
    # Median absolute difference of a Gaussian pair is 0.954 sigma.
    med = 0.5 * (lo + hi)
    return max(0.7, 1.4826 * med / math.sqrt(2.0) if med > 0 else 0.7)


# --------------------------------------------------------------------------- core

#: Minimum contrast of a candidate pixel as a fraction of the surround's headroom.
REL_FLOOR = 0.2
#: Tolerance (px) below Min Radius on the measured semi-major axis.
MIN_RADIUS_TOLERANCE = 0.5
#: Grey level from which a pixel counts as saturated.
SATURATED = 250
#: Smallest peak contrast (grey levels) of a candidate, whatever the noise estimate.
MIN_CONTRAST = 5.0
#: Largest semi-major axis (px of its own level) a pyramid level is responsible for.
LEVEL_RADIUS = 10.0
#: Overlap between neighbouring levels' radius bands (fraction).
LEVEL_OVERLAP = 0.15
#: Margin (px) of the refinement support beyond the seed ellipse, and ring width (px).
SUPPORT_MARGIN = 1.5
RING_WIDTH = 3.0
#: Seeds larger than this (px of a level) are refined on the next coarser level.
REFINE_RADIUS = 14.0

_KERNEL_LOCALMAX = cv2.getStructuringElement(cv2.MORPH_RECT, (9, 9))
_KERNEL_PEAK = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))
#: Seed inside regions of the full-resolution level that are too large for it by cutting
#: them again at stricter fractions of the local peak contrast (see _split_regions).
#: Coarser levels are not split: on carapost.synth their split seeds found no marker
#: that the full-resolution level missed, for ~2 ms per image.
SPLIT_SEEDS = True
SPLIT_LEVELS = (0.6, 0.75, 0.9)
#: Smallest ratio of a split part's area to the area of its outline ellipse.
SPLIT_FILL = 0.85
#: Fifth-round options, off by default (the shipped model is trained without them):
#: refine split seeds on their own part grown by PART_GROW px (negative: on the whole
#: support ellipse), and cut over-size regions on the unsmoothed contrast (SPLIT_RAW),
#: which keeps a thin marker whole where the 5x5 blur spreads the crease over it. With
#: both on and a retrained model, recall on carapost.synth is 0.984 (0.981 without),
#: but the Process-menu tracking test then sees one face point switch markers.
PART_GROW = -1
SPLIT_RAW = False


def _background(d_small: np.ndarray, radius: float, shape: tuple[int, int],
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


def _ellipse_from_moments(s0, sx, sy, sxx, syy, sxy):
    """Centre, semi-axes and angle from raw weighted moments (arrays per candidate)."""
    s0 = np.maximum(s0, 1e-9)
    mx, my = sx / s0, sy / s0
    cxx = np.maximum(sxx / s0 - mx * mx - 1.0 / 12.0, 1e-6)  # less a pixel's own variance
    cyy = np.maximum(syy / s0 - my * my - 1.0 / 12.0, 1e-6)
    cxy = sxy / s0 - mx * my
    tr = cxx + cyy
    root = np.sqrt(((cxx - cyy) * 0.5) ** 2 + cxy * cxy)
    a = 2.0 * np.sqrt(tr * 0.5 + root)
    b = 2.0 * np.sqrt(np.maximum(tr * 0.5 - root, 1e-6))
    theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    return mx, my, a, b, theta


def _contour_ellipses(contours) -> tuple[np.ndarray, ...]:
    """Area moments of many closed polygons at once (all contours of a level).

    Returns per contour: centroid x, y, semi-axes a, b (``2 sqrt(eigenvalue)`` of the
    area second moments), angle, polygon area, bounding-box extent (px) and the number
    of polygon vertices. Green's theorem sums over the edges are gathered for all
    contours into one array and summed with ``ufunc.reduceat``.
    """
    lens = np.fromiter((len(c) for c in contours), np.int64, len(contours))
    pts = np.concatenate(contours).reshape(-1, 2).astype(np.float64)
    starts = np.zeros(lens.size, np.int64)
    np.cumsum(lens[:-1], out=starts[1:])
    nxt = np.arange(1, pts.shape[0] + 1)
    nxt[starts + lens - 1] = starts  # each polygon closes on its own first vertex
    x, y = pts[:, 0], pts[:, 1]
    x1, y1 = x[nxt], y[nxt]
    cr = x * y1 - x1 * y
    area = 0.5 * np.add.reduceat(cr, starts)
    sa = np.where(np.abs(area) > 1e-9, area, 1e-9)
    cx = np.add.reduceat((x + x1) * cr, starts) / (6 * sa)
    cy = np.add.reduceat((y + y1) * cr, starts) / (6 * sa)
    sxx = np.add.reduceat((x * x + x * x1 + x1 * x1) * cr, starts) / (12 * sa) - cx * cx
    syy = np.add.reduceat((y * y + y * y1 + y1 * y1) * cr, starts) / (12 * sa) - cy * cy
    sxy = (np.add.reduceat((x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y) * cr, starts)
           / (24 * sa) - cx * cy)
    half_tr = 0.5 * (sxx + syy)
    root = np.sqrt(np.maximum(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0))
    a = 2 * np.sqrt(np.maximum(half_tr + root, 0))
    b = 2 * np.sqrt(np.maximum(half_tr - root, 0))
    th = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    ext = np.maximum(np.maximum.reduceat(x, starts) - np.minimum.reduceat(x, starts),
                     np.maximum.reduceat(y, starts) - np.minimum.reduceat(y, starts)) + 1
    return cx, cy, a, b, th, np.abs(area), ext, lens


def _level_seeds(d: np.ndarray, bg: np.ndarray, sigma: float, a_lo: float, a_hi: float,
                 fine: bool = True) -> tuple[np.ndarray, ...]:
    """Seed ellipses of one pyramid level (all in that level's pixels).

    ``bg`` is the surround (an opening with a window just larger than ``a_hi``), so a
    blob is judged against skin right around it (a marker on the dark side of a shading
    edge does not merge with the dark skin). Candidates are connected regions at half
    their local peak contrast; the area moments of their outlines give the seeds.
    """
    top = cv2.subtract(d, bg)
    t_low = max(MIN_CONTRAST, 4.0 * sigma)
    # Light smoothing keeps pixel noise from shattering regions; reduced levels are
    # already smooth (and blurring them would join neighbouring dots of a dense grid).
    top_s = cv2.GaussianBlur(top, (5, 5), 1.0) if fine else top
    local_max = cv2.dilate(top_s, _KERNEL_LOCALMAX)
    half = cv2.compare(cv2.add(top_s, top_s), local_max, cv2.CMP_GE)
    floor = cv2.max(cv2.convertScaleAbs(cv2.bitwise_not(bg), alpha=REL_FLOOR), int(t_low))
    cand = cv2.bitwise_and(half, cv2.compare(top_s, floor, cv2.CMP_GE))
    contours, _ = cv2.findContours(cand, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return (*(np.zeros(0) for _ in range(7)), [])
    cx, cy, a, b, th, _area, ext, _nv = _contour_ellipses(contours)
    # The outline runs through the centres of the region's border pixels, half a pixel
    # inside the region's edge.
    a, b = a + 0.5, b + 0.5
    ok = (a >= a_lo - 0.5) & (a <= a_hi) & (math.pi * a * b >= max(3.0, 0.5 * a_lo * a_lo))
    ok &= (ext >= 1.2 * a_lo - 2) & (ext <= 2.4 * a_hi + 6)
    seeds = (cx[ok], cy[ok], a[ok], b[ok], th[ok], np.zeros(int(ok.sum())))
    parts = [None] * int(ok.sum())
    if SPLIT_SEEDS and fine:
        big = np.flatnonzero((a > a_hi) | (ext > 2.4 * a_hi + 6))
        if big.size:
            *extra, outlines = _split_regions(top if SPLIT_RAW else top_s, local_max, cand,
                                              [contours[i] for i in big], a_lo, a_hi)
            seeds = tuple(np.concatenate([p, q]) for p, q in zip(seeds, extra, strict=True))
            parts.extend(outlines)
    # Surround level (the opening) under each seed centre: a blob sitting on a darker
    # pedestal (a pupil in its iris) has its ring plane well above it.
    h, w = d.shape
    sx = np.clip(np.rint(seeds[0]).astype(np.int64), 0, w - 1)
    sy = np.clip(np.rint(seeds[1]).astype(np.int64), 0, h - 1)
    return (*seeds, bg[sy, sx].astype(np.float64), parts)


def _split_regions(top: np.ndarray, local_max: np.ndarray, cand: np.ndarray, contours,
                   a_lo: float, a_hi: float) -> tuple[np.ndarray, ...]:
    """Seeds inside regions too large for their level (a marker joined to a nostril, a
    crease or the dark image border by its half-contrast region).

    The pixels of those regions are cut again at stricter fractions (``SPLIT_LEVELS``)
    of their local peak contrast: the neck of partly dark pixels joining a marker to
    the dark feature falls below them before the marker's core does. Compact parts
    whose outline ellipse fits the level's size band and fills its ellipse are seeds
    (flag 1); the same part found at several fractions is kept once, from the lowest
    fraction. Only the bounding box of the rejected regions is processed.
    """
    pts = np.concatenate(contours).reshape(-1, 2)
    x0, y0 = int(pts[:, 0].min()), int(pts[:, 1].min())
    x1, y1 = int(pts[:, 0].max()) + 1, int(pts[:, 1].max()) + 1
    region = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(region, contours, -1, 255, -1, offset=(-x0, -y0))
    cv2.bitwise_and(region, cand[y0:y1, x0:x1], region)
    # Contrast as a fraction of the local peak, in 1/255 steps.
    if SPLIT_RAW:
        tb = top[y0:y1, x0:x1]
        ratio = cv2.divide(tb, cv2.dilate(tb, _KERNEL_LOCALMAX), scale=255)
    else:
        ratio = cv2.divide(top[y0:y1, x0:x1], local_max[y0:y1, x0:x1], scale=255)
    found = []
    for q in SPLIT_LEVELS:
        sub = cv2.bitwise_and(region, cv2.compare(ratio, 255 * q, cv2.CMP_GE))
        cs, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE,
                                 offset=(x0, y0))
        found.extend(cs)
    if not found:
        return (*(np.zeros(0) for _ in range(6)), [])
    cx, cy, a, b, th, area, ext, _nv = _contour_ellipses(found)
    a, b = a + 0.5, b + 0.5
    ok = (a >= a_lo - 0.5) & (a <= a_hi) & (math.pi * a * b >= max(3.0, 0.5 * a_lo * a_lo))
    ok &= (ext >= 1.2 * a_lo - 2) & (ext <= 2.4 * a_hi + 6)
    # A marker's part is a filled ellipse; a crease or band cut into pieces is not.
    ok &= area >= SPLIT_FILL * math.pi * (a - 0.5) * (b - 0.5)
    i = np.flatnonzero(ok)
    cx, cy, a, b, th = cx[i], cy[i], a[i], b[i], th[i]
    if i.size > 1:
        # The same part at several fractions: keep the first (largest) copy.
        d = np.hypot(cx[:, None] - cx[None], cy[:, None] - cy[None])
        keep = ~np.triu(d <= 0.5 * np.minimum(b[:, None], b[None]) + 1.0, 1).any(axis=0)
        cx, cy, a, b, th, i = cx[keep], cy[keep], a[keep], b[keep], th[keep], i[keep]
    return cx, cy, a, b, th, np.ones(cx.size), [found[k] for k in i]


#: Half-widths (px) of the square patch classes used by the refinement.
_PATCH_RADII = (6, 8, 10, 13, 17, 22)


@cache
def _design(r: int) -> np.ndarray:
    """[P*P, 6] float32 columns 1, x, y, x^2, y^2, xy of a (2r+1)^2 patch (row-major,
    coordinates relative to the patch centre)."""
    off = np.arange(-r, r + 1, dtype=np.float32)
    y, x = np.meshgrid(off, off, indexing="ij")
    x, y = x.ravel(), y.ravel()
    return np.ascontiguousarray(np.column_stack([np.ones_like(x), x, y, x * x, y * y, x * y]))


def _refine(d: np.ndarray, raw: np.ndarray, lw: np.ndarray, lh: np.ndarray, lb: np.ndarray,
            sigma: np.ndarray, cx, cy, a, b, th, open_bg, colour: int, parts=None):
    """Centre, ellipse and features of seed ellipses, each on its own pyramid level.

    ``d`` and ``raw`` are the flattened levels (contrast image, raw image) one after the
    other; per seed ``lw``, ``lh`` are its level's width and height, ``lb`` the start
    of its level in the buffers, ``sigma`` the level's noise and the geometry is in
    that level's pixels.

    Per candidate, a plane fitted to a ring of pixels around the seed ellipse is the
    local background (so a shading gradient neither shifts the centre nor changes the
    contrast); each pixel's coverage is its contrast over that plane relative to the
    paint's level, clipped to 0-1 (the painted fraction of an anti-aliased pixel); the
    coverage moments inside the support give the centre and ellipse.

    Seeds are grouped by the size of the square patch that holds their ring. Within a
    group every patch has the same pixel grid, so all sums over pixels (plane normal
    equations, moments) and all quadratic forms over pixels (ellipse masks, planes) are
    products with one fixed design matrix [P*P, 6] (BLAS), and the rest is a handful of
    whole-array operations on the stack of patches [n, P*P].

    ``parts`` (object array [n], optional) holds, for split seeds, the outline of the
    split part (full-res pixels); their support is limited to that part grown by
    ``PART_GROW`` px, so the dark feature the marker was cut from (a crease along a
    thin marker) does not count as coverage.
    """
    n = cx.size
    if parts is None:
        parts = np.full(n, None, object)
    m = SUPPORT_MARGIN
    ai, bi = a + m, b + m
    ao, bo = ai + RING_WIDTH, bi + RING_WIDTH
    c, s = np.cos(th), np.sin(th)
    need = np.ceil(np.maximum(np.sqrt((ao * c) ** 2 + (bo * s) ** 2),
                              np.sqrt((ao * s) ** 2 + (bo * c) ** 2)) + 0.5)
    radii = np.asarray(_PATCH_RADII)
    cls = np.minimum(np.searchsorted(radii, need), radii.size - 1)
    out = np.zeros((n, 6 + _N_REFINED))
    for ci in np.unique(cls):
        i = np.flatnonzero(cls == ci)
        out[i] = _refine_patches(d, raw, lw[i], lh[i], lb[i], sigma[i], int(radii[ci]),
                                 cx[i], cy[i], ai[i], bi[i], ao[i], bo[i], c[i], s[i], a[i],
                                 open_bg[i], colour, parts[i])
    return (out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4], out[:, 6:],
            out[:, 5] > 1.5, out[:, 5] > 0)


def _refine_patches(d, raw, w, h, lb, sigma, r, cx, cy, ai, bi, ao, bo, c, s, a, open_bg,
                    colour, parts):
    """:func:`_refine` for seeds whose ring fits a (2r+1)-pixel square patch.

    Returns [n, 6 + F]: centre x, y, semi-axes, angle, status (0 rejected, 1 kept,
    2 kept but saturated), features.
    """
    g = _design(r)
    gt = np.ascontiguousarray(g.T)
    off = np.arange(-r, r + 1)
    xi, yi = np.rint(cx).astype(np.int64), np.rint(cy).astype(np.int64)
    cols, rows = xi[:, None] + off, yi[:, None] + off  # [n, P]
    w, h = w[:, None], h[:, None]
    valid = (((rows >= 0) & (rows < h))[:, :, None]
             & ((cols >= 0) & (cols < w))[:, None, :]).reshape(len(cx), -1)
    cols = np.clip(cols, 0, w - 1)
    rows = np.clip(rows, 0, h - 1)
    flat = ((rows * w + lb[:, None])[:, :, None] + cols[:, None, :]).reshape(len(cx), -1)
    dv = np.take(d, flat).astype(np.float32)  # [n, P*P]
    dx, dy = cx - xi, cy - yi  # seed centre in patch coordinates

    def quad(ea, eb):
        # (u / ea)^2 + (v / eb)^2 about the seed centre, u / v along the ellipse axes,
        # expanded on the design columns.
        ea2, eb2 = 1.0 / (ea * ea), 1.0 / (eb * eb)
        qa, qc = c * c * ea2 + s * s * eb2, s * s * ea2 + c * c * eb2
        qb = 2 * c * s * (ea2 - eb2)
        k = np.column_stack([qa * dx * dx + qc * dy * dy + qb * dx * dy,
                             -2 * qa * dx - qb * dy, -2 * qc * dy - qb * dx, qa, qc, qb])
        return k.astype(np.float32) @ gt

    support = (quad(ai, bi) <= 1.0) & valid
    ring = (quad(ao, bo) <= 1.0) & valid & ~support
    sel = np.flatnonzero([q is not None for q in parts])
    if sel.size and PART_GROW >= 0:
        # Split seeds: coverage only on the split part (grown by PART_GROW px to take
        # its anti-aliased edge), drawn from its outline; the ring stays as it is.
        p = 2 * r + 1
        pm = np.zeros((sel.size, p, p), np.uint8)
        for j, k in enumerate(sel):
            o = (int(r - xi[k]), int(r - yi[k]))
            cv2.drawContours(pm[j], [parts[k]], -1, 1, -1, offset=o)
            if PART_GROW > 0:
                cv2.drawContours(pm[j], [parts[k]], -1, 1, 2 * PART_GROW + 1, offset=o)
        support[sel] &= pm.reshape(sel.size, -1).astype(bool)
    supf, ringf = support.astype(np.float32), ring.astype(np.float32)
    g3t = gt[:3]

    def plane(wgt):
        # Weighted least-squares plane dv ~ c0 + c1 x + c2 y over the pixels in wgt.
        sg = (wgt @ g).astype(np.float64)  # n0, sx, sy, sxx, syy, sxy
        sd = ((wgt * dv) @ g[:, :3]).astype(np.float64)
        n0, sx, sy, sxx, syy, sxy = sg.T
        mat = np.stack([sg[:, [0, 1, 2]], sg[:, [1, 3, 5]], sg[:, [2, 5, 4]]], 1)
        mat += np.eye(3) * 1e-3
        coef = np.linalg.solve(mat, sd[..., None])[..., 0]
        few = n0 < 3
        coef[few] = 0.0
        coef[few, 0] = sd[few, 0] / np.maximum(n0[few], 1)
        return coef, n0

    neg = np.float32(-1e9)
    coef, _ = plane(ringf)
    res = dv - coef.astype(np.float32) @ g3t
    # Second pass without ring pixels well above the plane (a neighbouring marker's
    # edge, a dark crease): they would lift the background under this blob.
    peak = np.where(support, res, neg).max(axis=1)
    ring2 = ringf * (res < np.maximum(3.0 * sigma, 0.25 * peak)[:, None])
    coef, n_ring = plane(ring2)
    bgp = coef.astype(np.float32) @ g3t
    res = dv - bgp
    peak = np.where(support, res, neg).max(axis=1).astype(np.float64)
    pk = np.maximum(peak, 1e-3).astype(np.float32)[:, None]
    # Paint is opaque: a fully covered pixel has the paint's level whatever the skin
    # under it, so the full-coverage contrast is (paint level - plane) at each pixel,
    # not one number per blob (which would weight the centroid towards brighter skin).
    core = np.where(support, dv, neg).max(axis=1)[:, None]
    full = np.maximum(core - bgp, 0.25 * pk)
    cov = np.clip(res / full, 0.0, 1.0) * supf
    mom = (cov @ g).astype(np.float64)
    s0 = mom[:, 0]
    mx, my, a2, b2, th2 = _ellipse_from_moments(*mom.T)
    above = res >= 0.5 * pk
    half = (above & support).astype(np.float32)
    hm = (half @ g[:, :3]).astype(np.float64)
    n_half = hm[:, 0]
    hx, hy = hm[:, 1] / np.maximum(n_half, 1), hm[:, 2] / np.maximum(n_half, 1)
    n_r = np.maximum(ringf.sum(axis=1).astype(np.float64), 1)
    rr = np.sqrt(np.einsum("ij,ij->i", ring2 * res, res) / np.maximum(n_ring, 1))
    ring_fill = np.count_nonzero(above & ring, axis=1) / n_r
    ell_area = math.pi * a2 * b2
    bg_c = np.clip(coef[:, 0] + coef[:, 1] * dx + coef[:, 2] * dy, 0, 255)
    rv = np.take(raw, flat)
    sat_level = 255 if colour == WHITE else 0
    saturated = np.count_nonzero((rv == sat_level) & (half > 0), axis=1) > 0.3 * n_half
    feats = np.column_stack([
        np.log(np.maximum(peak, 1e-3) / sigma),
        np.clip(peak / np.maximum(255.0 - bg_c, 1.0), 0, 2),
        np.clip(np.abs(1.0 - s0 / ell_area), 0, 5),
        np.clip(np.abs(1.0 - n_half / ell_area), 0, 5),
        np.clip(rr / np.maximum(peak, 1e-3), 0, 2),
        np.clip(np.hypot(hx - mx, hy - my) / np.maximum(b2, 0.5), 0, 5),
        b2 / a2,
        ring_fill,
        np.clip((bg_c - open_bg) / np.maximum(peak, 1e-3), -2, 5),
    ])
    ok = (peak > 0) & np.isfinite(feats).all(axis=1) & (n_half > 0)
    # A refined centre far from its seed means the support did not hold the blob.
    ok &= np.hypot(mx - dx, my - dy) <= 0.5 * a + 1.0
    status = np.where(ok, np.where(saturated, 2.0, 1.0), 0.0)
    return np.column_stack([xi + mx, yi + my, a2, b2, th2, status, feats])


def _levels(min_radius: float, max_radius: float) -> list[tuple[int, float, float]]:
    """Pyramid levels (factor, lowest, highest semi-major axis in full-res px)."""
    out = []
    f, lo = 1, 0.0
    while True:
        hi = LEVEL_RADIUS * f
        band_lo = lo * (1 - LEVEL_OVERLAP)
        band_hi = hi * (1 + LEVEL_OVERLAP)
        if band_lo > max_radius:
            break
        if band_hi >= min_radius - MIN_RADIUS_TOLERANCE:
            out.append((f, max(band_lo, min_radius - MIN_RADIUS_TOLERANCE - 0.5),
                        min(band_hi, max_radius + 1.0)))
        lo, f = hi, 2 * f
    return out


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
    band against their own surround), then every seed is refined at full resolution.

    Parameters
    ----------
    image8 : ndarray [H, W] uint8
    colour : 0 (black) or 1 (white)
    min_radius, max_radius : float
        Semi-major axis range in px; candidates outside it are dropped.
    mask : ndarray [H, W] bool or uint8, optional
        Only candidates whose centre pixel is non-zero in the mask are kept.
    noise : float, optional
        Image noise sigma in grey levels (estimated when omitted).

    Returns
    -------
    Candidates
    """
    h, w = image8.shape
    sigma = _noise_sigma(image8) if noise is None else float(noise)
    levels = [lv for lv in _levels(min_radius, max_radius)
              if h // lv[0] >= 16 and w // lv[0] >= 16]
    # Pyramid of the raw image (each level an area reduction of the previous one); the
    # surround of level f is computed on level 2f.
    top_f = 2 * levels[-1][0] if levels else 1
    raws = {1: image8}
    f = 1
    while 2 * f <= top_f and (h // (2 * f)) >= 4 and (w // (2 * f)) >= 4:
        src = raws[f]
        hh, ww = src.shape[0] // 2, src.shape[1] // 2
        raws[2 * f] = cv2.resize(src[: 2 * hh, : 2 * ww], (ww, hh),
                                 interpolation=cv2.INTER_AREA)
        f *= 2

    def polar(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if colour != BLACK:
            return x, x
        d = cv2.bitwise_not(x)
        # Saturated highlights are not a surround level: hide them from the opening so
        # the skin between two highlights keeps its own level (they give no contrast).
        return d, cv2.max(d, cv2.compare(x, SATURATED, cv2.CMP_GE))

    pyramid = {f: polar(x) for f, x in raws.items()}
    seeds, parts = [], []
    for f, lo, hi in levels:
        dl, bl = pyramid[f]
        r = hi / f
        if r >= 6 and 2 * f in pyramid:
            bg = _background(pyramid[2 * f][1], r, dl.shape, 2)
        else:
            bg = _background(bl, r, dl.shape, 1)
        sx, sy, sa, sb, st, sp, sbg, sparts = _level_seeds(
            dl, bg, max(0.7, sigma / f), max(lo / f, 1.0), r, fine=f == 1)
        # Split parts exist on the full-resolution level only (their outlines are in
        # full-res pixels and the parts are refined there: semi-major axis <= 11.5).
        parts.extend(sparts)
        # A level pixel i covers full-res pixels f*i .. f*i + f - 1.
        seeds.append((sx * f + 0.5 * (f - 1), sy * f + 0.5 * (f - 1), sa * f, sb * f, st,
                      np.full(sx.size, f), sp, sbg))
    empty = Candidates(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                       np.zeros((0, len(FEATURE_NAMES))), np.zeros(0, bool))
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
    # All levels in one buffer, so each patch size is one gather for every level.
    used = [int(f) for f in np.unique(g)]
    base, off = {}, 0
    for f in used:
        base[f] = off
        off += pyramid[f][0].size
    dbuf = np.concatenate([pyramid[f][0].reshape(-1) for f in used])
    rbuf = np.concatenate([raws[f].reshape(-1) for f in used])
    lw = np.array([pyramid[f][0].shape[1] for f in used])[np.searchsorted(used, g)]
    lh = np.array([pyramid[f][0].shape[0] for f in used])[np.searchsorted(used, g)]
    lb = np.array([base[f] for f in used])[np.searchsorted(used, g)]
    o = 0.5 * (g - 1)
    part_arr = np.empty(len(parts), object)
    part_arr[:] = parts
    cx2, cy2, a2, b2, th2, feats, saturated, ok = _refine(
        dbuf, rbuf, lw, lh, lb, np.maximum(0.7, sigma / g), (cx - o) / g, (cy - o) / g,
        a / g, b / g, th, open_bg, colour, part_arr)
    cx2, cy2, a2, b2 = cx2 * g + o, cy2 * g + o, a2 * g, b2 * g
    feats = np.column_stack([feats, split])
    ok &= (a2 >= min_radius - MIN_RADIUS_TOLERANCE) & (a2 <= max_radius)
    if mask is not None:
        mc = np.asarray(mask)[np.clip(np.rint(cy2).astype(np.int64), 0, h - 1),
                              np.clip(np.rint(cx2).astype(np.int64), 0, w - 1)]
        ok &= mc.astype(bool)
    idx = np.flatnonzero(ok)
    # The same blob seen on two levels (close and of similar size): keep the finer
    # level's copy.
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
            coarse = np.where(lev[idx[i]] > lev[idx[j]], i, j)
            drop[coarse[same]] = True
        idx = idx[~drop]
    return Candidates(
        centre=np.column_stack([cx2, cy2])[idx],
        axes=np.column_stack([a2, b2])[idx],
        angle=th2[idx],
        features=feats[idx],
        saturated=saturated[idx],
    )


def _check_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"mask shape {mask.shape} does not match the image shape {shape}")
    return mask


def _detect8(image8: np.ndarray, params: BlobParameters, mask: np.ndarray | None
             ) -> BlobDetections:
    parts = []
    noise = _noise_sigma(image8)
    for colour, on, lo, hi, th in (
        (BLACK, params.find_black_blobs, params.black_min_radius, params.black_max_radius,
         params.black_threshold),
        (WHITE, params.find_white_blobs, params.white_min_radius, params.white_max_radius,
         params.white_threshold),
    ):
        if not on:
            continue
        c = blob_candidates(image8, colour, lo, hi, mask=mask, noise=noise)
        p = blob_probability(c.features)
        sel = (p >= th) & ~c.saturated
        m = int(sel.sum())
        parts.append(BlobDetections(
            centre=c.centre[sel].astype(np.float32),
            axes=c.axes[sel].astype(np.float32),
            angle=c.angle[sel].astype(np.float32),
            colour=np.full(m, colour, np.int8),
            score=p[sel].astype(np.float32),
        ))
    return BlobDetections.concatenate(parts)


def detect_blobs(
    image: np.ndarray, params: BlobParameters, *, mask: np.ndarray | None = None
) -> BlobDetections:
    """Detect black and/or white blobs in one grey image.

    Parameters
    ----------
    image : ndarray [H, W] uint8 or uint16
        Grey camera image (uint16 is reduced to its 8 most significant used bits).
    params : BlobParameters
    mask : ndarray [H, W], optional
        Region of interest: blobs whose centre falls on a zero pixel are dropped.

    Returns
    -------
    BlobDetections
        Black detections first, then white ones.

    Raises
    ------
    TypeError, ValueError
        For an image that is not a 2-D uint8/uint16 array or a mask of another shape.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((64, 64), 200, np.uint8)
    >>> _ = cv2.circle(img, (32, 30), 6, 20, -1)
    >>> det = detect_blobs(img, BlobParameters())
    >>> len(det), np.round(det.centre[0]).tolist()
    (1, [32.0, 30.0])
    """
    if not isinstance(params, BlobParameters):
        raise TypeError(f"params must be BlobParameters, got {type(params).__name__}")
    image8 = _as_uint8(image)
    _keep_freed_memory()
    return _detect8(image8, params, _check_mask(mask, image8.shape))


def preview_blobs(image: np.ndarray, params: BlobParameters) -> BlobDetections:
    """What Detect Blobs would find on this image with these parameters (no side effects).

    The same detector as :func:`detect_blobs` (so the preview never disagrees with the
    real run); it is fast enough for interactive scrubbing (a few ms at 1280x720).
    """
    return detect_blobs(image, params)


def detect_blobs_batch(
    get_image: Callable[[Hashable], np.ndarray],
    keys: Sequence[Hashable],
    params: BlobParameters,
    *,
    workers: int = 2,
    progress: Callable[[int, int], bool] | None = None,
    mask: np.ndarray | None = None,
) -> dict[Hashable, BlobDetections]:
    """Detect blobs in many images in parallel (e.g. all frames x cameras of a range).

    Images are fetched with ``get_image(key)`` on the calling thread, in the order of
    ``keys`` (so a sequential video reader needs no locking), while ``workers`` threads
    run the detector (OpenCV and numpy release the GIL for the heavy work).

    Parameters
    ----------
    get_image : callable key -> ndarray [H, W] uint8/uint16
    keys : sequence of hashable
        For example ``(frame, camera)`` tuples.
    params : BlobParameters
    workers : int
        Number of detector threads (default 2, the number of cores of a typical laptop).
    progress : callable (done, total) -> bool, optional
        Called after each finished image; returning False cancels: no new images are
        started, the ones in flight finish, and what is done is returned.
    mask : ndarray [H, W], optional
        Region of interest applied to every image.

    Returns
    -------
    dict key -> BlobDetections
        Finished images only (all of them unless cancelled).
    """
    if not isinstance(params, BlobParameters):
        raise TypeError(f"params must be BlobParameters, got {type(params).__name__}")
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    keys = list(keys)
    total = len(keys)
    results: dict[Hashable, BlobDetections] = {}
    if total == 0:
        return results
    cancelled = threading.Event()
    # Keep a bounded number of images in flight so memory stays flat on long takes.
    max_in_flight = 2 * workers
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="blobs") as pool:
        pending: dict[Future, Hashable] = {}
        it = iter(keys)
        exhausted = False

        def collect(done_set) -> None:
            for fut in done_set:
                key = pending.pop(fut)
                results[key] = fut.result()
                if progress is not None and not cancelled.is_set():
                    if progress(len(results), total) is False:
                        cancelled.set()

        while True:
            while not exhausted and not cancelled.is_set() and len(pending) < max_in_flight:
                try:
                    key = next(it)
                except StopIteration:
                    exhausted = True
                    break
                img = get_image(key)
                pending[pool.submit(detect_blobs, img, params, mask=mask)] = key
            if not pending:
                break
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            collect(done)
    return results
