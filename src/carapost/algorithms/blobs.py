"""Blob (painted marker) detection in camera images.

The detector turns one grey image into a table of elliptical blob detections, each with
a sub-pixel centre, semi-axes, angle, colour (black / white) and a calibrated
probability ``score`` that it is really a blob centre. All steps work on whole images
with OpenCV, on all candidates at once with numpy, or in compiled (numba) loops over the
candidates; there is no Python loop per pixel or blob:

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
   coverage is its contrast over the plane divided by the full paint contrast there
   (the core's, scaled by the light at that pixel), clipped to 0-1, inside the seed
   ellipse grown by 1.5 px. Its centroid is the sub-pixel centre
   and its second moments the ellipse (``a = 2 sqrt(lambda_1)``). Seeds larger than
   ~12 px are refined on a reduced copy (moments survive area reduction). A compiled
   kernel (numba) visits each seed's support and ring pixels once per pass; the numpy
   reference (seeds grouped by patch size, sums as products with one fixed design
   matrix) gives the same sums.
4. Probability: a small neural network (one hidden layer of 32 tanh units, trained on
   log-loss with an L2 penalty) over scale-free features (signal-to-noise, contrast
   relative to the surround, how well the coverage fills its ellipse, ring roughness,
   symmetry, axis ratio, how much of the ring is as dark as the blob, how far the ring
   plane sits above the surround) and over the candidate's appearance (its surroundings
   sampled on a grid aligned with its ellipse and on a wider context grid, scaled to
   its contrast and folded about both axes) gives the probability that the candidate
   is a blob centre; split seeds have a model of their own. It was fitted on synthetic images
   with known truth by ``scripts/train_blob_model.py`` (weights in
   ``carapost/resources/blob_model.json``). Candidates whose major axis (the full
   length of the longest ellipse axis, ``2 a``) is outside the radius range, or whose
   score is below the threshold, are dropped; the same blob seen on two levels is kept
   once.

Fully saturated regions (255) have no contrast against their surround and give no
detections; white candidates that are mostly saturated are rejected.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import math
import multiprocessing as mp
import sys
import threading
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from dataclasses import dataclass
from functools import cache, lru_cache
from importlib import resources
from multiprocessing.shared_memory import SharedMemory
from typing import NamedTuple

import cv2
import numba
import numpy as np

from carapost.algorithms.params import BLOB, param, validate

__all__ = [
    "BlobParameters",
    "BlobDetections",
    "detect_blobs",
    "detect_blobs_batch",
    "preview_blobs",
    "blob_candidates",
    "FEATURE_NAMES",
    "warm_up",
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
    # appearance (see _appearance): the candidate's surroundings sampled on a grid
    # aligned with its ellipse and scaled by its semi-axes (``patch``), and on a wider
    # grid scaled by its semi-major axis in both directions (``context``), each folded
    # about both axes
    *(f"{g}_{i}_{j}" if i >= 0 else f"{g}_asym_{j}"
      for g in ("patch", "context") for i in (*range(5), -1)
      for j in (range(5) if i >= 0 else ("major", "minor"))),
    "split",
)
#: Features measured by the refinement (the appearance features and ``split`` follow).
_N_REFINED = 9


@dataclass(frozen=True)
class BlobParameters:
    """The Blob Parameters section of the properties (names and defaults of the guide).

    Attributes
    ----------
    find_black_blobs, find_white_blobs : bool
        Which marker colours to search for (default black only).
    black_min_radius, black_max_radius, white_min_radius, white_max_radius : float
        Accepted range of the length of the longest ellipse axis (the full major axis,
        twice the semi-major axis ``a`` of :class:`BlobDetections`) in px (default 4-50),
        as in the guide: what its measuring tool gives when dragged across a blob.
    black_threshold, white_threshold : float
        Minimum probability (0-1) that a candidate is a blob centre (default 0.4):
        0 accepts almost anything, 1 only perfect blobs.

    Raises
    ------
    ValueError
        If a radius is not positive and finite, min > max, or a threshold is
        outside 0-1 (the message names the parameter).
    """

    # in the guide's order (the Properties pane shows them so)
    white_min_radius: float = param(
        4.0, label="White Min Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Smallest length of the longest axis of the ellipse (measured across the "
             "blob, as the measuring tool shows it) accepted as a white blob; lower finds "
             "tiny blobs but also noise. Range is our choice.")
    white_max_radius: float = param(
        50.0, label="White Max Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Largest length of the longest axis of the ellipse (measured across the blob) "
             "accepted as a white blob; larger is slower and admits clutter. Range is our "
             "choice.")
    black_min_radius: float = param(
        4.0, label="Black Min Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Smallest length of the longest axis of the ellipse (measured across the "
             "blob, as the measuring tool shows it) accepted as a black blob. Range is our "
             "choice.")
    black_max_radius: float = param(
        50.0, label="Black Max Radius", section=BLOB, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Largest length of the longest axis of the ellipse (measured across the blob) "
             "accepted as a black blob. Range is our choice.")
    find_black_blobs: bool = param(
        True, label="Find Black Blobs", section=BLOB,
        help="Look for dark markers on lighter skin.")
    find_white_blobs: bool = param(
        False, label="Find White Blobs", section=BLOB,
        help="Look for bright markers on darker skin.")
    black_threshold: float = param(
        0.4, label="Black Threshold", section=BLOB, unit="0-1", min=0.0, max=1.0,
        help="How closely a dark candidate must resemble a model blob: 0 accepts nearly "
             "anything, 1 only near-perfect blobs.")
    white_threshold: float = param(
        0.4, label="White Threshold", section=BLOB, unit="0-1", min=0.0, max=1.0,
        help="How closely a bright candidate must resemble a model blob: 0 accepts nearly "
             "anything, 1 only near-perfect blobs.")

    def __post_init__(self) -> None:
        validate(self)
        for colour in ("black", "white"):
            lo = getattr(self, f"{colour}_min_radius")
            hi = getattr(self, f"{colour}_max_radius")
            if lo > hi:
                raise ValueError(f"BlobParameters.{colour}_min_radius ({lo}) must not exceed "
                                 f"{colour}_max_radius ({hi})")


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

    ``features`` is [N, len(FEATURE_NAMES)] float64; ``score`` is
    :func:`blob_probability` of the features (computed once, here); other fields as in
    :class:`BlobDetections`.
    """

    centre: np.ndarray
    axes: np.ndarray
    angle: np.ndarray
    features: np.ndarray
    saturated: np.ndarray
    score: np.ndarray


# --------------------------------------------------------------------------- model


#: The two models of ``blob_model.json``: candidates from ordinary seeds and candidates
#: from seeds found by splitting an over-size region (indexed by the ``split`` feature),
#: with the number of leading FEATURE_NAMES each one uses (all but ``split``).
MODEL_KINDS = ("seed", "split")
MODEL_INPUTS = {"seed": 63, "split": 63}


#: Hidden units of each network (one tanh layer).
MODEL_HIDDEN = 32


class _Net(NamedTuple):
    """A neural network with one tanh hidden layer giving log-odds."""

    mean: np.ndarray  # [n] feature normalisation
    scale: np.ndarray  # [n]
    w1: np.ndarray  # [n, H]
    b1: np.ndarray  # [H]
    w2: np.ndarray  # [H]
    b2: float


@lru_cache(maxsize=1)
def _model() -> tuple[_Net, ...]:
    """Load the networks of ``blob_model.json``, one per entry of MODEL_KINDS."""
    text = resources.files("carapost").joinpath("resources/blob_model.json").read_text()
    m = json.loads(text)
    stale = RuntimeError("carapost/resources/blob_model.json does not match this detector "
                         "(features or model form); re-run scripts/train_blob_model.py")
    if tuple(m.get("features", ())) != FEATURE_NAMES or set(m.get("models", {})) != set(
            MODEL_KINDS):
        raise stale
    out = []
    for kind in MODEL_KINDS:
        n = MODEL_INPUTS[kind]
        try:
            k = m["models"][kind]
            net = _Net(*(np.asarray(k[f], np.float64) for f in _Net._fields[:5]),
                       float(k["b2"]))
        except (KeyError, TypeError):
            raise stale from None
        if net.w1.shape != (n, len(net.b1)) or net.w2.shape != net.b1.shape or (
                net.mean.shape != (n,)):
            raise stale
        out.append(net)
    return tuple(out)


def net_logit(net: _Net, features: np.ndarray) -> np.ndarray:
    """Log-odds of a network for candidates [N, F] (its leading MODEL_INPUTS features)."""
    x = (features[:, : net.mean.size] - net.mean) / net.scale
    return np.tanh(x @ net.w1 + net.b1) @ net.w2 + net.b2


def blob_probability(features: np.ndarray) -> np.ndarray:
    """Calibrated probability that each candidate is a blob centre.

    A small network (one hidden layer, trained on log-loss with an L2 penalty strong
    enough that it carries over to images unlike its synthetic training images, such as
    photos of printed dot grids). Candidates from split seeds (``split`` feature 1) have
    a network of their own: they are rarer, and a dark feature next to them changes what
    their other features mean.

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
    for k, net in enumerate(_model()):
        sel = kind == k
        if sel.any():
            z[sel] = net_logit(net, features[sel])
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
#: Tolerance (px) below Min Radius on the measured major-axis length (2 a).
MIN_RADIUS_TOLERANCE = 1.0
#: Grey level from which a pixel counts as saturated.
SATURATED = 250
#: Cap of the log signal-to-noise feature: beyond ~90x the noise more contrast is no
#: more evidence of a marker, and without the cap the score learned to distrust very
#: high contrast (dark facial features), which rejected the clean dots of real
#: calibration-target photos.
LOG_SNR_CAP = 4.5
#: Seed floor in units of the image noise sigma (contrast of the smoothed top-hat).
SEED_NOISE_FACTOR = 3.0
#: Smallest peak contrast (grey levels) of a candidate, whatever the noise estimate.
MIN_CONTRAST = 5.0
#: Largest semi-major axis (px of its own level) a pyramid level is responsible for.
LEVEL_RADIUS = 10.0
#: Overlap between neighbouring levels' radius bands (fraction).
LEVEL_OVERLAP = 0.15
#: Fraction of the peak contrast from which a pixel belongs to a blob's core, whose
#: mean level is the paint's level in the coverage.
CORE_FRACTION = 0.8
#: Margin (px) of the refinement support beyond the seed ellipse, and ring width (px).
#: A 2 px ring (3 px until the ninth round) sees the shading closest to the blob, where
#: a plane fits it best: centre p95 0.234 -> 0.219 px on the benchmark views, thin
#: markers 0.49 -> 0.45 px, recall and the dot grids unchanged.
SUPPORT_MARGIN = 1.5
RING_WIDTH = 2.0
#: Seeds larger than this (px of a level) are refined on the next coarser level.
REFINE_RADIUS = 12.0
#: A blob is cut by the image border when the outermost rows and columns hold at least
#: EDGE_COVERAGE px and EDGE_FRACTION of its coverage: a chord across the blob. One that
#: only touches the border has just its tip there (2 % of a 23 x 17 px brim dot) and an
#: unbiased centroid; a shading gradient running out of the image has much more.
EDGE_COVERAGE = 1.5
EDGE_FRACTION = 0.03

_KERNEL_LOCALMAX = cv2.getStructuringElement(cv2.MORPH_RECT, (9, 9))
_KERNEL_PEAK = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))
_KERNEL_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)
#: Seed inside regions of the full-resolution level that are too large for it by cutting
#: them again at stricter fractions of the local peak contrast (see _split_regions).
#: Coarser levels are not split: on carapost.synth their split seeds found no marker
#: that the full-resolution level missed, for ~2 ms per image.
SPLIT_SEEDS = True
SPLIT_LEVELS = (0.75, 0.9)
#: Smallest ratio of a split part's area to the area of its outline ellipse.
SPLIT_FILL = 0.85
#: Fifth-round options, off by default (the shipped model is trained without them):
#: refine split seeds on their own part grown by PART_GROW px (negative: on the whole
#: support ellipse), and cut over-size regions on the unsmoothed contrast (SPLIT_RAW),
#: which keeps a thin marker whole where the 5x5 blur spreads the crease over it. With
#: both on and a retrained model, recall on carapost.synth is 0.984 (0.981 without),
#: but the Process-menu tracking test then sees one face point switch markers.
PART_GROW = -1
SPLIT_RAW = 2
#: Noise sigma (grey levels) up to which SPLIT_RAW = 3 cuts on the unsmoothed contrast.
SPLIT_RAW_MAX_NOISE = 3.0


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


def _level_seeds(d: np.ndarray, bg: np.ndarray, sigma: float, a_lo: float, a_hi: float,
                 fine: bool = True) -> tuple[np.ndarray, ...]:
    """Seed ellipses of one pyramid level (all in that level's pixels).

    ``bg`` is the surround (an opening with a window just larger than ``a_hi``), so a
    blob is judged against skin right around it (a marker on the dark side of a shading
    edge does not merge with the dark skin). Candidates are connected regions at half
    their local peak contrast; the area moments of their outlines give the seeds.
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
            mode = SPLIT_RAW
            if mode == 3:  # adaptive: unsmoothed only where noise does not shatter it
                mode = 1 if sigma <= SPLIT_RAW_MAX_NOISE else 0
            sources = {0: [(top_s, local_max)], 1: [(top, None)],
                       2: [(top, None), (top_s, local_max)]}[int(mode)]
            *extra, outlines = _split_regions(sources, cand, [contours[i] for i in big],
                                              a_lo, a_hi)
            seeds = tuple(np.concatenate([p, q]) for p, q in zip(seeds, extra, strict=True))
            parts.extend(outlines)
    # Surround level (the opening) under each seed centre: a blob sitting on a darker
    # pedestal (a pupil in its iris) has its ring plane well above it.
    h, w = d.shape
    sx = np.clip(np.rint(seeds[0]).astype(np.int64), 0, w - 1)
    sy = np.clip(np.rint(seeds[1]).astype(np.int64), 0, h - 1)
    return (*seeds, bg[sy, sx].astype(np.float64), parts)


def _split_regions(sources, cand: np.ndarray, contours, a_lo: float, a_hi: float
                   ) -> tuple[np.ndarray, ...]:
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
        from scipy.spatial import cKDTree

        pairs = cKDTree(np.column_stack([cx, cy])).query_pairs(
            0.5 * float(b.max()) + 1.0, output_type="ndarray")
        keep = np.ones(cx.size, bool)
        if len(pairs):
            pi, pj = pairs.min(axis=1), pairs.max(axis=1)
            close = np.hypot(cx[pi] - cx[pj], cy[pi] - cy[pj]) <= (
                0.5 * np.minimum(b[pi], b[pj]) + 1.0)
            keep[pj[close]] = False
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


@cache
def _design3(r: int) -> np.ndarray:
    """First three columns (1, x, y) of :func:`_design` (contiguous), [P*P, 3]."""
    return np.ascontiguousarray(_design(r)[:, :3])


@cache
def _design_t(r: int) -> np.ndarray:
    """Transpose of :func:`_design` (contiguous), [6, P*P]."""
    return np.ascontiguousarray(_design(r).T)


#: Columns of the plane's normal matrix [[n, sx, sy], [sx, sxx, sxy], [sy, sxy, syy]] in
#: the design sums (1, x, y, x^2, y^2, xy).
_PLANE_IDX = np.array([0, 1, 2, 1, 3, 5, 2, 5, 4])
#: Per-seed sums returned by _refine_patches (see there).
_N_SUMS = 18
#: Largest m * n * k of a matrix product that OpenBLAS runs on the calling thread (its
#: default GEMM_MULTITHREAD_THRESHOLD 4 x 65536). Above it, it wakes its own threads,
#: which for these small products costs far more than the product (the detector took
#: 3.6x as long on a loaded 2-core machine), so seeds are refined in chunks that stay
#: below it.
_BLAS_ONE_THREAD = 4 * 65536


#: Refine with the compiled kernel (False: the numpy reference, _refine_patches).
USE_JIT = True


def _refine(d: np.ndarray, lw: np.ndarray, lh: np.ndarray, lb: np.ndarray,
            sigma: np.ndarray, cx, cy, a, b, th, open_bg, colour: int, parts=None):
    """Centre, ellipse and features of seed ellipses, each on its own pyramid level.

    ``d`` holds the flattened levels (contrast image: the inverted image for black
    blobs) one after the other; per seed ``lw``, ``lh`` are its level's width and
    height, ``lb`` the start of its level in ``d``, ``sigma`` the level's noise and the
    geometry is in that level's pixels.

    Per candidate, a plane fitted to a ring of pixels around the seed ellipse is the
    local background (so a shading gradient neither shifts the centre nor changes the
    contrast); each pixel's coverage is its contrast over that plane relative to the
    paint's full contrast there (the core's, scaled by the light at that pixel: paint
    reflects a fixed fraction of the light), clipped to 0-1 (the painted fraction of an
    anti-aliased pixel); the coverage moments inside the support give the centre and
    ellipse.

    Seeds are grouped by the size of the square patch that holds their ring. Within a
    group every patch has the same pixel grid, so all sums over pixels (plane normal
    equations, moments) and all quadratic forms over pixels (ellipse masks, planes) are
    products with one fixed design matrix [P*P, 6] (BLAS), and the rest is a handful of
    whole-array operations on the stack of patches [n, P*P]. The groups return per-seed
    sums; the ellipses and features are computed once for all seeds.

    The sums come from the compiled :func:`_refine_sums_jit` (``USE_JIT``, default) or
    from its numpy reference :func:`_refine_patches`.

    ``parts`` (object array [n], optional) holds, for split seeds, the outline of the
    split part (full-res pixels); their support is limited to that part grown by
    ``PART_GROW`` px, so the dark feature the marker was cut from (a crease along a
    thin marker) does not count as coverage.
    """
    n = cx.size
    if parts is None:
        parts = np.full(n, None, object)
    zero = 255.0 if colour == BLACK else 0.0  # the contrast image's level of no light
    m = SUPPORT_MARGIN
    ai, bi = a + m, b + m
    ao, bo = ai + RING_WIDTH, bi + RING_WIDTH
    c, s = np.cos(th), np.sin(th)
    need = np.ceil(np.maximum(np.sqrt((ao * c) ** 2 + (bo * s) ** 2),
                              np.sqrt((ao * s) ** 2 + (bo * c) ** 2)) + 0.5)
    radii = np.asarray(_PATCH_RADII)
    cls = np.minimum(np.searchsorted(radii, need), radii.size - 1)
    xi, yi = np.rint(cx), np.rint(cy)
    dx, dy = cx - xi, cy - yi  # seed centre relative to its patch centre
    if not (PART_GROW >= 0 and any(q is not None for q in parts)) and USE_JIT:
        # Compiled: one pass per seed over its own support and ring (3-4x faster).
        # Fixed argument types: one compiled specialisation (a new one costs ~3 s).
        i64 = [np.ascontiguousarray(v, np.int64)
               for v in (lw, lh, lb, np.minimum(need, radii[-1]), xi, yi)]
        f64 = [np.ascontiguousarray(v, np.float64) for v in (sigma, dx, dy, ai, bi, ao, bo, c, s)]
        sums = _refine_sums_jit(np.ascontiguousarray(d, np.uint8), *i64[:3], f64[0], *i64[3:],
                                *f64[1:], zero)
        cls = cls[:0]
    else:
        sums = np.zeros((n, _N_SUMS))
    for ci in np.unique(cls):
        r = int(radii[ci])
        step = max(1, _BLAS_ONE_THREAD // (6 * (2 * r + 1) ** 2))
        k = np.flatnonzero(cls == ci)
        for i in (k[j:j + step] for j in range(0, k.size, step)):
            sums[i] = _refine_patches(d, lw[i], lh[i], lb[i], sigma[i], r,
                                      xi[i].astype(np.int64), yi[i].astype(np.int64),
                                      dx[i], dy[i], ai[i], bi[i], ao[i], bo[i], c[i], s[i],
                                      parts[i], zero)
    mom, hm = sums[:, 0:6], sums[:, 6:9]
    n_ring, rr2, ring_fill, peak = sums[:, 9], sums[:, 10], sums[:, 11], sums[:, 12]
    coef, n_sat, n_edge = sums[:, 13:16], sums[:, 16], sums[:, 17]
    s0 = mom[:, 0]
    mx, my, a2, b2, th2 = _ellipse_from_moments(*mom.T)
    n_half = hm[:, 0]
    hx, hy = hm[:, 1] / np.maximum(n_half, 1), hm[:, 2] / np.maximum(n_half, 1)
    rr = np.sqrt(rr2 / np.maximum(n_ring, 1))
    ell_area = math.pi * a2 * b2
    bg_c = np.clip(coef[:, 0] + coef[:, 1] * dx + coef[:, 2] * dy, 0, 255)
    pk = np.maximum(peak, 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):
        feats = np.column_stack([
            np.minimum(np.log(pk / sigma), LOG_SNR_CAP),
            np.clip(peak / np.maximum(255.0 - bg_c, 1.0), 0, 2),
            np.clip(np.abs(1.0 - s0 / ell_area), 0, 5),
            np.clip(np.abs(1.0 - n_half / ell_area), 0, 5),
            np.clip(rr / pk, 0, 2),
            np.clip(np.hypot(hx - mx, hy - my) / np.maximum(b2, 0.5), 0, 5),
            b2 / a2,
            ring_fill,
            np.clip((bg_c - open_bg) / pk, -2, 5),
        ])
    # Fully saturated pixels (255 in the contrast image: 0 of a black blob's raw image,
    # 255 of a white one's) covering much of the half-contrast area.
    saturated = n_sat > 0.3 * n_half
    ok = (peak > 0) & np.isfinite(feats).all(axis=1) & (n_half > 0)
    # A blob cut by the image border (a chord of it lies on the outermost rows or
    # columns) has a biased centre and a shape that is not its own: a dark band
    # along the border otherwise passes for a large blob.
    ok &= (n_edge < EDGE_COVERAGE) | (n_edge < EDGE_FRACTION * s0)
    # A refined centre far from its seed means the support did not hold the blob.
    ok &= np.hypot(mx - dx, my - dy) <= 0.5 * a + 1.0
    return xi + mx, yi + my, a2, b2, th2, feats, saturated, ok


def _refine_patches(d, w, h, lb, sigma, r, xi, yi, dx, dy, ai, bi, ao, bo, c, s, parts,
                    zero=255.0):
    """Sums of :func:`_refine` for seeds whose ring fits a (2r+1)-pixel square patch
    centred on pixel (xi, yi).

    Returns [n, _N_SUMS]: coverage moments (6, design columns about the patch centre),
    half-contrast pixel count and coordinate sums (3), ring pixels used by the plane,
    their squared residual sum, fraction of the ring at half contrast, peak contrast,
    plane coefficients (3), saturated half-contrast pixels, summed coverage of the
    half-contrast pixels on the image's outermost rows and columns.

    This is the numpy reference of the compiled :func:`_refine_sums_jit` (used when
    ``USE_JIT`` is off, and for split seeds refined on their own part, ``PART_GROW``).
    """
    g = _design(r)
    g3 = _design3(r)
    gt = _design_t(r)
    n = xi.size
    off = np.arange(-r, r + 1)
    cols, rows = xi[:, None] + off, yi[:, None] + off  # [n, P]
    w, h = w[:, None], h[:, None]
    valid = None
    if (cols[:, 0] < 0).any() or (rows[:, 0] < 0).any() or (cols[:, -1] >= w[:, 0]).any() or (
            rows[:, -1] >= h[:, 0]).any():
        # Patches that reach past the image border: those pixels are neither blob nor
        # background.
        valid = (((rows >= 0) & (rows < h))[:, :, None]
                 & ((cols >= 0) & (cols < w))[:, None, :]).reshape(n, -1)
        cols = np.clip(cols, 0, w - 1)
        rows = np.clip(rows, 0, h - 1)
    flat = ((rows * w + lb[:, None])[:, :, None] + cols[:, None, :]).reshape(n, -1)
    dv8 = np.take(d, flat)  # [n, P*P] uint8
    dv = dv8.astype(np.float32)

    def quad(ea, eb):
        # (u / ea)^2 + (v / eb)^2 about the seed centre, u / v along the ellipse axes,
        # expanded on the design columns.
        ea2, eb2 = 1.0 / (ea * ea), 1.0 / (eb * eb)
        qa, qc = c * c * ea2 + s * s * eb2, s * s * ea2 + c * c * eb2
        qb = 2 * c * s * (ea2 - eb2)
        k = np.column_stack([qa * dx * dx + qc * dy * dy + qb * dx * dy,
                             -2 * qa * dx - qb * dy, -2 * qc * dy - qb * dx, qa, qc, qb])
        return k.astype(np.float32) @ gt

    support = quad(ai, bi) <= 1.0
    ring = quad(ao, bo) <= 1.0
    if valid is not None:
        support &= valid
        ring &= valid
    ring &= ~support
    sel = np.flatnonzero([q is not None for q in parts]) if PART_GROW >= 0 else ()
    if len(sel):
        # Split seeds: coverage only on the split part (grown by PART_GROW px to take
        # its anti-aliased edge), drawn from its outline; the ring stays as it is.
        p = 2 * r + 1
        pm = np.zeros((len(sel), p, p), np.uint8)
        for j, k in enumerate(sel):
            o = (int(r - xi[k]), int(r - yi[k]))
            cv2.drawContours(pm[j], [parts[k]], -1, 1, -1, offset=o)
            if PART_GROW > 0:
                cv2.drawContours(pm[j], [parts[k]], -1, 1, 2 * PART_GROW + 1, offset=o)
        support[sel] &= pm.reshape(len(sel), -1).astype(bool)
    supf, ringf = support.astype(np.float32), ring.astype(np.float32)
    # Pixels outside the support pushed far down, so a row maximum is one over the support.
    outside = (1.0 - supf) * np.float32(1e9)

    def plane(wgt):
        # Weighted least-squares plane dv ~ c0 + c1 x + c2 y over the pixels in wgt:
        # the normal equations' sums for all seeds in one product.
        sg = (wgt @ g).astype(np.float64)
        rhs = ((wgt * dv) @ g3).astype(np.float64)
        mat = sg[:, _PLANE_IDX].reshape(n, 3, 3)
        mat[:, [0, 1, 2], [0, 1, 2]] += 1e-3
        coef = np.linalg.solve(mat, rhs[..., None])[..., 0]
        n0 = sg[:, 0]
        few = n0 < 3
        if few.any():
            coef[few] = 0.0
            coef[few, 0] = rhs[few, 0] / np.maximum(n0[few], 1)
        return coef, n0

    coef, _ = plane(ringf)
    res = dv - coef.astype(np.float32) @ gt[:3]
    # Second pass without ring pixels well above the plane (a neighbouring marker's
    # edge, a dark crease): they would lift the background under this blob.
    peak = (res - outside).max(axis=1)
    ring2 = ringf * (res < np.maximum(3.0 * sigma, 0.25 * peak)[:, None])
    coef, n_ring = plane(ring2)
    bgp = coef.astype(np.float32) @ gt[:3]
    res = dv - bgp
    peak = (res - outside).max(axis=1)
    pk = np.maximum(peak, 1e-3).astype(np.float32)[:, None]
    # Paint reflects a fixed fraction of the light that skin would: under a shading
    # gradient the fully covered level follows the light, so the full-coverage contrast
    # at each pixel is the core's contrast scaled by the light there, (plane - zero) /
    # (plane at the core - zero), ``zero`` being the contrast image's level of no light
    # (255 for black blobs, whose image is inverted; 0 for white). One number per blob
    # would weight the centroid towards brighter skin; a paint level that ignores the
    # light (the plane less a constant) still weights a thin marker along a steep
    # gradient (ninth round: centre p95 of thin markers 0.52 -> 0.49 px). The core's
    # level is its mean (pixels at CORE_FRACTION of the peak contrast or more), not its
    # darkest pixel: noise, and ink or light that is not quite even across a blob, would
    # otherwise leave its interior less than fully covered (a real dot-grid photo's
    # dots then looked unlike painted markers).
    corem = support & (res >= CORE_FRACTION * pk)
    ncore = np.maximum(corem.sum(axis=1), 1)[:, None]
    core = (dv * corem).sum(axis=1)[:, None] / ncore
    bg_core = (bgp * corem).sum(axis=1)[:, None] / ncore
    den = bg_core - np.float32(zero)
    den = np.where(np.abs(den) < 1.0, np.where(den < 0, -1.0, 1.0), den).astype(np.float32)
    full = np.maximum((core - bg_core) * (bgp - np.float32(zero)) / den, 0.25 * pk)
    cov = np.clip(res / full, 0.0, 1.0)
    cov *= supf
    above = res >= 0.5 * pk
    half = above & support
    halff = half.astype(np.float32)
    out = np.empty((n, _N_SUMS))
    out[:, 0:6] = cov @ g
    out[:, 6:9] = halff @ g3
    out[:, 9] = n_ring
    out[:, 10] = np.einsum("ij,ij->i", ring2 * res, res)
    out[:, 11] = np.count_nonzero(above & ring, axis=1) / np.maximum(ringf.sum(axis=1), 1)
    out[:, 12] = peak
    out[:, 13:16] = coef
    out[:, 16] = np.count_nonzero((dv8 == 255) & half, axis=1)
    out[:, 17] = 0
    if (rows[:, 0] <= 0).any() or (cols[:, 0] <= 0).any() or (
            rows[:, -1] >= h[:, 0] - 1).any() or (cols[:, -1] >= w[:, 0] - 1).any():
        # Half-contrast pixels on the outermost rows / columns of the image: the blob
        # is cut by the border.
        edge = (((rows == 0) | (rows == h - 1))[:, :, None]
                | ((cols == 0) | (cols == w - 1))[:, None, :]).reshape(n, -1)
        if valid is not None:
            edge &= valid
        out[:, 17] = np.einsum("ij,ij->i", (edge & half).astype(np.float32), cov)
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _add_plane_pixel(m: np.ndarray, rhs: np.ndarray, x: float, y: float, v: float
                     ) -> None:  # pragma: no cover - jit
    """Add pixel (x, y) of value v to the weight sums ``m`` (1, x, y, x^2, y^2, xy) and
    right-hand sums ``rhs`` (v, v x, v y) of a plane fit (see :func:`_solve_plane`)."""
    m[0] += 1.0
    m[1] += x
    m[2] += y
    m[3] += x * x
    m[4] += y * y
    m[5] += x * y
    rhs[0] += v
    rhs[1] += v * x
    rhs[2] += v * y


@numba.njit(cache=True, nogil=True, inline="always")
def _plane_residuals(pv, px, py, pflag, coef, pres, cnt):  # pragma: no cover - jit
    """Residuals over the plane ``coef`` of the first ``cnt`` pixels into ``pres``;
    returns the largest residual over the support pixels (flag 1), -1e9 if none."""
    peak = -1e9
    for j in range(cnt):
        res = pv[j] - (coef[0] + coef[1] * px[j] + coef[2] * py[j])
        pres[j] = res
        if pflag[j] & 1 and res > peak:
            peak = res
    return peak


@numba.njit(cache=True, nogil=True)
def _solve_plane(m: np.ndarray, rhs: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - jit
    """Least-squares plane c0 + c1 x + c2 y from weight sums ``m`` (1, x, y, x^2, y^2,
    xy) and right-hand sums ``rhs`` (v, v x, v y) into ``out``; a level plane (the mean)
    when fewer than 3 pixels are given. The 3x3 normal matrix gets 1e-3 on its diagonal,
    as in :func:`_refine_patches`."""
    n0 = m[0]
    if n0 < 3:
        out[0] = rhs[0] / max(n0, 1.0)
        out[1] = 0.0
        out[2] = 0.0
        return
    a00, a01, a02 = m[0] + 1e-3, m[1], m[2]
    a11, a12, a22 = m[3] + 1e-3, m[5], m[4] + 1e-3
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    out[0] = (c00 * rhs[0] + c01 * rhs[1] + c02 * rhs[2]) / det
    out[1] = (c01 * rhs[0] + c11 * rhs[1] + c12 * rhs[2]) / det
    out[2] = (c02 * rhs[0] + c12 * rhs[1] + c22 * rhs[2]) / det


@numba.njit(cache=True, nogil=True)
def _refine_sums_jit(d, lw, lh, lb, sigma, rad, xi, yi, dx, dy, ai, bi, ao, bo, c, s, zero
                     ):  # pragma: no cover - jit
    """The sums of :func:`_refine_patches` (same order and meaning) for all seeds, one
    seed at a time, visiting only the pixels of its support and ring (compiled).

    ``rad`` is the half-width of the square around (xi, yi) searched for them (px).
    """
    n = xi.size
    out = np.zeros((n, 18))
    cap = int(2 * rad.max() + 1) ** 2 if n else 1
    px = np.empty(cap)
    py = np.empty(cap)
    pv = np.empty(cap)
    pres = np.empty(cap)
    pflag = np.empty(cap, np.uint8)  # 1 support, 2 ring, 4 ring2, 8 image edge, 16 saturated
    m = np.empty(6)
    rhs = np.empty(3)
    coef = np.empty(3)
    for k in range(n):
        w, h, base, r = lw[k], lh[k], lb[k], rad[k]
        ca, sa = c[k], s[k]
        ia2, ib2 = 1.0 / (ai[k] * ai[k]), 1.0 / (bi[k] * bi[k])
        oa2, ob2 = 1.0 / (ao[k] * ao[k]), 1.0 / (bo[k] * bo[k])
        m[:] = 0.0
        rhs[:] = 0.0
        cnt = 0
        for iy in range(-r, r + 1):
            row = yi[k] + iy
            if row < 0 or row >= h:
                continue
            v0 = iy - dy[k]
            for ix in range(-r, r + 1):
                col = xi[k] + ix
                if col < 0 or col >= w:
                    continue
                u0 = ix - dx[k]
                p = ca * u0 + sa * v0
                q = ca * v0 - sa * u0
                pp, qq = p * p, q * q
                if pp * ia2 + qq * ib2 <= 1.0:
                    f = 1
                elif pp * oa2 + qq * ob2 <= 1.0:
                    f = 2
                else:
                    continue
                val = d[base + row * w + col]
                if row == 0 or row == h - 1 or col == 0 or col == w - 1:
                    f |= 8
                if val == 255:
                    f |= 16
                x, y, v = float(ix), float(iy), float(val)
                px[cnt], py[cnt], pv[cnt], pflag[cnt] = x, y, v, f
                cnt += 1
                if f & 2:
                    _add_plane_pixel(m, rhs, x, y, v)
        _solve_plane(m, rhs, coef)
        # Second plane without ring pixels well above the first one.
        peak = _plane_residuals(pv, px, py, pflag, coef, pres, cnt)
        thr = max(3.0 * sigma[k], 0.25 * peak)
        m[:] = 0.0
        rhs[:] = 0.0
        for j in range(cnt):
            if pflag[j] & 2 and pres[j] < thr:
                pflag[j] |= 4
                _add_plane_pixel(m, rhs, px[j], py[j], pv[j])
        n_ring = m[0]
        _solve_plane(m, rhs, coef)
        peak = _plane_residuals(pv, px, py, pflag, coef, pres, cnt)
        pk = max(peak, 1e-3)
        # Paint level: mean over the core, scaled by the light (see _refine_patches).
        core_sum, bg_sum, core_n = 0.0, 0.0, 0
        for j in range(cnt):
            if pflag[j] & 1 and pres[j] >= CORE_FRACTION * pk:
                core_sum += pv[j]
                bg_sum += pv[j] - pres[j]
                core_n += 1
        core = core_sum / max(core_n, 1)
        bg_core = bg_sum / max(core_n, 1)
        den = bg_core - zero
        if abs(den) < 1.0:
            den = -1.0 if den < 0 else 1.0
        scale = (core - bg_core) / den
        o = out[k]
        n_ring_all, ring_above = 0, 0
        for j in range(cnt):
            f = pflag[j]
            res = pres[j]
            x, y = px[j], py[j]
            above = res >= 0.5 * pk
            if f & 1:
                full = max(scale * (pv[j] - res - zero), 0.25 * pk)
                cov = min(max(res / full, 0.0), 1.0)
                o[0] += cov
                o[1] += cov * x
                o[2] += cov * y
                o[3] += cov * x * x
                o[4] += cov * y * y
                o[5] += cov * x * y
                if above:
                    o[6] += 1.0
                    o[7] += x
                    o[8] += y
                    if f & 16:
                        o[16] += 1.0
                    if f & 8:
                        o[17] += cov
            else:
                n_ring_all += 1
                if above:
                    ring_above += 1
                if f & 4:
                    o[10] += res * res
        o[9] = n_ring
        o[11] = ring_above / max(n_ring_all, 1)
        o[12] = peak
        o[13] = coef[0]
        o[14] = coef[1]
        o[15] = coef[2]
    return out


def _levels(a_min: float, a_max: float) -> list[tuple[int, float, float]]:
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


class _Levels(NamedTuple):
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


def _stack_levels(pyramid: dict[int, np.ndarray]) -> _Levels:
    """All levels of ``pyramid`` ({factor: image}) in one buffer."""
    factor = sorted(pyramid)
    sizes = [pyramid[f].size for f in factor]
    return _Levels(np.concatenate([pyramid[f].reshape(-1) for f in factor]),
                   np.array(factor, np.int64),
                   np.array([pyramid[f].shape[1] for f in factor], np.int64),
                   np.array([pyramid[f].shape[0] for f in factor], np.int64),
                   np.cumsum([0, *sizes[:-1]]).astype(np.int64))


#: Appearance grids: PATCH_SIZE x PATCH_SIZE samples spanning +-PATCH_EXTENT semi-axes
#: along each ellipse axis (the minor one at least 1 px), and +-CONTEXT_EXTENT
#: semi-major axes in both directions.
PATCH_SIZE = 9
PATCH_EXTENT = 2.0
CONTEXT_EXTENT = 4.0


def _appearance(levels: _Levels, sigma: float, centre: np.ndarray,
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
    levels : _Levels
        The contrast pyramid in one buffer (:func:`_stack_levels`).
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
    _appearance_jit(levels.buf, lb, lw, lh, g.astype(np.float64), max(3.0 * sigma, 2.0),
                    np.ascontiguousarray(centre[:, 0], np.float64),
                    np.ascontiguousarray(centre[:, 1], np.float64), su, sv,
                    np.cos(angle).astype(np.float64), np.sin(angle).astype(np.float64), k, out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _appearance_jit(buf, lb, lw, lh, lf, min_scale, cx, cy, su, sv, c, s, k, out
                    ):  # pragma: no cover - jit
    """The sampling, scaling and folding of :func:`_appearance`, one candidate at a
    time: bilinear samples of level ``lf`` (pixels beyond the border repeat the border),
    ring median, centre mean, fold."""
    q = np.empty((k, k))
    ring = np.empty(4 * (k - 1))
    t = np.empty(k)
    for a in range(k):
        t[a] = 2.0 * a / (k - 1) - 1.0
    m = k // 2
    for i in range(cx.size):
        f = lf[i]
        o = 0.5 * (f - 1.0)
        w, h, b0 = lw[i], lh[i], lb[i]
        # grid steps along the major (u) and minor (v) axis, in level pixels
        ux, uy = su[i] * c[i] / f, su[i] * s[i] / f
        vx, vy = -sv[i] * s[i] / f, sv[i] * c[i] / f
        x_c, y_c = (cx[i] - o) / f, (cy[i] - o) / f
        wm, hm = w - 1.0, h - 1.0
        for a in range(k):
            xa, ya = x_c + t[a] * ux, y_c + t[a] * uy
            for bb in range(k):
                x = min(max(xa + t[bb] * vx, 0.0), wm)
                y = min(max(ya + t[bb] * vy, 0.0), hm)
                x0 = min(int(x), w - 2) if w > 1 else 0
                y0 = min(int(y), h - 2) if h > 1 else 0
                fx, fy = x - x0, y - y0
                x1 = min(x0 + 1, w - 1)
                y1 = min(y0 + 1, h - 1)
                r0 = b0 + y0 * w
                r1 = b0 + y1 * w
                top_row = (1.0 - fx) * buf[r0 + x0] + fx * buf[r0 + x1]
                bottom_row = (1.0 - fx) * buf[r1 + x0] + fx * buf[r1 + x1]
                q[a, bb] = (1.0 - fy) * top_row + fy * bottom_row
        r = 0
        for j in range(k):
            ring[r] = q[0, j]
            ring[r + 1] = q[k - 1, j]
            r += 2
        for j in range(1, k - 1):
            ring[r] = q[j, 0]
            ring[r + 1] = q[j, k - 1]
            r += 2
        for j in range(1, r):  # insertion sort of the ring in place (32 values)
            v = ring[j]
            jj = j - 1
            while jj >= 0 and ring[jj] > v:
                ring[jj + 1] = ring[jj]
                jj -= 1
            ring[jj + 1] = v
        base = 0.5 * (ring[r // 2 - 1] + ring[r // 2])
        top = 0.0
        for a in range(m - 1, m + 2):
            for bb in range(m - 1, m + 2):
                top += q[a, bb]
        scale = max(top / 9.0 - base, min_scale)
        for a in range(k):
            for bb in range(k):
                q[a, bb] = min(max((q[a, bb] - base) / scale, -1.5), 1.5)
        du = 0.0
        dv = 0.0
        for a in range(k):
            for bb in range(k):
                du += abs(q[a, bb] - q[k - 1 - a, bb])
                dv += abs(q[a, bb] - q[a, k - 1 - bb])
        col = 0
        for a in range(m, k):
            for bb in range(m, k):
                out[i, col] = 0.25 * (q[a, bb] + q[k - 1 - a, bb] + q[a, k - 1 - bb]
                                      + q[k - 1 - a, k - 1 - bb])
                col += 1
        out[i, col] = du / (k * k)
        out[i, col + 1] = dv / (k * k)


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
    sigma = _noise_sigma(image8) if noise is None else float(noise)
    a_min, a_max = 0.5 * min_radius, 0.5 * max_radius  # semi-major axis range
    levels = [lv for lv in _levels(a_min, a_max)
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

    # Contrast image of each level (the inverted image for black blobs).
    pyramid = {f: x if colour != BLACK else cv2.bitwise_not(x) for f, x in raws.items()}

    def surround_source(f: int) -> np.ndarray:
        # Saturated highlights are not a surround level: hide them from the opening so
        # the skin between two highlights keeps its own level (they give no contrast).
        if colour != BLACK:
            return pyramid[f]
        return cv2.max(pyramid[f], cv2.compare(raws[f], SATURATED, cv2.CMP_GE))

    seeds, parts = [], []
    for f, lo, hi in levels:
        dl = pyramid[f]
        r = hi / f
        if r >= 6 and 2 * f in pyramid:
            bg = _background(surround_source(2 * f), r, dl.shape, 2)
        else:
            bg = _background(surround_source(f), r, dl.shape, 1)
        sx, sy, sa, sb, st, sp, sbg, sparts = _level_seeds(
            dl, bg, max(0.7, sigma / f), max(lo / f, 1.0), r, fine=f == 1)
        # Split parts exist on the full-resolution level only (their outlines are in
        # full-res pixels and the parts are refined there: semi-major axis <= 11.5).
        parts.extend(sparts)
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
    levels = _stack_levels(pyramid)
    dbuf = levels.buf
    lw, lh, lb = levels.at(g)
    o = 0.5 * (g - 1)
    part_arr = np.empty(len(parts), object)
    part_arr[:] = parts
    sig = np.maximum(0.7, sigma / g)
    sx, sy, sa, sb = (cx - o) / g, (cy - o) / g, a / g, b / g
    cx2, cy2, a2, b2, th2, feats, saturated, ok = _refine(
        dbuf, lw, lh, lb, sig, sx, sy, sa, sb, th, open_bg, colour, part_arr)
    cx2, cy2, a2, b2 = cx2 * g + o, cy2 * g + o, a2 * g, b2 * g
    ok &= (2 * a2 >= min_radius - MIN_RADIUS_TOLERANCE) & (2 * a2 <= max_radius)
    if mask is not None:
        mc = np.asarray(mask)[np.clip(np.rint(cy2).astype(np.int64), 0, h - 1),
                              np.clip(np.rint(cx2).astype(np.int64), 0, w - 1)]
        ok &= mc.astype(bool)
    idx = np.flatnonzero(ok)
    look = np.zeros((cx2.size, len(FEATURE_NAMES) - _N_REFINED - 1))
    # both grids in one call: the candidates twice, ellipse-aligned then context
    m = idx.size
    both = _appearance(levels, sigma, np.tile(np.column_stack([cx2[idx], cy2[idx]]), (2, 1)),
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
        p = c.score
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


#: Batches of at least this many images run in worker processes when ``workers > 1``
#: (see :func:`detect_blobs_batch`); smaller ones (Detect Blobs [Current Frame]) run in
#: threads, which start instantly.
PROCESS_MIN_IMAGES = 16
#: Images per task of the worker processes.
PROCESS_CHUNK = 4

_POOL_LOCK = threading.Lock()
_POOL: ProcessPoolExecutor | None = None
_POOL_WORKERS = 0


def _worker_init() -> None:
    """Initialise a detector process: OpenCV single-threaded (the parallelism is the
    processes; OpenCV's own threads would only compete with them) and the malloc
    settings of :func:`_keep_freed_memory`."""
    cv2.setNumThreads(1)
    _keep_freed_memory()
    warm_up()


def warm_up() -> None:
    """Load (or, on the first run after installation, compile: ~3 s) the detector's
    compiled kernels, so the first detection does not pay for it. Detector processes do
    this when they start; a GUI may call it in the background at start-up."""
    from scipy.spatial import cKDTree  # noqa: F401 - imported on first use otherwise

    img = np.full((24, 24), 200, np.uint8)
    cv2.circle(img, (12, 12), 4, 30, -1)
    _detect8(img, BlobParameters(), None)


#: Shared-memory blocks this detector process has attached (name -> SharedMemory).
_ATTACHED: dict = {}


def _worker_detect(image: np.ndarray | tuple, params: BlobParameters,
                   mask: np.ndarray | None) -> BlobDetections:
    """Detect in a worker process. ``image`` is an array or (shared-memory block name,
    byte offset, shape, dtype) of an image the caller copied into that block."""
    if isinstance(image, tuple):
        name, offset, shape, dtype = image
        shm = _ATTACHED.get(name)
        if shm is None:
            # A new batch: let go of the previous batch's block (already unlinked).
            for old in _ATTACHED.values():
                try:
                    old.close()
                except BufferError:  # pragma: no cover - no array refers to it here
                    pass
            _ATTACHED.clear()
            shm = _ATTACHED[name] = SharedMemory(name=name)
        image = np.ndarray(shape, dtype, buffer=shm.buf, offset=offset)
    return _detect8(_as_uint8(image), params, mask)


def _worker_detect_many(images: list, params: BlobParameters, mask: np.ndarray | None
                        ) -> list[BlobDetections]:
    """:func:`_worker_detect` for the images of one task, in order."""
    return [_worker_detect(image, params, mask) for image in images]


def _process_pool(workers: int) -> ProcessPoolExecutor:
    """The detector processes, started on first use and kept for later batches (a new
    process costs ~0.3-0.5 s to import numpy, OpenCV and this module).

    On Linux the processes are forked from a ``forkserver`` that has imported this
    module once (they start in ~10 ms and never inherit the caller's threads, e.g. a GUI
    toolkit's); elsewhere they are spawned.
    """
    global _POOL, _POOL_WORKERS
    with _POOL_LOCK:
        if _POOL is not None and (_POOL_WORKERS != workers or getattr(_POOL, "_broken",
                                                                       False)):
            _POOL.shutdown(wait=False, cancel_futures=True)
            _POOL = None
        if _POOL is None:
            if "forkserver" in mp.get_all_start_methods():
                ctx = mp.get_context("forkserver")
                ctx.set_forkserver_preload([__name__])
            else:
                ctx = mp.get_context("spawn")
            _POOL = ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                        initializer=_worker_init)
            _POOL_WORKERS = workers
        return _POOL


def shutdown_workers() -> None:
    """Stop the detector processes started by :func:`detect_blobs_batch` (they are
    otherwise kept for the next batch and stopped when the program exits)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is not None:
            _POOL.shutdown(wait=True, cancel_futures=True)
            _POOL = None


def detect_blobs_batch(
    get_image: Callable[[Hashable], np.ndarray],
    keys: Sequence[Hashable],
    params: BlobParameters,
    *,
    workers: int = 2,
    progress: Callable[[int, int], bool] | None = None,
    mask: np.ndarray | None = None,
    processes: bool | None = None,
) -> dict[Hashable, BlobDetections]:
    """Detect blobs in many images in parallel (e.g. all frames x cameras of a range).

    Images are fetched with ``get_image(key)`` on the calling thread, in the order of
    ``keys`` (so a sequential video reader needs no locking), and detected by
    ``workers`` worker processes (batches of :data:`PROCESS_MIN_IMAGES` images or more)
    or threads (smaller batches). Processes scale with the cores: the detector's numpy
    steps hold Python's GIL for much of their time, so two threads reach only ~1.2x
    one thread's rate. The processes are started on the first large batch and kept
    for the next ones (:func:`shutdown_workers` stops them).

    Parameters
    ----------
    get_image : callable key -> ndarray [H, W] uint8/uint16
        Called on the calling thread only.
    keys : sequence of hashable
        For example ``(frame, camera)`` tuples.
    params : BlobParameters
    workers : int
        Number of detector processes or threads (default 2, the number of cores of a
        typical laptop); 1 detects on one worker thread.
    progress : callable (done, total) -> bool, optional
        Called on the calling thread after each finished image; returning False
        cancels: no new images are started, the ones in flight finish, and what is done
        is returned.
    mask : ndarray [H, W], optional
        Region of interest applied to every image.
    processes : bool, optional
        Force worker processes (True) or threads (False); default: processes for
        batches of at least PROCESS_MIN_IMAGES images when ``workers > 1``.

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
    if processes is None:
        processes = workers > 1 and total >= PROCESS_MIN_IMAGES
    cancelled = False
    # Keep a bounded number of tasks in flight so memory stays flat on long takes. A
    # process task carries PROCESS_CHUNK images: each task costs the caller's executor
    # threads ~0.5 ms of CPU (pipes, wake-ups), as much per task as per image.
    chunk = PROCESS_CHUNK if processes else 1
    max_in_flight = 2 * workers
    thread_pool = None
    shm = None
    if processes:
        pool = _process_pool(workers)
        mask8 = None if mask is None else np.ascontiguousarray(np.asarray(mask) != 0)
        # Images travel in a shared-memory block with one slot per image in flight (a
        # copy of ~0.1 ms instead of ~0.5 ms of pickling and pipe writes per 1280x720
        # image); one larger than a slot (another camera size) is pickled instead.
        free_slots: list[int] = list(range(max_in_flight * chunk))
        slot_of: dict[Future, list[int]] = {}
        slot_bytes = 0
    else:
        pool = thread_pool = ThreadPoolExecutor(max_workers=workers,
                                                thread_name_prefix="blobs")
    try:
        pending: dict[Future, list[Hashable]] = {}
        it = iter(keys)
        exhausted = False
        while True:
            while not exhausted and not cancelled and len(pending) < max_in_flight:
                task_keys: list[Hashable] = []
                args: list[np.ndarray | tuple] = []
                slots: list[int] = []
                while len(task_keys) < chunk:
                    try:
                        key = next(it)
                    except StopIteration:
                        exhausted = True
                        break
                    img = get_image(key)
                    task_keys.append(key)
                    if not processes:
                        args.append(img)
                        continue
                    # Validate here, so a bad image fails as it would in one process.
                    if not isinstance(img, np.ndarray) or img.ndim != 2:
                        _as_uint8(img)
                    if mask is not None:
                        _check_mask(mask, img.shape)
                    if shm is None:
                        slot_bytes = max(img.nbytes, 1)
                        shm = SharedMemory(create=True,
                                           size=max_in_flight * chunk * slot_bytes)
                    if img.nbytes <= slot_bytes:
                        slot = free_slots.pop()
                        view = np.ndarray(img.shape, img.dtype, buffer=shm.buf,
                                          offset=slot * slot_bytes)
                        view[...] = img
                        del view  # no array may refer to the block when it is closed
                        args.append((shm.name, slot * slot_bytes, img.shape, img.dtype.str))
                        slots.append(slot)
                    else:
                        args.append(img)
                if not task_keys:
                    break
                if processes:
                    fut = pool.submit(_worker_detect_many, args, params, mask8)
                    slot_of[fut] = slots
                else:
                    fut = pool.submit(detect_blobs, args[0], params, mask=mask)
                pending[fut] = task_keys
            if not pending:
                break
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                task_keys = pending.pop(fut)
                if processes:
                    free_slots.extend(slot_of.pop(fut))
                    found = fut.result()
                else:
                    found = [fut.result()]
                for key, det in zip(task_keys, found, strict=True):
                    results[key] = det
                    if progress is not None and not cancelled:
                        if progress(len(results), total) is False:
                            cancelled = True
    finally:
        if thread_pool is not None:
            thread_pool.shutdown(wait=True)
        elif pending:
            # An error: let the images in flight finish before the pool is reused.
            wait(pending)
        if shm is not None:
            shm.close()
            shm.unlink()
    return results
