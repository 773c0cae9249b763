"""Input images of the blob detector: validation, 8-bit conversion and noise level.

Examples
--------
>>> import numpy as np
>>> from carapost.algorithms.blobs.image import as_uint8, noise_sigma
>>> img = as_uint8(np.full((16, 16), 1023, np.uint16))  # a saturated 10-bit image
>>> int(img.max()), img.dtype.name
(255, 'uint8')
>>> noise_sigma(np.full((64, 64), 100, np.uint8))  # never below 0.7 grey levels
0.7
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["as_uint8", "noise_sigma", "check_mask"]


def as_uint8(image: np.ndarray) -> np.ndarray:
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


def noise_sigma(img: np.ndarray) -> float:
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



def check_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """The region-of-interest ``mask`` as an array, checked against the image ``shape``.

    Raises
    ------
    ValueError
        If the mask's shape is not ``shape``.
    """
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"mask shape {mask.shape} does not match the image shape {shape}")
    return mask

