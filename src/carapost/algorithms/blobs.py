"""Blob (painted marker) detection in camera images.

The detector turns one grey image into a table of elliptical blob detections, each with
a sub-pixel centre, semi-axes, angle, colour (black / white) and a calibrated
probability ``score`` that it is really a blob centre. It works in five steps, all on
whole images with OpenCV / numpy (no Python loop per pixel or per blob):

1. Polarity: black blobs are found on the inverted image, so blobs are always bright
   peaks ``d`` on a darker surround.
2. Surround at matching scale: a morphological opening of ``d`` with a window larger
   than the largest allowed blob (computed on a 2x / 4x reduced image for speed) is the
   local background; the top-hat ``t = d - opening(d)`` is each pixel's contrast
   against its surround.
3. Boundary: a pixel belongs to a blob when its contrast is at least half of the
   highest contrast nearby (a 9x9 window) and clearly above the image noise; connected
   components of that mask are the candidates, and their outline is the half-contrast
   boundary.
4. Shape and centre: per candidate, the coverage ``c = (t - t0) / (peak - t0)`` clipped
   to 0-1 over the candidate and a 2-pixel ring gives, through its moments, the
   sub-pixel centre (coverage centroid) and the fitted ellipse (axes from the
   eigenvalues of the second moments, ``a = 2 sqrt(lambda_1)``).
5. Probability: a logistic model over a few scale-free features (signal-to-noise,
   contrast relative to the surround, how well the coverage fills its ellipse, edge
   sharpness, symmetry, axis ratio) gives the probability that the candidate is a
   blob centre. It was fitted on synthetic blobs with known truth by
   ``scripts/train_blob_model.py`` (weights in ``carapost/resources/blob_model.json``)
   so that the score means what it says. Candidates whose semi-major axis is outside
   the radius range, or whose score is below the threshold, are dropped.

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
    "edge_ratio",
    "asymmetry",
    "axis_ratio",
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

_KERNEL_LOCALMAX = cv2.getStructuringElement(cv2.MORPH_RECT, (9, 9))
_KERNEL_RING = cv2.getStructuringElement(cv2.MORPH_RECT, (5, 5))


def _background(d: np.ndarray, max_radius: float) -> np.ndarray:
    """Surround level: grey opening of ``d`` by a square larger than the largest blob."""
    h, w = d.shape
    f = 4 if max_radius >= 12 else (2 if max_radius >= 5 else 1)
    if f > 1:
        small = cv2.resize(d, (w // f, h // f), interpolation=cv2.INTER_AREA)
    else:
        small = d
    k = 2 * int(math.ceil(max_radius / f)) + 3
    ker = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    bg = cv2.morphologyEx(small, cv2.MORPH_OPEN, ker, borderType=cv2.BORDER_REPLICATE)
    bg = cv2.blur(bg, (3, 3))
    if f > 1:
        bg = cv2.resize(bg, (w, h), interpolation=cv2.INTER_LINEAR)
    return bg


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
    bg = _background(d_for_bg, max_radius)
    top = cv2.subtract(d, bg)
    sigma = _noise_sigma(image8) if noise is None else float(noise)
    t_low = max(3.0, 3.5 * sigma)
    # The boundary mask is taken on a lightly smoothed top-hat so pixel noise does not
    # shatter the background into thousands of one-pixel components.
    top_s = cv2.GaussianBlur(top, (5, 5), 1.0)
    local_max = cv2.dilate(top_s, _KERNEL_LOCALMAX)
    # Half-contrast boundary: 2*t >= local max (saturating add keeps this exact).
    half = cv2.compare(cv2.add(top_s, top_s), local_max, cv2.CMP_GE)
    # Contrast floor: above the noise and a tenth of the surround's headroom, so skin
    # texture and pores never become candidates (true markers are far above this).
    floor = cv2.max(cv2.convertScaleAbs(cv2.bitwise_not(bg), alpha=REL_FLOOR), int(t_low))
    strong = cv2.compare(top_s, floor, cv2.CMP_GE)
    cand = cv2.bitwise_and(half, strong)
    n, labels, stats, _cent = cv2.connectedComponentsWithStats(cand, connectivity=8,
                                                               ltype=cv2.CV_16U)
    empty = Candidates(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
                       np.zeros((0, len(FEATURE_NAMES))), np.zeros(0, bool))
    if n <= 1:
        return empty
    x0, y0, bw, bh, area = (stats[1:, i].astype(np.int32) for i in range(5))
    ext = np.maximum(bw, bh)
    # Cheap gates on the bounding box and area before any per-pixel work.
    keep = (area >= max(3.0, 0.5 * min_radius * min_radius)) & (ext >= 1.2 * min_radius - 2)
    keep &= ext <= 2.0 * max_radius * 1.2 + 6
    ids = (np.flatnonzero(keep) + 1).astype(np.int32)
    if ids.size == 0:
        return empty
    pad = 2
    x0, y0 = x0[ids - 1] - pad, y0[ids - 1] - pad
    bw, bh = bw[ids - 1] + 2 * pad, bh[ids - 1] + 2 * pad
    x0c, y0c = np.clip(x0, 0, w - 1), np.clip(y0, 0, h - 1)
    bw = np.minimum(x0 + bw, w) - x0c
    bh = np.minimum(y0 + bh, h) - y0c
    x0, y0 = x0c, y0c
    # Gather every pixel of every padded bounding box, grouped per candidate.
    sizes = bw * bh
    starts = np.zeros(ids.size, np.int64)
    np.cumsum(sizes[:-1], out=starts[1:])
    total = int(sizes.sum())
    k = np.repeat(np.arange(ids.size, dtype=np.int32), sizes)
    local = np.arange(total, dtype=np.int32) - starts[k].astype(np.int32)
    ly, lx = np.divmod(local, bw[k])
    flat = (y0[k] + ly) * w + (x0[k] + lx)
    lab = np.take(labels.reshape(-1), flat)
    ring_lab = np.take(cv2.dilate(labels, _KERNEL_RING).reshape(-1), flat)
    idk = ids[k]
    own = lab == idk
    near = own | ((lab == 0) & (ring_lab == idk))
    tv = np.take(top.reshape(-1), flat).astype(np.float64)

    # Peak contrast per candidate (segments are contiguous: reduceat).
    peak = np.maximum.reduceat(np.where(own, tv, 0.0), starts)
    t0 = min(2.0 * sigma, 0.5 * t_low)
    cov = np.clip((tv - t0) / np.maximum(peak - t0, 1e-6)[k], 0.0, 1.0) * near
    fx = lx.astype(np.float64)
    fy = ly.astype(np.float64)
    s0 = np.add.reduceat(cov, starts)
    s0 = np.maximum(s0, 1e-9)
    mx = np.add.reduceat(cov * fx, starts) / s0
    my = np.add.reduceat(cov * fy, starts) / s0
    dx, dy = fx - mx[k], fy - my[k]
    sxx = np.add.reduceat(cov * dx * dx, starts) / s0
    syy = np.add.reduceat(cov * dy * dy, starts) / s0
    sxy = np.add.reduceat(cov * dx * dy, starts) / s0
    # Pixels are unit squares: remove their own variance (1/12) from the moments.
    sxx_c = np.maximum(sxx - 1.0 / 12.0, 1e-6)
    syy_c = np.maximum(syy - 1.0 / 12.0, 1e-6)
    tr = sxx_c + syy_c
    det_term = np.sqrt(((sxx_c - syy_c) * 0.5) ** 2 + sxy * sxy)
    l1 = tr * 0.5 + det_term
    l2 = np.maximum(tr * 0.5 - det_term, 1e-6)
    a = 2.0 * np.sqrt(l1)
    b = 2.0 * np.sqrt(l2)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx_c - syy_c)
    cx = x0 + mx
    cy = y0 + my

    n_half = np.add.reduceat(own.astype(np.float64), starts)
    n_near = np.add.reduceat((near & (cov > 0)).astype(np.float64), starts)
    # Unweighted centroid of the half-contrast region, for the symmetry feature.
    hx = np.add.reduceat(own * fx, starts) / np.maximum(n_half, 1)
    hy = np.add.reduceat(own * fy, starts) / np.maximum(n_half, 1)
    ell_area = math.pi * a * b
    bg_c = bg[np.clip(np.rint(cy).astype(np.int64), 0, h - 1),
              np.clip(np.rint(cx).astype(np.int64), 0, w - 1)].astype(np.float64)
    raw = np.take(image8.reshape(-1), flat)
    sat_level = 255 if colour == WHITE else 0
    saturated = np.add.reduceat((own & (raw == sat_level)).astype(np.float64), starts)
    saturated = saturated > 0.3 * n_half

    feats = np.column_stack([
        np.log(np.maximum(peak, 1e-3) / sigma),
        np.clip(peak / np.maximum(255.0 - bg_c, 1.0), 0, 2),
        np.abs(1.0 - s0 / ell_area),
        np.abs(1.0 - n_half / ell_area),
        np.clip(n_near / np.maximum(n_half, 1), 0, 5),
        np.hypot(hx - mx, hy - my) / np.maximum(b, 0.5),
        b / a,
    ])
    # The measured axis scatters by a few tenths of a pixel (noise, blur, thin slivers), so
    # the lower bound has a 0.5 px tolerance: a marker at the edge of the range is kept.
    ok = (a >= min_radius - MIN_RADIUS_TOLERANCE) & (a <= max_radius)
    ok &= np.isfinite(feats).all(axis=1)
    if mask is not None:
        mc = np.asarray(mask)[np.clip(np.rint(cy).astype(np.int64), 0, h - 1),
                              np.clip(np.rint(cx).astype(np.int64), 0, w - 1)]
        ok &= mc.astype(bool)
    return Candidates(
        centre=np.column_stack([cx, cy])[ok],
        axes=np.column_stack([a, b])[ok],
        angle=theta[ok],
        features=feats[ok],
        saturated=saturated[ok],
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
