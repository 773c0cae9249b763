"""Camera pose from known 3D points: PnP candidates and Gauss-Newton refinement.

Cameras are ``x_cam = R X + t`` (world -> camera, mm). Errors are measured in
normalised image coordinates scaled by the focal length, i.e. in pinhole pixels (within
a fraction of a percent of raw pixels for the mild radial distortion of head-mounted
cameras). Used by the brim solve (:mod:`carapost.algorithms.brim`) and by tracking,
which re-solves the cameras of every frame from the brim points.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import cross_matrix, rodrigues_to_matrix

__all__ = ["PNP_METHODS", "PoseRefinement", "pnp_candidates", "refine_poses"]


class PoseRefinement(NamedTuple):
    """Result of :func:`refine_poses`.

    Attributes
    ----------
    R : ndarray, shape (C, 3, 3)
        Refined world -> camera rotations (the starting pose where not ``solved``).
    t : ndarray, shape (C, 3)
        Refined translations (mm).
    rms_px : ndarray, shape (C,)
        RMS reprojection error (pinhole px) of the observed points; NaN where not
        ``solved``.
    solved : ndarray of bool, shape (C,)
        Cameras with at least ``min_points`` observations, which were refined.
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    rms_px: NDArray[np.float64]
    solved: NDArray[np.bool_]


def refine_poses(
    X: ArrayLike,
    xn: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    *,
    scale: ArrayLike | None = None,
    iterations: int = 8,
    huber_px: float | None = 2.0,
    min_points: int = 3,
    linearise: Literal["rotated", "camera"] = "rotated",
) -> PoseRefinement:
    """Refine camera poses against fixed 3D points (Gauss-Newton, all cameras at once).

    Each step updates a camera as ``R <- exp([w]x) R``, ``t <- exp([w]x) t + tau``.

    Parameters
    ----------
    X : array_like, shape (B, 3) or (C, B, 3)
        Known 3D points (mm), shared by all cameras or per camera (``"rotated"`` only).
    xn : array_like, shape (C, B, 2)
        Observed normalised image coordinates; NaN where a camera does not see a point.
    R : array_like, shape (C, 3, 3)
        Initial world->camera rotations.
    t : array_like, shape (C, 3)
        Initial translations (mm).
    scale : array_like, shape (C,), optional
        Pixels per normalised unit (the focal length) used to express errors in pixels
        (default 1; required for ``"camera"``).
    iterations : int
        Most Gauss-Newton steps (both schemes stop early when every update is tiny).
    huber_px : float or None
        Observations further than this (px) from their projection are down-weighted
        (Huber), so a single wrong match cannot drag a pose (``"rotated"``; a huge value
        turns it off). ``"camera"`` is unweighted and needs None.
    min_points : int
        Cameras with fewer observations keep their starting pose (``solved`` False).
    linearise : {"rotated", "camera"}
        The two refinement schemes carapost uses, kept apart because their results
        differ in the last bits and every stored result depends on them:

        ``"rotated"`` (the brim solve)
            The rotation increment is linearised about the rotated points ``R X`` (the
            translation part of the update is left out of the Jacobian), Huber weights,
            stops when the rotation and translation increments are below 1e-10 and 1e-8.
        ``"camera"`` (tracking's per-frame resection, ~1 ms for 4 cameras)
            The exact Jacobian of the update, about the camera-frame points
            ``R X + t``, unweighted; only the ``solved`` cameras are stepped; stops when
            every increment is below 1e-9.

    Returns
    -------
    PoseRefinement
        ``(R, t, rms_px, solved)``.

    Examples
    --------
    >>> from carapost.algorithms.camera import rodrigues_to_matrix
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform(-50, 50, (10, 3)) + [0.0, 0.0, 300.0]
    >>> R_true, t_true = rodrigues_to_matrix([[0.05, -0.02, 0.01]]), np.array([[2.0, 1, 5]])
    >>> p = X @ R_true[0].T + t_true[0]
    >>> xn = (p[:, :2] / p[:, 2:])[None]  # (C=1, B, 2)
    >>> for how in ("rotated", "camera"):
    ...     out = refine_poses(X, xn, np.eye(3)[None], np.zeros((1, 3)), scale=[1000.0],
    ...                        huber_px=None if how == "camera" else 2.0, linearise=how)
    ...     print(how, bool(np.allclose(out.R, R_true)), bool(out.rms_px[0] < 1e-6))
    rotated True True
    camera True True
    """
    if linearise == "rotated":
        if huber_px is None:
            raise ValueError('refine_poses(linearise="rotated") needs a huber_px')
        return _refine_rotated(X, xn, R, t, scale, int(iterations), float(huber_px),
                               int(min_points))
    if linearise == "camera":
        if huber_px is not None:
            raise ValueError('refine_poses(linearise="camera") is unweighted: pass '
                             'huber_px=None')
        if scale is None:
            raise ValueError('refine_poses(linearise="camera") needs scale (the focal '
                             'lengths)')
        return _refine_camera(X, xn, R, t, scale, int(iterations), int(min_points))
    raise ValueError(f'linearise must be "rotated" or "camera", got {linearise!r}')


def _refine_rotated(X: ArrayLike, xn: ArrayLike, R: ArrayLike, t: ArrayLike,
                    scale: ArrayLike | None, iterations: int, huber_px: float,
                    min_points: int) -> PoseRefinement:
    """The brim solve's scheme (see :func:`refine_poses`)."""
    xn = np.asarray(xn, dtype=np.float64)
    C, B = xn.shape[:2]
    X = np.broadcast_to(np.asarray(X, dtype=np.float64), (C, B, 3))
    R = np.array(R, dtype=np.float64).reshape(C, 3, 3)
    t = np.array(t, dtype=np.float64).reshape(C, 3)
    f = np.ones(C) if scale is None else np.asarray(scale, dtype=np.float64).reshape(C)
    valid = np.isfinite(xn).all(-1)
    ok = valid.sum(1) >= min_points
    obs = np.where(valid[..., None], xn, 0.0)
    w_valid = valid.astype(np.float64)

    def residuals(Rc: NDArray, tc: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        p = np.einsum("cij,cbj->cbi", Rc, X) + tc[:, None, :]
        z = np.where(np.abs(p[..., 2]) > 1e-9, p[..., 2], 1e-9)
        proj = p[..., :2] / z[..., None]
        r = (proj - obs) * f[:, None, None]
        return r, p, z

    for _ in range(int(iterations)):
        r, p, z = residuals(R, t)
        e = np.linalg.norm(r, axis=-1)
        w = w_valid * np.where(e > huber_px, huber_px / np.maximum(e, 1e-12), 1.0)
        # d proj / d p  (C, B, 2, 3)
        Jp = np.zeros((C, B, 2, 3))
        Jp[..., 0, 0] = 1.0 / z
        Jp[..., 1, 1] = 1.0 / z
        Jp[..., 0, 2] = -p[..., 0] / z**2
        Jp[..., 1, 2] = -p[..., 1] / z**2
        Jp *= f[:, None, None, None]
        # p = exp(w) R X + t: dp/dw = -[R X]x, dp/dt = I
        RX = p - t[:, None, :]
        J = np.concatenate([-Jp @ cross_matrix(RX), Jp], axis=-1)  # (C, B, 2, 6)
        JtJ = np.einsum("cbki,cb,cbkj->cij", J, w, J)
        Jtr = np.einsum("cbki,cb,cbk->ci", J, w, r)
        JtJ[~ok] = np.eye(6)
        Jtr[~ok] = 0.0
        JtJ += 1e-9 * np.eye(6)
        delta = -np.linalg.solve(JtJ, Jtr[..., None])[..., 0]
        dR = rodrigues_to_matrix(delta[:, :3])
        R = dR @ R
        t = np.einsum("cij,cj->ci", dR, t) + delta[:, 3:]
        if np.all(np.abs(delta[:, :3]) < 1e-10) and np.all(np.abs(delta[:, 3:]) < 1e-8):
            break
    r, _, _ = residuals(R, t)
    sq = np.where(valid, (r**2).sum(-1), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq.sum(1) / valid.sum(1))
    rms[~ok] = np.nan
    return PoseRefinement(R, t, rms, ok)


def _refine_camera(X: ArrayLike, xn: ArrayLike, R: ArrayLike, t: ArrayLike,
                   scale: ArrayLike, iterations: int, min_points: int) -> PoseRefinement:
    """Tracking's per-frame resection scheme (see :func:`refine_poses`)."""
    X = np.asarray(X, np.float64)
    R = np.array(R, np.float64)
    t = np.array(t, np.float64)
    # the kernel's own (B, C, 2) layout, C-contiguous as it always was: the sums below
    # must see the same memory order to give the same bits
    xn = np.ascontiguousarray(np.swapaxes(np.asarray(xn, np.float64), 0, 1))  # (B, C, 2)
    m = np.isfinite(xn).all(-1) & np.isfinite(X).all(-1)[:, None]
    solved = m.sum(0) >= min_points
    if not solved.any():
        return PoseRefinement(R, t, np.full(len(R), np.nan), solved)
    xn = np.where(m[..., None], xn, 0.0)
    X0 = np.nan_to_num(X)
    f = np.asarray(scale, np.float64).reshape(-1)[None, :, None]
    for _ in range(iterations):
        xc = np.einsum("cij,bj->bci", R, X0) + t[None]  # (B, C, 3)
        z = xc[..., 2]
        z = np.where(np.abs(z) > 1e-9, z, 1e-9)
        r = (xc[..., :2] / z[..., None] - xn) * f  # px-ish residual (B, C, 2)
        r = np.where(m[..., None], r, 0.0)
        # d(x/z, y/z)/d(xc) (B, C, 2, 3) times d(xc)/d(omega, tau) = [-[xc]x | I]
        Jp = np.zeros(xc.shape[:2] + (2, 3))
        Jp[..., 0, 0] = 1.0 / z
        Jp[..., 1, 1] = 1.0 / z
        Jp[..., 0, 2] = -xc[..., 0] / z**2
        Jp[..., 1, 2] = -xc[..., 1] / z**2
        Jp *= f[..., None]
        sk = np.zeros(xc.shape[:2] + (3, 3))
        sk[..., 0, 1], sk[..., 0, 2] = xc[..., 2], -xc[..., 1]
        sk[..., 1, 0], sk[..., 1, 2] = -xc[..., 2], xc[..., 0]
        sk[..., 2, 0], sk[..., 2, 1] = xc[..., 1], -xc[..., 0]
        J = np.concatenate([Jp @ sk, Jp], axis=-1)  # -[xc]x == sk as built
        J = np.where(m[..., None, None], J, 0.0)
        H = np.einsum("bcki,bckj->cij", J, J) + 1e-9 * np.eye(6)
        g = np.einsum("bcki,bck->ci", J, r)
        delta = -np.linalg.solve(H[solved], g[solved][..., None])[..., 0]
        dR = rodrigues_to_matrix(delta[:, :3])
        R[solved] = dR @ R[solved]
        t[solved] = np.einsum("cij,cj->ci", dR, t[solved]) + delta[:, 3:]
        if np.abs(delta).max() < 1e-9:
            break
    xc = np.einsum("cij,bj->bci", R, X0) + t[None]
    z = np.where(np.abs(xc[..., 2]) > 1e-9, xc[..., 2], 1e-9)
    sq = np.where(m, (((xc[..., :2] / z[..., None] - xn) * f) ** 2).sum(-1), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(sq.sum(0) / m.sum(0))
    rms[~solved] = np.nan
    return PoseRefinement(R, t, rms, solved)


#: OpenCV PnP solvers tried by :func:`pnp_candidates`, in order.
PNP_METHODS = ("SOLVEPNP_SQPNP", "SOLVEPNP_EPNP", "SOLVEPNP_AP3P", "SOLVEPNP_IPPE",
               "SOLVEPNP_ITERATIVE")


def pnp_candidates(obj: NDArray, img_n: NDArray) -> list[tuple[NDArray, NDArray]]:
    """Pose candidates from every OpenCV PnP solver that applies, on normalised points.

    4-point PnP is ambiguous, so all solutions of all solvers are returned for the
    caller to score (the brim solve refines each and keeps the one explaining most of
    the brim).

    Parameters
    ----------
    obj : ndarray, shape (N, 3)
        Known 3D points (mm), N >= 4.
    img_n : ndarray, shape (N, 2)
        Their normalised image coordinates in one camera.

    Returns
    -------
    list of (R (3, 3), t (3,))
        Finite candidate poses, in the order of :data:`PNP_METHODS`.

    Examples
    --------
    >>> obj = np.array([[0.0, 0, 0], [40, 0, 0], [0, 40, 0], [40, 40, 5], [20, 10, 10],
    ...                 [5, 30, -5]])
    >>> p = obj + [-20.0, -20.0, 300.0]  # camera 300 mm in front, no rotation
    >>> cands = pnp_candidates(obj, p[:, :2] / p[:, 2:])
    >>> any(np.allclose(t, [-20.0, -20.0, 300.0], atol=1e-6) for _, t in cands)
    True
    """
    K = np.eye(3)
    out = []
    o = np.ascontiguousarray(obj, dtype=np.float64).reshape(-1, 1, 3)
    i = np.ascontiguousarray(img_n, dtype=np.float64).reshape(-1, 1, 2)
    for name in PNP_METHODS:
        flag = getattr(cv2, name, None)
        if flag is None:
            continue
        if name == "SOLVEPNP_AP3P" and len(obj) != 4:
            continue
        if name == "SOLVEPNP_ITERATIVE" and len(obj) < 6:
            continue
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(o, i, K, None, flags=flag)
        except cv2.error:
            continue
        for k in range(int(n)):
            rv = np.asarray(rvecs[k], dtype=np.float64).reshape(3)
            tv = np.asarray(tvecs[k], dtype=np.float64).reshape(3)
            if np.all(np.isfinite(rv)) and np.all(np.isfinite(tv)):
                out.append((rodrigues_to_matrix(rv), tv))
    return out
