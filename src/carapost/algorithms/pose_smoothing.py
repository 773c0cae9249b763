"""Per-frame camera poses smoothed over a short window of frames.

Tracking resects every camera in every frame from the brim dots alone; the frame-to-frame
part of that error is white (sensor noise on each frame's brim dots) while real rig flex
is smooth, so :func:`smooth_camera_poses` fits every camera's pose by a local quadratic
(:func:`savgol_quadratic`). `carapost.algorithms.uncertainty` re-solves the points with
the smoothed cameras and re-exports these names.

Units: mm, radians. Shapes: ``F`` frames, ``C`` cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["POSE_SMOOTHING_FRAMES", "savgol_quadratic", "smooth_camera_poses",
           "smoothing_variance_factor"]

#: Window (frames) of the pose fit. On rendered takes with rig flex up to 2.5 Hz at
#: 60 fps, 9-11 frames removed most of the per-frame resection noise (camera tilt error
#: 0.033 -> 0.020 deg RMS) and 15+ frames began to lag the flex (docs/benchmarks.md).
POSE_SMOOTHING_FRAMES = 11

def _rotvec(Rm: NDArray[np.float64]) -> NDArray[np.float64]:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(Rm.reshape(-1, 3, 3)).as_rotvec().reshape(Rm.shape[:-2] + (3,))


def _matrix(rv: NDArray[np.float64]) -> NDArray[np.float64]:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rv.reshape(-1, 3)).as_matrix().reshape(rv.shape[:-1] + (3, 3))


def savgol_quadratic(x: ArrayLike, window: int) -> NDArray[np.float64]:
    """Savitzky-Golay filter of order 2 along the first axis, a quadratic fitted to the
    first and last ``window`` samples at the ends.

    The values of :func:`scipy.signal.savgol_filter` ``(x, window, 2, axis=0,
    mode="interp")`` (to ~1e-14 relative: the same least-squares fit, computed once):
    importing `scipy.signal` (which imports `scipy.stats`, `scipy.fft` and
    `scipy.integrate`) cost every process that smooths poses ~0.3-0.5 s of CPU, a
    batch's start-up included (docs/benchmarks.md).

    Parameters
    ----------
    x : array_like, shape (F, ...)
        Samples along the first axis.
    window : int
        Odd number of samples of each fit, ``3 <= window <= F``.

    Returns
    -------
    ndarray, shape (F, ...)

    Examples
    --------
    >>> import numpy as np
    >>> f = np.arange(7.0)
    >>> bool(np.allclose(savgol_quadratic(3 * f ** 2 - f + 2, 5), 3 * f ** 2 - f + 2))
    True
    """
    from scipy.ndimage import correlate1d

    xs = np.asarray(x, dtype=np.float64)
    F, w = xs.shape[0], int(window)
    if w < 3 or w % 2 == 0 or w > F:
        raise ValueError(f"window must be odd, at least 3 and at most {F}, got {window}")
    half = w // 2
    V = np.vander(np.arange(-half, half + 1, dtype=np.float64), 3, increasing=True)
    fit = np.linalg.pinv(V)  # (3, w): the quadratic's coefficients from w samples
    out = correlate1d(xs, fit[0], axis=0, mode="constant")  # its value at the centre
    # the ends: the quadratic of the first / last w samples at their positions
    out[:half] = np.tensordot(V[:half] @ fit, xs[:w], axes=1)
    out[F - half:] = np.tensordot(V[half + 1:] @ fit, xs[F - w:], axes=1)
    return out


def smoothing_variance_factor(window: int, frames: int) -> float:
    """What :func:`smooth_camera_poses` leaves of white per-frame pose noise (variance).

    A least-squares fit's hat matrix is idempotent, so the variance of the fitted value
    at the window's centre is its own weight ``h_00``: for a quadratic over ``2m + 1``
    frames ``3 (3m^2 + 3m - 1) / ((2m + 3)(2m + 1)(2m - 1))`` (0.21 for 11 frames). The
    window is shortened as :func:`smooth_camera_poses` shortens it; 1 where it smooths
    nothing. (The ends of the take, fitted off-centre, keep somewhat more.)

    Parameters
    ----------
    window : int
        Frames of the fit.
    frames : int
        Frames of the take.

    Returns
    -------
    float

    Examples
    --------
    >>> round(smoothing_variance_factor(11, 600), 4), smoothing_variance_factor(3, 600)
    (0.2075, 1.0)
    """
    F = int(frames)
    w = min(int(window), F if F % 2 else F - 1)
    if w < 5:
        return 1.0
    w += 1 - w % 2
    m = (w - 1) // 2
    return 3.0 * (3 * m * m + 3 * m - 1) / ((2 * m + 3) * (2 * m + 1) * (2 * m - 1))


def smooth_camera_poses(R: ArrayLike, t: ArrayLike, window: int = POSE_SMOOTHING_FRAMES,
                        keep: ArrayLike | None = None
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fit every camera's per-frame pose by a local quadratic over ``window`` frames.

    A Savitzky-Golay filter (`savgol_quadratic`: order 2, polynomial fit at the ends)
    on each camera's rotation (as a rotation vector relative to its middle frame's) and
    centre. A quadratic follows smooth flex without lag; what it removes
    is the frame-to-frame scatter of independent resections.

    Parameters
    ----------
    R : array_like, shape (F, C, 3, 3)
        World->camera rotations per frame.
    t : array_like, shape (F, C, 3)
        Translations (mm).
    window : int
        Frames of the fit (odd; shortened on short takes). Below 5 nothing changes.
    keep : array_like of bool, shape (F,), optional
        Frames whose poses stay as they are (an initialised frame).

    Returns
    -------
    R, t : ndarray
        Smoothed poses, same shapes.

    Examples
    --------
    >>> import numpy as np
    >>> R = np.tile(np.eye(3), (30, 2, 1, 1)); t = np.zeros((30, 2, 3))
    >>> t[:, :, 2] = 150 + np.random.default_rng(0).normal(0, 0.1, (30, 2))
    >>> Rs, ts = smooth_camera_poses(R, t)
    >>> bool(np.std(ts[..., 2]) < np.std(t[..., 2]))
    True
    """
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    F = Rm.shape[0]
    w = min(int(window), F if F % 2 else F - 1)
    if w < 5:
        return Rm.copy(), tm.copy()
    w += 1 - w % 2
    ref = Rm[F // 2]  # (C, 3, 3)
    rv = _rotvec(np.einsum("fcij,ckj->fcik", Rm, ref))  # R_f = exp(rv) ref
    centre = -np.einsum("fcji,fcj->fci", Rm, tm)
    rv_s = savgol_quadratic(rv, w)
    cen_s = savgol_quadratic(centre, w)
    Rs = np.einsum("fcij,cjk->fcik", _matrix(rv_s), ref)
    ts = -np.einsum("fcij,fcj->fci", Rs, cen_s)
    if keep is not None:
        k = np.asarray(keep, dtype=bool)
        Rs[k], ts[k] = Rm[k], tm[k]
    return Rs, ts
