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
   so a blob is judged against the skin right around it; pixels at least half their
   local peak contrast form connected regions whose coverage moments are the seed
   ellipses.
3. Refinement at the blob's own scale: per seed, a plane fitted (twice, the second time
   without ring pixels far above the first plane) to a ring of pixels around the seed
   ellipse is the local background, which removes shading gradients; each pixel's
   coverage is its contrast over the plane divided by the peak contrast, clipped to
   0-1, inside the seed ellipse grown by 1.5 px. Its centroid is the sub-pixel centre
   and its second moments the ellipse (``a = 2 sqrt(lambda_1)``). Seeds larger than
   ~14 px are refined on a reduced copy (moments survive area reduction).
4. Probability: a logistic model over scale-free features (signal-to-noise, contrast
   relative to the surround, how well the coverage fills its ellipse, ring roughness,
   symmetry, axis ratio, how much of the ring is as dark as the blob) gives the
   probability that the candidate is a blob centre. It was fitted on synthetic images
   with known truth by ``scripts/train_blob_model.py`` (weights in
   ``carapost/resources/blob_model.json``). Candidates whose semi-major axis is outside
   the radius range, or whose score is below the threshold, are dropped; the same blob
   seen on two levels is kept once.

Fully saturated regions (255) have no contrast against their surround and give no
detections; white candidates that are mostly saturated are rejected.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from functools import lru_cache
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
)


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


@lru_cache(maxsize=1)
def _model() -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Load the logistic model (weights, bias, feature mean, feature scale)."""
    text = resources.files("carapost").joinpath("resources/blob_model.json").read_text()
    m = json.loads(text)
    if tuple(m["features"]) != FEATURE_NAMES or len(m["weights"]) != len(m["mean"]):
        raise RuntimeError("carapost/resources/blob_model.json does not match FEATURE_NAMES; "
                           "re-run scripts/train_blob_model.py")
    return (np.asarray(m["weights"], np.float64), float(m["bias"]),
            np.asarray(m["mean"], np.float64), np.asarray(m["scale"], np.float64))


def expand_features(features: np.ndarray) -> np.ndarray:
    """Model inputs: the features, their squares and pairwise products.

    Parameters
    ----------
    features : ndarray [N, F]

    Returns
    -------
    ndarray [N, F + F (F + 1) / 2]
    """
    f = np.asarray(features, np.float64)
    iu, ju = np.triu_indices(f.shape[1])
    return np.hstack([f, f[:, iu] * f[:, ju]])


def blob_probability(features: np.ndarray) -> np.ndarray:
    """Calibrated probability that each candidate is a blob centre.

    Parameters
    ----------
    features : ndarray [N, len(FEATURE_NAMES)]

    Returns
    -------
    ndarray [N] float64 in 0-1
    """
    w, b, mean, scale = _model()
    z = ((expand_features(features) - mean) / scale) @ w + b
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))


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
_KERNEL_RING = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))


def _background(d: np.ndarray, radius: float) -> np.ndarray:
    """Surround level: grey opening of ``d`` by a square just larger than a blob of
    semi-major axis ``radius`` (computed on a reduced copy for speed)."""
    h, w = d.shape
    f = 2 if radius >= 6 else 1
    small = cv2.resize(d, (w // f, h // f), interpolation=cv2.INTER_AREA) if f > 1 else d
    k = 2 * int(math.ceil(radius / f)) + 3
    ker = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg = cv2.morphologyEx(small, cv2.MORPH_OPEN, ker, borderType=cv2.BORDER_REPLICATE)
    bg = cv2.blur(bg, (3, 3))
    if f > 1:
        bg = cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR)
    return bg


def _segments(ids: np.ndarray, x0: np.ndarray, y0: np.ndarray, bw: np.ndarray,
              bh: np.ndarray, w: int):
    """Flat pixel indices of many boxes, grouped per box (for ``ufunc.reduceat``).

    Returns (k, lx, ly, flat, starts): box index, local x / y, flat image index of every
    gathered pixel, and the start of each box's segment.
    """
    sizes = bw * bh
    starts = np.zeros(ids.size, np.int64)
    np.cumsum(sizes[:-1], out=starts[1:])
    total = int(sizes.sum())
    k = np.repeat(np.arange(ids.size, dtype=np.int32), sizes)
    local = np.arange(total, dtype=np.int32) - starts[k].astype(np.int32)
    ly, lx = np.divmod(local, bw[k])
    flat = (y0[k] + ly) * w + (x0[k] + lx)
    return k, lx, ly, flat, starts


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


def _level_seeds(d: np.ndarray, d_bg: np.ndarray, sigma: float, a_lo: float, a_hi: float,
                 fine: bool = True) -> tuple[np.ndarray, ...]:
    """Seed ellipses of one pyramid level (all in that level's pixels).

    The surround is an opening with a window just larger than ``a_hi``, so a blob is
    judged against skin right around it (a marker on the dark side of a shading edge
    does not merge with the dark skin). Candidates are connected regions at half their
    local peak contrast; their coverage moments give a seed centre and ellipse.
    """
    h, w = d.shape
    bg = _background(d_bg, a_hi)
    top = cv2.subtract(d, bg)
    t_low = max(MIN_CONTRAST, 4.0 * sigma)
    # Light smoothing keeps pixel noise from shattering regions; reduced levels are
    # already smooth (and blurring them would join neighbouring dots of a dense grid).
    top_s = cv2.GaussianBlur(top, (5, 5), 1.0) if fine else top
    local_max = cv2.dilate(top_s, _KERNEL_LOCALMAX)
    half = cv2.compare(cv2.add(top_s, top_s), local_max, cv2.CMP_GE)
    floor = cv2.max(cv2.convertScaleAbs(cv2.bitwise_not(bg), alpha=REL_FLOOR), int(t_low))
    cand = cv2.bitwise_and(half, cv2.compare(top_s, floor, cv2.CMP_GE))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(cand, connectivity=8,
                                                           ltype=cv2.CV_16U)
    empty = tuple(np.zeros(0) for _ in range(5))
    if n <= 1:
        return empty
    x0, y0, bw, bh, area = (stats[1:, i].astype(np.int32) for i in range(5))
    ext = np.maximum(bw, bh)
    keep = (area >= max(3.0, 0.5 * a_lo * a_lo)) & (ext >= 1.2 * a_lo - 2)
    keep &= ext <= 2.4 * a_hi + 6
    ids = (np.flatnonzero(keep) + 1).astype(np.int32)
    if ids.size == 0:
        return empty
    pad = 2
    x0, y0 = x0[ids - 1] - pad, y0[ids - 1] - pad
    bw, bh = bw[ids - 1] + 2 * pad, bh[ids - 1] + 2 * pad
    x0c, y0c = np.clip(x0, 0, w - 1), np.clip(y0, 0, h - 1)
    bw, bh = np.minimum(x0 + bw, w) - x0c, np.minimum(y0 + bh, h) - y0c
    x0, y0 = x0c, y0c
    k, lx, ly, flat, starts = _segments(ids, x0, y0, bw, bh, w)
    lab = np.take(labels.reshape(-1), flat)
    ring_lab = np.take(cv2.dilate(labels, _KERNEL_RING).reshape(-1), flat)
    idk = ids[k]
    own = lab == idk
    near = own | ((lab == 0) & (ring_lab == idk))
    tv = np.take(top.reshape(-1), flat).astype(np.float32)
    peak = np.maximum.reduceat(np.where(own, tv, 0.0), starts)
    t0 = min(2.0 * sigma, 0.5 * t_low)
    cov = np.clip((tv - t0) / np.maximum(peak - t0, 1e-6)[k], 0.0, 1.0) * near
    fx, fy = lx.astype(np.float32), ly.astype(np.float32)
    cx_, cy_ = cov * fx, cov * fy
    mx, my, a, b, th = _ellipse_from_moments(
        np.add.reduceat(cov, starts).astype(np.float64),
        np.add.reduceat(cx_, starts).astype(np.float64),
        np.add.reduceat(cy_, starts).astype(np.float64),
        np.add.reduceat(cx_ * fx, starts).astype(np.float64),
        np.add.reduceat(cy_ * fy, starts).astype(np.float64),
        np.add.reduceat(cx_ * fy, starts).astype(np.float64))
    ok = (a >= a_lo) & (a <= a_hi)
    return (x0 + mx)[ok], (y0 + my)[ok], a[ok], b[ok], th[ok]


def _refine(d: np.ndarray, raw: np.ndarray, sigma: float, cx, cy, a, b, th, colour: int):
    """Full-resolution centre, ellipse and features of seed ellipses.

    Per candidate, a plane fitted to the ring of pixels around the seed ellipse is the
    local background (so a shading gradient neither shifts the centre nor changes the
    contrast); each pixel's coverage is its contrast over that plane scaled by the
    candidate's peak contrast and clipped to 0-1 (the painted fraction of an
    anti-aliased pixel); the coverage moments inside the support give the centre and
    ellipse.
    """
    h, w = d.shape
    m = SUPPORT_MARGIN
    ext = np.ceil(a + m + RING_WIDTH + 1).astype(np.int32)
    xi, yi = np.rint(cx).astype(np.int32), np.rint(cy).astype(np.int32)
    x0, y0 = np.clip(xi - ext, 0, w - 1), np.clip(yi - ext, 0, h - 1)
    bw = np.minimum(xi + ext + 1, w) - x0
    bh = np.minimum(yi + ext + 1, h) - y0
    good = (bw > 2) & (bh > 2)
    n = cx.size
    k, lx, ly, flat, starts = _segments(np.arange(n, dtype=np.int32), x0, y0,
                                        np.maximum(bw, 1), np.maximum(bh, 1), w)
    # Coordinates relative to the seed centre, in the seed ellipse's frame.
    px = (x0[k] + lx).astype(np.float32) - cx[k].astype(np.float32)
    py = (y0[k] + ly).astype(np.float32) - cy[k].astype(np.float32)
    c, s = np.cos(th).astype(np.float32), np.sin(th).astype(np.float32)
    u = px * c[k] + py * s[k]
    v = -px * s[k] + py * c[k]
    ai, bi = (a + m).astype(np.float32), (b + m).astype(np.float32)
    ao, bo = ai + RING_WIDTH, bi + RING_WIDTH
    r_out = (u / ao[k]) ** 2 + (v / bo[k]) ** 2
    # Keep only the pixels inside the outer ellipse (the boxes are mostly corners);
    # every candidate keeps its centre pixel, so no segment becomes empty.
    sel = np.flatnonzero(r_out <= 1.0)
    k, flat, px, py, u, v = k[sel], flat[sel], px[sel], py[sel], u[sel], v[sel]
    counts = np.bincount(k, minlength=n)
    good &= counts > 0
    starts = np.zeros(n, np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    starts = np.minimum(starts, max(k.size - 1, 0))
    r_in = (u / ai[k]) ** 2 + (v / bi[k]) ** 2
    support = r_in <= 1.0
    ring = ~support
    dv = np.take(d.reshape(-1), flat).astype(np.float32)

    def plane(sel):
        wgt = sel.astype(np.float32)
        sums = [np.add.reduceat(q, starts).astype(np.float64) for q in (
            wgt, wgt * px, wgt * py, wgt * px * px, wgt * px * py, wgt * py * py,
            wgt * dv, wgt * dv * px, wgt * dv * py)]
        n0, sx, sy, sxx, sxy, syy, sd, sdx, sdy = sums
        mat = np.stack([np.stack([n0, sx, sy], -1), np.stack([sx, sxx, sxy], -1),
                        np.stack([sy, sxy, syy], -1)], -2)
        mat += np.eye(3) * 1e-3
        rhs = np.stack([sd, sdx, sdy], -1)
        coef = np.linalg.solve(mat, rhs[..., None])[..., 0]
        coef[n0 < 3] = 0.0
        coef[n0 < 3, 0] = sd[n0 < 3] / np.maximum(n0[n0 < 3], 1)
        return coef, n0

    coef, _ = plane(ring)
    res = dv - (coef[k, 0] + coef[k, 1] * px + coef[k, 2] * py).astype(np.float32)
    # Second pass without ring pixels well above the plane (a neighbouring marker's
    # edge, a dark crease): they would lift the background under this blob.
    peak = np.maximum.reduceat(np.where(support, res, -1e9), starts)
    ring2 = ring & (res < np.maximum(3.0 * sigma, 0.25 * peak[k]))
    coef, n_ring = plane(ring2)
    res = dv - (coef[k, 0] + coef[k, 1] * px + coef[k, 2] * py).astype(np.float32)
    peak = np.maximum.reduceat(np.where(support, res, -1e9), starts).astype(np.float64)
    pk = np.maximum(peak, 1e-3).astype(np.float32)
    # Paint is opaque: a fully covered pixel has the paint's level whatever the skin
    # under it, so the full-coverage contrast is (paint level - plane) at each pixel,
    # not one number per blob (which would weight the centroid towards brighter skin).
    core = np.maximum.reduceat(np.where(support, dv, -1e9), starts).astype(np.float32)
    full = np.maximum(core[k] - (dv - res), 0.25 * pk[k])
    cov = np.clip(res / full, 0.0, 1.0) * support
    # Moments about the seed centre (small numbers) for float32 accuracy.
    cpx, cpy = cov * px, cov * py
    s0 = np.add.reduceat(cov, starts).astype(np.float64)
    mx, my, a2, b2, th2 = _ellipse_from_moments(
        s0, np.add.reduceat(cpx, starts).astype(np.float64),
        np.add.reduceat(cpy, starts).astype(np.float64),
        np.add.reduceat(cpx * px, starts).astype(np.float64),
        np.add.reduceat(cpy * py, starts).astype(np.float64),
        np.add.reduceat(cpx * py, starts).astype(np.float64))
    ncx, ncy = cx + mx, cy + my
    half = support & (res >= 0.5 * pk[k])
    n_half = np.add.reduceat(half.astype(np.float32), starts).astype(np.float64)
    hx = np.add.reduceat(half * px, starts) / np.maximum(n_half, 1)
    hy = np.add.reduceat(half * py, starts) / np.maximum(n_half, 1)
    ringf = ring.astype(np.float32)
    n_r = np.maximum(np.add.reduceat(ringf, starts).astype(np.float64), 1)
    rr = np.sqrt(np.add.reduceat(ring2 * res * res, starts) / np.maximum(n_ring, 1))
    ring_fill = np.add.reduceat(ring & (res >= 0.5 * pk[k]), starts) / n_r
    ell_area = math.pi * a2 * b2
    bg_c = np.clip(coef[:, 0], 0, 255)
    rv = np.take(raw.reshape(-1), flat)
    sat_level = 255 if colour == WHITE else 0
    saturated = np.add.reduceat((half & (rv == sat_level)).astype(np.float32), starts)
    saturated = saturated > 0.3 * n_half
    feats = np.column_stack([
        np.log(np.maximum(peak, 1e-3) / sigma),
        np.clip(peak / np.maximum(255.0 - bg_c, 1.0), 0, 2),
        np.clip(np.abs(1.0 - s0 / ell_area), 0, 5),
        np.clip(np.abs(1.0 - n_half / ell_area), 0, 5),
        np.clip(rr / np.maximum(peak, 1e-3), 0, 2),
        np.clip(np.hypot(hx - mx, hy - my) / np.maximum(b2, 0.5), 0, 5),
        b2 / a2,
        ring_fill,
    ])
    ok = good & (peak > 0) & np.isfinite(feats).all(axis=1)
    # A refined centre far from its seed means the support did not hold the blob.
    ok &= np.hypot(mx, my) <= 0.5 * a + 1.0
    return ncx, ncy, a2, b2, th2, feats, saturated, ok


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
    if colour == BLACK:
        d = cv2.bitwise_not(image8)
        # Saturated highlights are not a surround level: hide them from the opening so
        # the skin between two highlights keeps its own level (they give no contrast).
        d_for_bg = cv2.max(d, cv2.compare(image8, SATURATED, cv2.CMP_GE))
    else:
        d = d_for_bg = image8
    sigma = _noise_sigma(image8) if noise is None else float(noise)
    seeds = []
    pyramid = {1: (d, d_for_bg, image8)}
    for f, lo, hi in _levels(min_radius, max_radius):
        if h // f < 16 or w // f < 16:
            break
        if f not in pyramid:
            size = (w // f, h // f)
            pyramid[f] = tuple(
                cv2.resize(x[: h // f * f, : w // f * f], size, interpolation=cv2.INTER_AREA)
                for x in (d, d_for_bg, image8))
        dl, bl, _ = pyramid[f]
        sx, sy, sa, sb, st = _level_seeds(dl, bl, max(0.7, sigma / f), max(lo / f, 1.0),
                                          hi / f, fine=f == 1)
        # A level pixel i covers full-res pixels f*i .. f*i + f - 1.
        seeds.append((sx * f + 0.5 * (f - 1), sy * f + 0.5 * (f - 1), sa * f, sb * f, st,
                      np.full(sx.size, f)))
    empty = Candidates(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                       np.zeros((0, len(FEATURE_NAMES))), np.zeros(0, bool))
    if not seeds:
        return empty
    cx, cy, a, b, th, lev = (np.concatenate([s[i] for s in seeds]) for i in range(6))
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
    n = cx.size
    cx2, cy2, a2, b2, th2 = (np.zeros(n) for _ in range(5))
    feats = np.zeros((n, len(FEATURE_NAMES)))
    saturated, ok = np.zeros(n, bool), np.zeros(n, bool)
    for f in np.unique(g):
        i = np.flatnonzero(g == f)
        dl, _, rl = pyramid[int(f)]
        o = 0.5 * (f - 1)
        r = _refine(dl, rl, max(0.7, sigma / f), (cx[i] - o) / f, (cy[i] - o) / f, a[i] / f,
                    b[i] / f, th[i], colour)
        cx2[i], cy2[i], a2[i], b2[i] = r[0] * f + o, r[1] * f + o, r[2] * f, r[3] * f
        th2[i], feats[i], saturated[i], ok[i] = r[4], r[5], r[6], r[7]
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
