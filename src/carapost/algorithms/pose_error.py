"""The cameras' pose error from the brim: its covariance per frame, and what it does to a
triangulated point.

Every camera is resected from the brim dots it sees in every frame
(:func:`carapost.algorithms.tracking.resect_cameras`), so its pose error is that of a
resection from those dots' centroid errors (:func:`brim_pose_covariance`). How that error
reaches a face sample depends on whether the cameras share it: a rig-wide error (the
brim dots' offsets when a tilted dot's centroid is taken for its centre, constant over
the take and alike in the cameras of a caddy) moves every point rigidly
(:func:`pose_shift_variance`); the cameras' own white centroid noise, once those offsets
are removed (:mod:`carapost.algorithms.brim_discs`), is independent per camera and acts
as extra 2D noise of each observation (:func:`pose_noise_variance`).
`carapost.algorithms.uncertainty.sample_sigma` adds either to a sample's variance.

Units: mm and radians in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``N`` brim dots,
``C`` cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics, project

__all__ = ["brim_pose_covariance", "pose_noise_variance", "pose_shift_variance"]

def pose_noise_variance(Xc: NDArray[np.float64], ok: NDArray[np.bool_], R: NDArray[np.float64],
                         frame: NDArray[np.intp], pc: NDArray[np.float64],
                         focal: NDArray[np.float64]) -> NDArray[np.float64]:
    """Trace of the point's covariance from independent pose errors of its cameras
    (mm^2): each camera's pose error moves the point's image in that camera by
    ``D_c dp`` (``D_c`` 2x6, px per pose parameter), an extra 2D noise of covariance
    ``E_c = D_c Cov_c D_c^T`` that the triangulation (every ray alike) carries into 3D
    as the sandwich ``A^-1 (sum_c f_c^2 J_c^T E_c J_c) A^-1``, ``A = sum_c f_c^2 J_c^T
    J_c``. Unlike a shared shift it averages over cameras across the rays and grows
    along a short baseline's depth. Arguments as `pose_shift_variance`, ``focal``
    (C,) px."""
    N, C, _ = Xc.shape
    use = ok & np.isfinite(pc[frame]).all((-1, -2))
    z = np.where(use, Xc[..., 2], 1.0)
    x, y = Xc[..., 0] / z, Xc[..., 1] / z
    Jn = np.zeros((N, C, 2, 3))  # d(normalised)/d(camera coordinates)
    Jn[..., 0, 0] = Jn[..., 1, 1] = 1.0 / z
    Jn[..., 0, 2], Jn[..., 1, 2] = -x / z, -y / z
    f = np.asarray(focal, np.float64)[None, :, None, None]
    Jw = f * np.einsum("ncak,nckj->ncaj", Jn, R[frame])  # px per mm of the world point
    M = np.zeros((N, C, 3, 6))  # camera-coordinate motion of the point per pose parameter
    M[..., 0, 1], M[..., 0, 2] = Xc[..., 2], -Xc[..., 1]
    M[..., 1, 0], M[..., 1, 2] = -Xc[..., 2], Xc[..., 0]
    M[..., 2, 0], M[..., 2, 1] = Xc[..., 1], -Xc[..., 0]
    M[..., 3:] = np.eye(3)
    D = f * (Jn @ M)  # (N, C, 2, 6)
    E = D @ np.nan_to_num(pc[frame]) @ np.swapaxes(D, -1, -2)  # (N, C, 2, 2) px^2
    w = use[..., None, None]
    A = np.einsum("ncai,ncaj->nij", np.where(w, Jw, 0.0), np.where(w, Jw, 0.0))
    Bm = np.einsum("ncai,ncab,ncbj->nij", np.where(w, Jw, 0.0), np.where(w, E, 0.0),
                   np.where(w, Jw, 0.0))
    out = np.zeros(N)
    good = (use.sum(-1) >= 2) & (np.linalg.det(A) > 1e-12 * np.einsum("nii->n", A) ** 3)
    if good.any():
        Ai = np.linalg.inv(A[good])
        out[good] = np.einsum("nii->n", Ai @ Bm[good] @ Ai)
    return out


def pose_shift_variance(Xc: NDArray[np.float64], ok: NDArray[np.bool_], R: NDArray[np.float64],
                         frame: NDArray[np.intp], pc: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
    """Trace of the point's shift covariance from its cameras' pose errors (mm^2), the
    mean over the cameras that see it. ``Xc`` (N, C, 3) camera coordinates, ``ok``
    (N, C), ``frame`` (N,) the block frame of each sample, ``pc`` (F, C, 6, 6)."""
    N, C, _ = Xc.shape
    # displacement of a point fixed to camera c per pose parameter (omega, delta), in c
    M = np.zeros((N, C, 3, 6))
    M[..., 0, 1], M[..., 0, 2] = Xc[..., 2], -Xc[..., 1]
    M[..., 1, 0], M[..., 1, 2] = -Xc[..., 2], Xc[..., 0]
    M[..., 2, 0], M[..., 2, 1] = Xc[..., 1], -Xc[..., 0]
    M[..., 3:] = np.eye(3)
    # the rotation to world keeps the trace, so it is left out
    cov = np.nan_to_num(pc[frame])  # (N, C, 6, 6)
    tr = np.einsum("ncik,nckl,ncil->nc", M, cov, M)
    use = ok & np.isfinite(pc[frame]).all((-1, -2))
    n = use.sum(-1)
    return np.where(n > 0, np.where(use, tr, 0.0).sum(-1) / np.maximum(n, 1), 0.0)


def brim_pose_covariance(brim_xyz: ArrayLike, brim_obs: ArrayLike, R: ArrayLike,
                         t: ArrayLike, intr: CameraIntrinsics, min_dots: int = 4,
                         white_factor: ArrayLike | None = None
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Covariance of every camera's pose resected from its brim dots, per frame.

    Each camera's pose is solved from the brim dots it sees, so its uncertainty is that
    of a resection: ``s_b^2 (G^T G)^-1`` with ``G`` (2N x 6) the Jacobian of the dots'
    pixels with respect to a small rotation and translation of the camera, and ``s_b``
    the camera's brim reprojection residual (RMS per axis over the take, ``2N - 6``
    degrees of freedom per frame). The residual is measured on the poses given (fitted
    over time or not); the fit over time removes white scatter but not the part of the
    dots' centroid error that stays the same from frame to frame, so no reduction is
    assumed (on rendered takes the error of the fitted poses at the face matched this
    single-frame figure; docs/algorithms.md).

    With ``white_factor`` (what the fit over time leaves of white pose noise, per frame:
    `carapost.algorithms.pose_smoothing.smoothing_variance_factor`) the residual is
    split into the part each dot keeps in every frame (its mean residual over the take,
    per camera: ``s_sys``) and the white rest (``s_w``); the covariance is then
    ``(s_w^2 white_factor + s_sys^2) (G^T G)^-1``: once the dots' known offsets are
    removed (:mod:`carapost.algorithms.brim_discs`), most of the residual is white.

    Parameters
    ----------
    brim_xyz : array_like, shape (F, N, 3)
        The brim dots (mm, world), NaN where unknown.
    brim_obs : array_like, shape (F, N, C, 2)
        Their observations (raw pixels), NaN where none.
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    min_dots : int
        Fewer dots seen by a camera in a frame leave its covariance NaN there.
    white_factor : array_like, shape (F,), optional
        Variance factor of the white part of the residual (1: none removed).

    Returns
    -------
    cov : ndarray, shape (F, C, 6, 6)
        Rotation (rad) then translation (mm), in camera coordinates.
    residual_px : ndarray, shape (C,)
        ``s_b`` of each camera (NaN without brim observations).

    Examples
    --------
    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics, project
    >>> intr = CameraIntrinsics(focal=np.array([800.0]), principal_point=np.array([[640.0, 360.0]]))
    >>> g = np.stack(np.meshgrid(np.linspace(-60, 60, 5), np.linspace(-20, 20, 3)), -1)
    >>> B = np.c_[g.reshape(-1, 2), np.full(15, 120.0)][None].repeat(10, 0)
    >>> R = np.tile(np.eye(3), (10, 1, 1, 1)); t = np.zeros((10, 1, 3))
    >>> uv = project(B, R, t, intr)[0] + np.random.default_rng(0).normal(0, 0.05, (10, 15, 1, 2))
    >>> cov, s_b = brim_pose_covariance(B, uv, R, t, intr)
    >>> bool(0.03 < s_b[0] < 0.08), cov.shape
    (True, (10, 1, 6, 6))
    """
    B = np.asarray(brim_xyz, dtype=np.float64)
    ob = np.asarray(brim_obs, dtype=np.float64)
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    F, N, C, _ = ob.shape
    has = np.isfinite(ob).all(-1) & np.isfinite(B).all(-1)[..., None]  # (F, N, C)
    cov = np.full((F, C, 6, 6), np.nan)
    s_b = np.full(C, np.nan)
    if N == 0 or not has.any():
        return cov, s_b
    Bz = np.nan_to_num(B)
    uv = project(Bz, Rm, tm, intr)[0]  # (F, N, C, 2)
    r2 = np.where(has, np.sum((ob - uv) ** 2, -1), 0.0)
    n = has.sum(1)  # (F, C)
    solved = n >= min_dots
    dof = np.where(solved, 2 * n - 6, 0).sum(0)
    ss = np.where(solved[:, None, :], r2, 0.0).sum((0, 1))
    s_b = np.where(dof > 0, np.sqrt(ss / np.maximum(dof, 1)), np.nan)
    f = np.asarray(intr.focal, dtype=np.float64)[None, None, :]
    info = np.zeros((F, C, 6, 6))
    for a in range(0, F, 256):  # blocks of frames bound the memory of long takes
        b = slice(a, a + 256)
        Xc = np.einsum("fcij,fnj->fnci", Rm[b], Bz[b]) + tm[b][:, None]  # (f, N, C, 3)
        zs = np.where(has[b] & (Xc[..., 2] > 1e-6), Xc[..., 2], 1.0)
        Jp = np.zeros(Xc.shape[:-1] + (2, 3))
        Jp[..., 0, 0] = Jp[..., 1, 1] = f / zs
        Jp[..., 0, 2] = -f * Xc[..., 0] / zs ** 2
        Jp[..., 1, 2] = -f * Xc[..., 1] / zs ** 2
        M = np.zeros(Xc.shape[:-1] + (3, 6))
        M[..., 0, 1], M[..., 0, 2] = Xc[..., 2], -Xc[..., 1]
        M[..., 1, 0], M[..., 1, 2] = -Xc[..., 2], Xc[..., 0]
        M[..., 2, 0], M[..., 2, 1] = Xc[..., 1], -Xc[..., 0]
        M[..., 3:] = np.eye(3)
        G = np.where(has[b][..., None, None], Jp @ M, 0.0)  # (f, N, C, 2, 6)
        info[b] = np.einsum("fncai,fncaj->fcij", G, G)
    good = solved & np.isfinite(s_b)[None, :]
    good[good] = np.linalg.cond(info[good]) < 1e12
    var = np.broadcast_to((s_b ** 2)[None, :], (F, C))
    if white_factor is not None:
        sys2 = _persistent_residual(ob - uv, has & solved[:, None, :], n, s_b)
        wf = np.asarray(white_factor, np.float64).reshape(F, 1)
        var = (s_b ** 2 - sys2)[None, :] * wf + sys2[None, :]
    cov[good] = np.linalg.inv(info[good]) * var[good][:, None, None]
    return cov, s_b


#: Fewest frames in which a dot is seen by a camera for its mean residual to count in
#: `_persistent_residual`.
_PERSISTENT_MIN_FRAMES = 10


def _persistent_residual(res: NDArray[np.float64], use: NDArray[np.bool_],
                         n: NDArray[np.int64], s_b: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
    """(C,) per-axis variance (px^2) of the brim residual that each dot keeps over the
    take: the mean square of the dots' mean residuals, less what the white part leaves
    in a mean of that many frames, scaled like ``s_b`` for the pose's degrees of freedom
    and at most ``s_b^2``. ``res`` (F, N, C, 2), ``use`` (F, N, C), ``n`` (F, C) dots
    per frame."""
    k = use.sum(0)  # (N, C)
    mean = np.where(use[..., None], res, 0.0).sum(0) / np.maximum(k, 1)[..., None]
    enough = k >= _PERSISTENT_MIN_FRAMES
    per_axis = 0.5 * (mean ** 2).sum(-1) - (s_b ** 2)[None, :] / np.maximum(k, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sys2 = np.where(enough, per_axis, 0.0).sum(0) / enough.sum(0)
        nn = np.where(n >= 4, n, np.nan)
        dof = np.nanmean(2.0 * nn / (2.0 * nn - 6.0), axis=0)
    sys2 = np.nan_to_num(sys2 * np.nan_to_num(dof, nan=1.0))
    return np.clip(sys2, 0.0, np.nan_to_num(s_b ** 2))
