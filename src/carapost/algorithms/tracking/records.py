"""Inputs and outputs of the tracker: detections per frame, start state, result."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.codes import PointArrays

#: Detections of one frame: one ``(centre [N, 2], axes [N, 2] or None)`` per camera.
FrameDetections = Sequence[tuple[NDArray[Any], NDArray[Any] | None]]

#: The tracker's output: the shared point-array record (see
#: :class:`carapost.algorithms.codes.PointArrays`).
TrackResult = PointArrays


@dataclass
class InitialState:
    """The tracked points in the start frame.

    Attributes
    ----------
    positions : ndarray, shape (P, 3)
        3D positions (mm); points with NaN are carried but never tracked.
    kind : ndarray, shape (P,)
        ``KIND_FACE`` or ``KIND_BRIM``; brim points keep their start position (known
        structure) and fix the cameras of every frame.
    obs : ndarray, shape (P, C, 2), optional
        2D observations in the start frame (templates for patch tracking).
    axes : ndarray, shape (P, C, 2), optional
        Blob semi-axes of those observations (for the blob size test).
    """

    positions: NDArray[np.float64]
    kind: NDArray[np.int8]
    obs: NDArray[np.float64] | None = None
    axes: NDArray[np.float64] | None = None


class RaggedDetections:
    """Detections of a whole take as the model stores them, served frame by frame.

    Parameters
    ----------
    offsets : array_like, shape (F * C + 1,)
        Image ``(f, c)`` owns rows ``offsets[f * C + c]:offsets[f * C + c + 1]``.
    centre : array_like, shape (N, 2)
    axes : array_like, shape (N, 2), optional
    n_cameras : int
    score : array_like, shape (N,), optional
        The detector's probability of each blob (for the observations' 2D noise,
        :func:`carapost.algorithms.blob_noise.blob_noise_scale`).
    """

    def __init__(self, offsets: ArrayLike, centre: ArrayLike, axes: ArrayLike | None,
                 n_cameras: int, score: ArrayLike | None = None) -> None:
        self.offsets = np.asarray(offsets, dtype=np.int64)
        self.centre = np.asarray(centre)
        self.axes = None if axes is None else np.asarray(axes)
        self.n_cameras = int(n_cameras)
        self.score = None if score is None else np.asarray(score)

    def __call__(self, frame: int) -> list[tuple[NDArray[Any], NDArray[Any] | None]]:
        """Per camera ``(centre, axes)`` of one frame (float64 copies)."""
        C = self.n_cameras
        out = []
        for c in range(C):
            i = frame * C + c
            s, e = int(self.offsets[i]), int(self.offsets[i + 1])
            ax = None if self.axes is None else self.axes[s:e].astype(np.float64)
            out.append((self.centre[s:e].astype(np.float64), ax))
        return out

    def scores(self, frame: int) -> list[NDArray[Any] | None]:
        """Per camera the blobs' scores of one frame (None without scores)."""
        C = self.n_cameras
        rows = self.offsets[frame * C:(frame + 1) * C + 1]
        if self.score is None:
            return [None] * C
        return [self.score[rows[c]:rows[c + 1]] for c in range(C)]
