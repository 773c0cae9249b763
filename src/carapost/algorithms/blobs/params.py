"""The Blob Parameters section of the properties (:class:`BlobParameters`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BlobParameters"]


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
