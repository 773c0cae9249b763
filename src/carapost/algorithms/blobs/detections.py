"""Result types of the blob detector and the names of its candidate features.

Examples
--------
>>> import numpy as np
>>> from carapost.algorithms.blobs import BlobDetections
>>> det = BlobDetections.concatenate([BlobDetections.empty(), BlobDetections.empty()])
>>> len(det), det.centre.shape
(0, (0, 2))
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["BLACK", "WHITE", "FEATURE_NAMES", "N_REFINED", "BlobDetections", "Candidates"]

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
    # appearance (see appearance.py): the candidate's surroundings sampled on a grid
    # aligned with its ellipse and scaled by its semi-axes (``patch``), and on a wider
    # grid scaled by its semi-major axis in both directions (``context``), each folded
    # about both axes
    *(f"{g}_{i}_{j}" if i >= 0 else f"{g}_asym_{j}"
      for g in ("patch", "context") for i in (*range(5), -1)
      for j in (range(5) if i >= 0 else ("major", "minor"))),
    "split",
)
#: Features measured by the refinement (the appearance features and ``split`` follow).
N_REFINED = 9


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

    def __len__(self) -> int:
        """Number of detections (not of fields, as for other named tuples)."""
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
