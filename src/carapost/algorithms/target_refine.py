"""Sub-pixel pieces of the Target Tracker's refinement: resampling and the marker weight.

:mod:`carapost.algorithms.target_track` refines each integer NCC peak by Lucas-Kanade
on the pattern. Two things decide how close that refinement gets to the marker's true
centre, measured against the truth projections of rendered takes:

- **Resampling.** Every Lucas-Kanade iteration resamples the image at a sub-pixel
  position, and the keyframe pattern itself is sampled at the keyframe's sub-pixel
  position. Keys' 4-tap cubic convolution smooths differently at every sub-pixel phase,
  so a sharp marker edge resampled at two different phases no longer matches at the
  true shift: a bias of up to about 0.02 px that depends on the phase (most of the
  median error on noiseless renders). Keys' 6-point cubic convolution has a much
  flatter response across phases and is still exact on polynomials up to cubics; on
  the speech take it lowered the median error on noiseless renders from 0.028 to
  0.020 px (the 6-tap Lanczos kernel did as well, but is not exact on a ramp).
- **What is weighed.** The pattern box holds the marker and its surroundings. The
  surroundings of an eyelid or a mouth-corner marker are the lid's edge, the lip line
  or the shadow of the nose: strong edges that do not move with the marker. With the
  Gaussian window alone a small, obliquely seen marker (2-3 px across, low contrast) is
  outweighed by them and the refinement is pulled by 0.1-0.4 px. :func:`marker_weight`
  finds the marker in the pattern (a dark or bright blob at the centre, isolated by a
  morphological top-hat) and weighs the blob and a rim around it only.

Coordinates follow OpenCV's pixel-centre convention as everywhere in carapost.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["TAPS", "cubic6_weights", "denoise_pattern", "gaussian_window", "marker_weight",
           "noise_sigma", "shift_patch", "shrink_odd_noise"]

#: Samples per axis of the resampling kernel (6-point cubic): offsets -2 .. 3.
TAPS = 6
#: Samples the kernel needs before / after the integer part of a position.
MARGIN_BEFORE, MARGIN_AFTER = 2, 3


def cubic6_weights(t: float) -> NDArray[np.float64]:
    """The six weights of Keys' 6-point cubic convolution for phase ``t``.

    The kernel (Keys 1981, the fourth-order member of the cubic convolution family)
    reproduces polynomials up to cubics exactly and keeps more of the high frequencies
    than the 4-point kernel, so the phase of the resampling biases a sharp edge much
    less.

    Parameters
    ----------
    t : float
        Sub-pixel phase in [0, 1).

    Returns
    -------
    ndarray, shape (6,) float64
        Weights of the samples at offsets -2 .. 3.

    Examples
    --------
    >>> (cubic6_weights(0.0).round(6) + 0.0).tolist()
    [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    >>> w = cubic6_weights(0.37)
    >>> round(float(w.sum()), 12), round(float(w @ np.arange(-2, 4)), 12)
    (1.0, 0.37)
    """
    # the samples at -2 .. 3 lie at distances 2 + t, 1 + t, t, 1 - t, 2 - t, 3 - t, each
    # on a fixed piece of the kernel (scalar arithmetic: this runs for every resampling)
    a, b, c, d, e, f = 2.0 + t, 1.0 + t, t, 1.0 - t, 2.0 - t, 3.0 - t
    return np.array((
        ((a / 12.0 - 2.0 / 3.0) * a + 1.75) * a - 1.5,
        ((-7.0 / 12.0 * b + 3.0) * b - 59.0 / 12.0) * b + 2.5,
        (4.0 / 3.0 * c - 7.0 / 3.0) * c * c + 1.0,
        (4.0 / 3.0 * d - 7.0 / 3.0) * d * d + 1.0,
        ((-7.0 / 12.0 * e + 3.0) * e - 59.0 / 12.0) * e + 2.5,
        ((f / 12.0 - 2.0 / 3.0) * f + 1.75) * f - 1.5))


def shift_patch(crop: NDArray[np.float64], x: float, y: float, size: int
                ) -> NDArray[np.float64]:
    """The ``size`` x ``size`` patch of ``crop`` centred on (x, y) in crop pixels.

    Separable 6-point cubic convolution (:func:`cubic6_weights`): every pixel of the
    patch has the same sub-pixel phase, so the patch is one separable correlation with
    two 6-tap kernels
    (``cv2.sepFilter2D``) over the ``size + 5`` square that holds its samples. Samples
    beyond the crop repeat its border (callers keep a margin of
    ``size // 2 + 2`` before and ``size // 2 + 3`` after ``floor(x)``, ``floor(y)``).

    Parameters
    ----------
    crop : ndarray (H, W) float64 or float32
    x, y : float
        Patch centre (crop px).
    size : int
        Side of the patch (px, odd).

    Returns
    -------
    ndarray, shape (size, size), the dtype of ``crop``

    Examples
    --------
    A linear ramp is resampled exactly:

    >>> ramp = np.tile(np.arange(20, dtype=np.float64), (20, 1))
    >>> shift_patch(ramp, 9.25, 9.0, 3)[1].round(6).tolist()
    [8.25, 9.25, 10.25]
    """
    h = size // 2
    ix, iy = math.floor(x), math.floor(y)
    c0, r0 = ix - h - MARGIN_BEFORE, iy - h - MARGIN_BEFORE
    n = size + TAPS - 1
    H, W = crop.shape[:2]
    if r0 < 0 or c0 < 0 or r0 + n > H or c0 + n > W:
        crop = cv2.copyMakeBorder(crop, max(-r0, 0), max(r0 + n - H, 0), max(-c0, 0),
                                  max(c0 + n - W, 0), cv2.BORDER_REPLICATE)
        r0, c0 = max(r0, 0), max(c0, 0)
    src = crop[r0:r0 + n, c0:c0 + n]
    out = cv2.sepFilter2D(src, -1, cubic6_weights(x - ix), cubic6_weights(y - iy),
                          anchor=(0, 0), borderType=cv2.BORDER_CONSTANT)
    return out[:size, :size]


def gaussian_window(size: int, sigma: float) -> NDArray[np.float64]:
    """The ``size`` x ``size`` Gaussian centred on the middle pixel, peak 1 (px sigma);
    all ones when ``sigma <= 0``. The tracker's score window and fit weights start here.

    >>> float(gaussian_window(3, 0.0).sum()), round(float(gaussian_window(3, 1.0)[0, 1]), 4)
    (9.0, 0.6065)
    """
    if sigma <= 0:
        return np.ones((size, size))
    g = np.arange(size) - size // 2
    return np.exp(-0.5 * (g[:, None] ** 2 + g[None, :] ** 2) / sigma ** 2)


def marker_weight(tpl: NDArray[np.floating], sigma: float, *, rim: int = 4,
                  min_contrast: float = 2.0) -> NDArray[np.float64]:
    """Refinement weights that follow the marker in a pattern, not its surroundings.

    The marker is the dark or bright blob at the pattern's centre: a black (or white)
    top-hat with a disc half the pattern's side removes everything larger (lid and lip
    edges, shading), the part above 30 % of the top-hat's value at the centre that is
    connected to the centre is the blob, and the weight is that blob grown by ``rim``
    px (its edge is where the position information is), softened by one pixel and
    tapered by the Gaussian window. A pattern without a clear blob at its centre (a
    marker larger than half the pattern, or none) keeps the Gaussian window.

    Parameters
    ----------
    tpl : ndarray, shape (P, P)
        The pattern, zero mean and unit variance.
    sigma : float
        Sigma of the Gaussian window (px); <= 0 for none.
    rim : int
        Pixels added around the blob.
    min_contrast : float
        The top-hat's value at the centre must be at least this many times its upper
        quartile over the pattern (the level of the noise and texture, which the blob,
        covering well under a quarter of the box, does not raise); below it there is no
        clear blob. Relative to the top-hat, not to the pattern's contrast: a faint
        marker beside a strong edge is the case the weight is for.

    Returns
    -------
    ndarray, shape (P, P) float64
        Non-negative weights (not normalised).

    Examples
    --------
    A small dark disc beside a strong edge: the weight keeps the disc, not the edge.

    >>> yy, xx = np.mgrid[0:21, 0:21]
    >>> img = np.where(xx > 16, 200.0, 100.0) - 60.0 * (np.hypot(xx - 10, yy - 10) < 2)
    >>> tpl = (img - img.mean()) / img.std()
    >>> w = marker_weight(tpl, 3.8)
    >>> bool(w[10, 10] > 0.9 * w.max()), bool(w[10, 18] < 0.01 * w.max())
    (True, True)
    """
    n = tpl.shape[0]
    c = n // 2
    gauss = gaussian_window(n, sigma)
    k = max(int(n * 0.5) | 1, 3)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    t = np.ascontiguousarray(tpl, dtype=np.float32)
    black = cv2.morphologyEx(t, cv2.MORPH_BLACKHAT, disc)
    white = cv2.morphologyEx(t, cv2.MORPH_TOPHAT, disc)
    centre = np.s_[c - 1:c + 2, c - 1:c + 2]
    hat = black if black[centre].max() >= white[centre].max() else white
    peak = float(hat[centre].max())
    if not (peak > 1e-6 and peak >= min_contrast * float(np.percentile(hat, 75))):
        return gauss
    _, labels = cv2.connectedComponents((hat > 0.3 * peak).astype(np.uint8))
    blob = (labels == labels[centre].max()).astype(np.uint8)
    if rim > 0:
        blob = cv2.dilate(blob, cv2.getStructuringElement(
            cv2.MORPH_ELLIPSE, (2 * rim + 1, 2 * rim + 1)))
    w = cv2.GaussianBlur(blob.astype(np.float64), (0, 0), 1.0)
    # a trace of the window everywhere keeps the system well posed
    return w * gauss + 1e-3 * gauss


def noise_sigma(image: NDArray[np.floating]) -> float:
    """Robust standard deviation of the pixel noise of a grey image (grey levels).

    Immerkaer's estimator: the image filtered by the 3 x 3 kernel
    ``[[1, -2, 1], [-2, 4, -2], [1, -2, 1]]`` (the difference of two Laplacians, which
    cancels smooth shading and band-limited skin texture), whose response to white
    noise of standard deviation ``s`` has standard deviation ``6 s``; the median
    absolute response (x 1.4826) is used, so that the marker's edges do not count.

    Parameters
    ----------
    image : ndarray (H, W)
        At least 3 x 3.

    Returns
    -------
    float
        Noise standard deviation (grey levels).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> yy, xx = np.mgrid[0:80, 0:80]
    >>> smooth = 100 + 0.5 * xx + 20 * np.sin(yy / 9.0)
    >>> noisy = smooth + rng.normal(0, 5, smooth.shape)
    >>> round(noise_sigma(smooth), 3), round(noise_sigma(noisy))
    (0.0, 5)
    """
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float32)
    r = cv2.filter2D(np.asarray(image, dtype=np.float32), -1, k)[1:-1, 1:-1]
    return float(1.4826 * np.median(np.abs(r)) / 6.0)


def shrink_odd_noise(tpl: NDArray[np.floating], weight: NDArray[np.floating],
                     noise_var: float = math.inf) -> NDArray[np.float64]:
    """The pattern with the noise of its odd part, about its centre, shrunk away.

    A marker disc, and the rim of skin right around it, is nearly point-symmetric about
    the keyframe position; the pattern's noise is not. The odd part of the noise is what
    moves the pattern's apparent centre (the refinement's gradients of a symmetric disc
    are odd), so a noisy keyframe pattern puts every frame of the track off by the same
    0.1-0.3 px. Inside ``weight`` the odd part is shrunk by the Wiener factor
    ``max(0, 1 - noise / odd energy)``: a pattern whose odd part is no more than the
    noise's becomes symmetric there, one with a real asymmetry (a lid's edge, a lip
    line) keeps it. Outside the weight the pattern is unchanged.

    Parameters
    ----------
    tpl : ndarray, shape (P, P)
        The pattern (zero mean, unit variance), centred on the keyframe position.
    weight : ndarray, shape (P, P)
        Where the marker is (the refinement's marker weight), any positive scale.
    noise_var : float
        Variance of the pixel noise in the pattern's units (the image's noise variance
        over the patch's variance); infinite (the default): all of the odd part inside
        the weight is taken as noise, the pattern becomes symmetric there (the
        tracker's choice: on the renders the skin in the marker's rim is odd structure
        that does not move with the marker either).

    Returns
    -------
    ndarray, shape (P, P) float64

    Examples
    --------
    A symmetric disc with noise: most of the odd part (within the weight) goes; without
    noise, or beside a real edge, the pattern keeps its odd part.

    >>> rng = np.random.default_rng(3)
    >>> yy, xx = np.mgrid[-10:11, -10:11]
    >>> disc = -1.0 / (1 + np.exp((np.hypot(xx, yy) - 3) * 2.0))
    >>> noise = rng.normal(0, 0.1, disc.shape)
    >>> w = np.exp(-(xx ** 2 + yy ** 2) / 50.0)
    >>> def odd_left(t, out):
    ...     odd = lambda a: np.abs(0.5 * (a - a[::-1, ::-1])) * w
    ...     return round(float(odd(out).sum() / odd(t).sum()), 2)
    >>> odd_left(disc + noise, shrink_odd_noise(disc + noise, w, 0.01))
    0.48
    >>> odd_left(disc + noise, shrink_odd_noise(disc + noise, w, 0.0))
    1.0
    >>> edge = disc + (xx > 4) + noise
    >>> odd_left(edge, shrink_odd_noise(edge, w, 0.01))
    0.97
    """
    t = np.asarray(tpl, dtype=np.float64)
    m = np.asarray(weight, dtype=np.float64)
    m = m / m.max() if m.max() > 0 else m
    odd = 0.5 * (t - t[::-1, ::-1])
    # a linear ramp is odd too, but it is the skin's shading (the refinement models it
    # with its own terms): kept, the rest of the odd part is shrunk
    n = t.shape[0]
    g = np.arange(n) - n // 2
    ramps = np.stack([np.tile(g, (n, 1)).ravel(), np.repeat(g, n).astype(float)])
    a = ramps * m.ravel()
    coef = np.linalg.lstsq(a @ ramps.T, a @ odd.ravel(), rcond=None)[0]
    odd = odd - (coef @ ramps).reshape(odd.shape)
    energy = float((m * odd * odd).sum() / max(m.sum(), 1e-12))
    # the odd part of white noise of variance v has variance v / 2 per pixel
    keep = max(0.0, 1.0 - 0.5 * noise_var / energy) if energy > 0 else 1.0
    return t - m * (1.0 - keep) * odd



def denoise_pattern(image: NDArray[np.floating], xy: NDArray[np.floating] | tuple,
                    raw: NDArray[np.floating], norm: NDArray[np.floating],
                    weight_sigma: float) -> NDArray[np.float64]:
    """A keyframe pattern with the noise of its odd part shrunk inside the marker weight.

    The odd part of the pattern's own noise about the keyframe position puts every frame
    of a track off by the same amount (a faint, obliquely seen marker under noise 5:
    0.1-0.3 px); :func:`shrink_odd_noise` shrinks it by how far it exceeds the image's
    noise (:func:`noise_sigma` around the keyframe, scaled by the resampling's gain at
    the keyframe's sub-pixel phase and by the patch's variance).

    Parameters
    ----------
    image : ndarray (H, W)
        The keyframe's image.
    xy : array_like, shape (2,)
        Keyframe position (raw px).
    raw, norm : ndarray, shape (P, P)
        The pattern as sampled and normalised (zero mean, unit variance).
    weight_sigma : float
        Sigma of the marker weight's Gaussian window (px).

    Returns
    -------
    ndarray, shape (P, P) float64
        The pattern (to be normalised again); ``norm`` itself where there is no noise.
    """
    x, y = float(xy[0]), float(xy[1])
    n = raw.shape[0]
    ix, iy = int(round(x)), int(round(y))
    area = np.asarray(image[max(iy - n, 0):iy + n + 1, max(ix - n, 0):ix + n + 1])
    sigma = noise_sigma(area) if min(area.shape[:2]) >= 3 else 0.0
    if not sigma > 0 or not float(raw.var()) > 0:
        return np.asarray(norm, dtype=np.float64)
    gain = float((cubic6_weights(x - math.floor(x)) ** 2).sum()
                 * (cubic6_weights(y - math.floor(y)) ** 2).sum())
    var = sigma * sigma * gain / float(raw.var())
    return shrink_odd_noise(norm, marker_weight(norm, weight_sigma), var)
