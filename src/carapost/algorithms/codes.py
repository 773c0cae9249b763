"""Record codes and the point-array layout, shared by the model and the algorithms.

The project model (:mod:`carapost.model.project`) stores every per-point sample as
columnar arrays; the algorithms produce the same arrays. Both take the codes and the
array layout from here, so they cannot drift apart.

Examples
--------
>>> from carapost.algorithms.codes import POINT_ARRAYS, RECON_NAMES, RECON_TRIANGULATED
>>> RECON_NAMES[RECON_TRIANGULATED]
'triangulated'
>>> POINT_ARRAYS["detection"]
('int32', -1)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CAMERA_ARRAYS",
    "KIND_BRIM",
    "KIND_FACE",
    "OPTIONAL_POINT_ARRAYS",
    "POINT_ARRAYS",
    "RAW_POINT_ARRAYS",
    "POINT_FILLS",
    "PointArrays",
    "RECON_FILTERED",
    "RECON_INTERPOLATED",
    "RECON_NAMES",
    "RECON_NONE",
    "RECON_SINGLE_SENSOR",
    "RECON_TRIANGULATED",
    "SOURCE_BLOB",
    "SOURCE_KEYFRAME",
    "SOURCE_MANUAL",
    "SOURCE_NAMES",
    "SOURCE_NONE",
    "SOURCE_PATCH",
    "SOURCE_TARGET",
    "blank_point_array",
]

# Reconstruction kinds of a 3D sample.
RECON_NONE = 0
RECON_TRIANGULATED = 1
RECON_SINGLE_SENSOR = 2
RECON_INTERPOLATED = 3
RECON_FILTERED = 4
RECON_NAMES = {0: "none", 1: "triangulated", 2: "single sensor", 3: "interpolated", 4: "filtered"}

# Sources of a 2D observation.
SOURCE_NONE = 0
SOURCE_BLOB = 1
SOURCE_PATCH = 2
SOURCE_KEYFRAME = 3
SOURCE_TARGET = 4
SOURCE_MANUAL = 5
SOURCE_NAMES = {0: "none", 1: "blob", 2: "patch", 3: "keyframe", 4: "target track", 5: "manual"}

# Point kinds.
KIND_FACE = 0
KIND_BRIM = 1

#: Per-point arrays, their storage dtypes and fill values (no sample), in save order.
#: Shapes (F frames, P points, C cameras): positions (F, P, 3), recon, residual and
#: sigma (F, P), the others (F, P, C) and obs (F, P, C, 2).
#: ``sigma`` is the estimated standard deviation (mm) of a 3D sample's error: from the
#: observation geometry for measured samples, from the fill method's hold-out test for
#: filled ones; NaN where unknown.
POINT_ARRAYS: dict[str, tuple[str, Any]] = {
    "positions": ("float32", np.nan),
    "recon": ("int8", RECON_NONE),
    "residual": ("float32", np.nan),
    "sigma": ("float32", np.nan),
    "obs": ("float32", np.nan),
    "source": ("int8", SOURCE_NONE),
    "detection": ("int32", -1),
    "quality": ("float16", 0.0),
    "keyframe": ("bool", False),
    # the samples' values before Filter Trajectories changed them (Remove Filtering
    # restores them); blank where the sample was never filtered
    "raw_positions": ("float32", np.nan),
    "raw_recon": ("int8", RECON_NONE),
    "raw_sigma": ("float32", np.nan),
}

#: Arrays with a camera axis.
CAMERA_ARRAYS = ("obs", "source", "detection", "quality", "keyframe")

#: The raw values kept by Filter Trajectories (a project file holds them only when some
#: sample is filtered).
RAW_POINT_ARRAYS = ("raw_positions", "raw_recon", "raw_sigma")

#: Arrays a project file may lack (written by an older carapost): read as blank.
OPTIONAL_POINT_ARRAYS = ("sigma",) + RAW_POINT_ARRAYS

#: Fill value of each array the algorithms produce (all but ``keyframe``, ``sigma`` and
#: the raw values).
POINT_FILLS: dict[str, Any] = {k: fill for k, (_, fill) in POINT_ARRAYS.items()
                               if k not in ("keyframe", "sigma") + RAW_POINT_ARRAYS}



def blank_point_array(name: str, n_frames: int, n_points: int,
                      n_cameras: int) -> NDArray[Any]:
    """One per-point array of :data:`POINT_ARRAYS` holding no sample (its fill value).

    Parameters
    ----------
    name : str
        A key of :data:`POINT_ARRAYS`.
    n_frames, n_points, n_cameras : int

    Returns
    -------
    ndarray
        Shape (F, P, 3) for positions, (F, P) for recon, residual and sigma, (F, P, C, 2) for
        obs and (F, P, C) for the others; the storage dtype.

    Examples
    --------
    >>> blank_point_array("obs", 2, 3, 4).shape
    (2, 3, 4, 2)
    """
    dt, fill = POINT_ARRAYS[name]
    trailing = {"positions": (3,), "recon": (), "residual": (), "sigma": (),
                "obs": (n_cameras, 2), "raw_positions": (3,), "raw_recon": (),
                "raw_sigma": ()}.get(name, (n_cameras,))
    return np.full((n_frames, n_points) + trailing, fill, dtype=dt)

class PointArrays(NamedTuple):
    """Point samples an algorithm computed, in the model's layout and storage dtypes.

    Tracking (:func:`carapost.algorithms.tracking.track`, ``track_take``) fills a run
    of frames: the arrays have a leading frame axis ``n = last - first + 1``. Initialize
    From ROM (:func:`carapost.algorithms.rom.initialize_from_rom`) fills one frame: the
    arrays have no frame axis (shapes below without ``n``).

    Attributes
    ----------
    positions : ndarray, shape (n, P, 3) float32
        3D positions (mm); NaN where none.
    recon : ndarray, shape (n, P) int8
        ``RECON_*``.
    residual : ndarray, shape (n, P) float32
        RMS distance of the point to its rays (mm).
    obs : ndarray, shape (n, P, C, 2) float32
        Raw pixel observations; NaN where none.
    source : ndarray, shape (n, P, C) int8
        ``SOURCE_*``.
    detection : ndarray, shape (n, P, C) int32
        Index of the attached detection in its image, -1 if none.
    quality : ndarray, shape (n, P, C) float16
        Match quality 0-1.
    R : ndarray, shape (n, C, 3, 3)
    t : ndarray, shape (n, C, 3)
        Cameras of each frame (world -> camera, mm).
    first, last : int
        Tracking: inclusive frame range the arrays cover (the start frame is not
        included); when nothing was tracked ``last < first``. 0 for one frame.
    frames_done : int
        Tracking: frames tracked (fewer than asked only when cancelled).
    cancelled : bool
    n_new : int
        Tracking: points found during tracking, appended after the initial ones.
    structure : ndarray, shape (P, 3), optional
        Initialize From ROM: the ROM positions (the brim model for brim points).
    sigma : ndarray, shape (n, P) float32, optional
        Estimated standard deviation (mm) of each sample's 3D error (NaN where unknown);
        None when the algorithm does not estimate it.
    """

    positions: NDArray[np.float32]
    recon: NDArray[np.int8]
    residual: NDArray[np.float32]
    obs: NDArray[np.float32]
    source: NDArray[np.int8]
    detection: NDArray[np.int32]
    quality: NDArray[np.float16]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    first: int = 0
    last: int = 0
    frames_done: int = 1
    cancelled: bool = False
    n_new: int = 0
    structure: NDArray[np.float64] | None = None
    sigma: NDArray[np.float32] | None = None
