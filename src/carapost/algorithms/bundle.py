"""Bundle adjustment: refine cameras (and points, optionally intrinsics) on reprojection error.

Two solvers share one analytic Jacobian, built per observation as dense camera and point
blocks: the default ``solver="schur"`` is Levenberg-Marquardt with the points eliminated
(:func:`carapost.algorithms.lm.lm_schur`); ``solver="least_squares"`` is
:func:`scipy.optimize.least_squares` (trust-region reflective) on the same Jacobian
assembled as a sparse matrix, solved with LSMR. Nothing dense of size observations x
parameters is ever built.

Camera model (ours)
    ``x_cam = R X + t``; raw pixels through the Vicon radial model (see
    :mod:`carapost.algorithms.camera`). The residual of an observation is measured in
    raw pixels to first order: the ideal pinhole residual ``K pi(x_cam) - undistort(uv)``
    mapped through the inverse Jacobian of the radial model at the observation. The
    radial model maps raw to corrected pixels in closed form, so nothing needs iterating.
    Rotations are updated as ``R = exp([w]x) R0`` with the increment ``w`` as the
    parameter, which keeps the rotation vector small and away from its singularity.

Gauge
    Bundle adjustment can move, rotate and scale everything without changing the error.
    When brim points are given they are known structure and stay fixed, which fixes the
    gauge. Without them one camera is held fixed, and after the solve the result is scaled
    about that camera so that the distance between the first two camera centres keeps its
    starting value (a similarity transform leaves every reprojection error unchanged).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    cross_matrix,
    rodrigues_to_matrix,
)
from carapost.algorithms.lm import (
    JacobianStructure,
    jacobian_structure,
    lm_schur,
    sparse_jacobian,
)

#: Options of :func:`bundle_frame` for the brim solve and Initialize 3D: scipy's
#: trust-region solver. On these small, well-conditioned problems it converges to the
#: minimum where the fast Schur solver was seen to stop early (0.09 px instead of
#: 0.035 px on one synthetic frame).
BUNDLE_OPTIONS: dict[str, Any] = {"solver": "least_squares"}

# --------------------------------------------------------------------------------------
# Rotation helpers
# --------------------------------------------------------------------------------------


def left_jacobian(w: ArrayLike) -> NDArray[np.float64]:
    """Left Jacobian of SO(3) at rotation vectors ``w [..., 3]`` -> ``[..., 3, 3]``.

    ``R(w + dw) X = R(w) X - [R(w) X]x J_l(w) dw`` to first order.
    """
    w = np.asarray(w, dtype=np.float64)
    th2 = (w * w).sum(-1)
    th = np.sqrt(th2)
    small = th2 < 1e-8
    ths = np.where(small, 1.0, th)
    # (1 - cos t) / t^2 and (t - sin t) / t^3 with their series near 0.
    a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - np.sin(ths)) / ths**3)
    W = cross_matrix(w)
    return np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)


# --------------------------------------------------------------------------------------
# Our camera model
# --------------------------------------------------------------------------------------


class BundleResult(NamedTuple):
    """Result of :func:`bundle_frame`.

    Attributes
    ----------
    R : ndarray, shape (C, 3, 3)
    t : ndarray, shape (C, 3)
        Refined extrinsics (mm).
    points : ndarray, shape (P, 3)
        Refined points (mm); fixed and unobserved points unchanged.
    rms_before, rms_after : float
        RMS reprojection error over all used observations (px), before and after.
    success : bool
    message : str
    intrinsics : CameraIntrinsics or None
        Refined intrinsics when ``refine_intrinsics`` was set, else None.
    nfev : int
        Residual evaluations.
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    points: NDArray[np.float64]
    rms_before: float
    rms_after: float
    success: bool
    message: str
    intrinsics: CameraIntrinsics | None = None
    nfev: int = 0


@dataclass
class _FrameProblem:
    ci: NDArray[np.intp]  # [No] camera of each observation
    pi: NDArray[np.intp]  # [No] point of each observation
    uc: NDArray[np.float64]  # [No, 2] undistorted (corrected) pixel observations
    jinv: NDArray[np.float64]  # [No, 2, 2] raw <- corrected pixel Jacobian at the observation
    R0: NDArray[np.float64]  # [C, 3, 3]
    t0: NDArray[np.float64]  # [C, 3]
    X0: NDArray[np.float64]  # [P, 3]
    K: NDArray[np.float64]  # [C, 3, 3]
    cam_free: NDArray[np.bool_]  # [C]
    pt_free: NDArray[np.bool_]  # [P]
    intrinsics: bool

    @property
    def n_cam_par(self) -> int:
        return 9 if self.intrinsics else 6

    def split(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Free-parameter vector -> camera increments ``[C, k]`` and points ``[P, 3]``."""
        C = self.R0.shape[0]
        k = self.n_cam_par
        nc = int(self.cam_free.sum())
        cam = np.zeros((C, k))
        cam[self.cam_free] = x[: nc * k].reshape(nc, k)
        X = self.X0.copy()
        X[self.pt_free] = x[nc * k:].reshape(-1, 3)
        return cam, X

    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        return self.state(*self.split(x))

    def state(self, cam: NDArray[np.float64], X: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], ...]:
        """Camera increments and points -> ``(cam, R, t, X, K)``."""
        R = rodrigues_to_matrix(cam[:, :3]) @ self.R0
        t = self.t0 + cam[:, 3:6]
        K = self.K.copy()
        if self.intrinsics:
            a = self.K[:, 0, 0] / self.K[:, 1, 1]
            K[:, 0, 0] += cam[:, 6]
            K[:, 1, 1] = K[:, 0, 0] / a
            K[:, 0, 2] += cam[:, 7]
            K[:, 1, 2] += cam[:, 8]
        return cam, R, t, X, K

    def x0(self) -> NDArray[np.float64]:
        nc = int(self.cam_free.sum())
        return np.concatenate([np.zeros(nc * self.n_cam_par), self.X0[self.pt_free].ravel()])

    def residuals(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.block_residuals(*self.split(x)).ravel()

    def block_residuals(self, cam: NDArray[np.float64], X: NDArray[np.float64]
                        ) -> NDArray[np.float64]:
        _, R, t, X, K = self.state(cam, X)
        P = np.einsum("nij,nj->ni", R[self.ci], X[self.pi]) + t[self.ci]
        return self._pixel_residual(P, K)

    def _pixel_residual(self, P: NDArray[np.float64], K: NDArray[np.float64]
                        ) -> NDArray[np.float64]:
        Kc = K[self.ci]
        with np.errstate(divide="ignore", invalid="ignore"):
            px = P[:, 0] / P[:, 2]
            py = P[:, 1] / P[:, 2]
        u = Kc[:, 0, 0] * px + Kc[:, 0, 1] * py + Kc[:, 0, 2] - self.uc[:, 0]
        v = Kc[:, 1, 1] * py + Kc[:, 1, 2] - self.uc[:, 1]
        return np.einsum("nij,nj->ni", self.jinv, np.stack([u, v], -1))

    def jacobian(self, x: NDArray[np.float64], struct: JacobianStructure) -> sp.csr_matrix:
        return sparse_jacobian(struct, self.dense_blocks(*self.split(x)))

    def blocks(self, cam: NDArray[np.float64], X: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        dense = self.dense_blocks(cam, X)
        k = self.n_cam_par
        return dense[:, :, :k], dense[:, :, k:]

    def dense_blocks(self, cam: NDArray[np.float64], X: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
        """Per-observation Jacobian ``[No, 2, k + 3]`` (camera increments, then point)."""
        cam, R, t, X, K = self.state(cam, X)
        Rc = R[self.ci]
        RX = np.einsum("nij,nj->ni", Rc, X[self.pi])
        P = RX + t[self.ci]
        Kc = K[self.ci]
        iz = 1.0 / P[:, 2]
        px, py = P[:, 0] * iz, P[:, 1] * iz
        No = P.shape[0]
        dpi = np.zeros((No, 2, 3))
        dpi[:, 0, 0] = iz
        dpi[:, 1, 1] = iz
        dpi[:, 0, 2] = -px * iz
        dpi[:, 1, 2] = -py * iz
        A = self.jinv @ Kc[:, :2, :2] @ dpi  # d r / d P, [No, 2, 3]
        k = self.n_cam_par
        dense = np.empty((No, 2, k + 3))
        dense[:, :, 0:3] = -A @ cross_matrix(RX) @ left_jacobian(cam[self.ci, :3])
        dense[:, :, 3:6] = A
        if self.intrinsics:
            a = Kc[:, 0, 0] / Kc[:, 1, 1]
            dense[:, :, 6] = np.einsum("nij,nj->ni", self.jinv, np.stack([px, py / a], -1))
            dense[:, :, 7] = self.jinv[:, :, 0]
            dense[:, :, 8] = self.jinv[:, :, 1]
        dense[:, :, k:] = A @ Rc
        return dense


def _undistort_with_jacobian(uv: NDArray[np.float64], cam: NDArray[np.intp],
                             intr: CameraIntrinsics
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Corrected pixels ``[N, 2]`` of raw ``uv [N, 2]`` and the raw <- corrected Jacobian."""
    cd = intr.distortion_centre[cam]
    a2 = intr.aspect[cam] ** 2
    k1, k2, k3 = intr.radial[cam].T
    e = uv - cd
    r2 = e[:, 0] ** 2 + a2 * e[:, 1] ** 2
    s = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ds = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    g = np.stack([e[:, 0], a2 * e[:, 1]], -1)
    J = s[:, None, None] * np.eye(2) + 2 * ds[:, None, None] * e[:, :, None] * g[:, None, :]
    return cd + s[:, None] * e, np.linalg.inv(J)


def _rms(r: NDArray[np.float64]) -> float:
    r = r.reshape(-1, 2)
    return float(np.sqrt((r**2).sum(-1).mean())) if r.size else float("nan")


def bundle_frame(
    observations: ArrayLike,
    points: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    *,
    fixed_points_mask: ArrayLike | None = None,
    fixed_cameras: ArrayLike | None = None,
    refine_points: bool = True,
    refine_intrinsics: bool = False,
    loss: str = "huber",
    f_scale: float = 1.0,
    max_nfev: int | None = 50,
    ftol: float = 1e-8,
    solver: str = "schur",
) -> BundleResult:
    """Bundle Current Frame [Unconstrained]: refine one frame's cameras and points.

    Parameters
    ----------
    observations : array_like, shape (P, C, 2)
        Raw pixel observations, NaN where missing.
    points : array_like, shape (P, 3)
        Starting 3D points (mm); NaN points and their observations are ignored.
    R : array_like, shape (C, 3, 3)
    t : array_like, shape (C, 3)
        Starting extrinsics (world->camera, mm).
    intr : CameraIntrinsics
    fixed_points_mask : array_like of bool, shape (P,), optional
        Points of known structure (the brim): kept fixed, which fixes the gauge. Without
        any, the first camera with observations is fixed and the scale is held by the
        distance between the first two camera centres.
    fixed_cameras : array_like of bool, shape (C,), optional
        Cameras to keep fixed in addition.
    refine_points : bool
        Also refine the free points (False: cameras only, a resection).
    refine_intrinsics : bool
        Also refine focal length and principal point per camera (radial terms fixed).
    loss : str
        ``least_squares`` loss (``"linear"``, ``"huber"``, ``"soft_l1"``, ``"cauchy"``...).
    f_scale : float
        Inlier scale of the robust loss (px).
    max_nfev : int or None
        Limit on iterations (Schur solver) or residual evaluations (least_squares).
    ftol : float
        Relative cost tolerance.
    solver : {"schur", "least_squares"}
        ``"schur"``: Levenberg-Marquardt on the analytic Jacobian with the points
        eliminated, robust loss by re-weighting (fast; the default). ``"least_squares"``:
        :func:`scipy.optimize.least_squares` (TRF) with the analytic sparse Jacobian and
        LSMR; ``max_nfev`` then counts residual evaluations, not iterations.

    Returns
    -------
    BundleResult

    Raises
    ------
    ValueError
        On inconsistent shapes (the message names the argument).
    """
    uv = np.asarray(observations, dtype=np.float64)
    X0 = np.asarray(points, dtype=np.float64)
    R0 = np.asarray(R, dtype=np.float64)
    t0 = np.asarray(t, dtype=np.float64)
    if uv.ndim != 3 or uv.shape[-1] != 2:
        raise ValueError(f"observations must have shape (P, C, 2), got {uv.shape}")
    P, C, _ = uv.shape
    if X0.shape != (P, 3):
        raise ValueError(f"points must have shape ({P}, 3), got {X0.shape}")
    if R0.shape != (C, 3, 3) or t0.shape != (C, 3):
        raise ValueError(f"R and t must have shapes ({C}, 3, 3) and ({C}, 3), got "
                         f"{R0.shape} and {t0.shape}")
    if intr.n_cameras != C:
        raise ValueError(f"intr has {intr.n_cameras} cameras but observations have {C}")
    fixed_pts = (np.zeros(P, bool) if fixed_points_mask is None
                 else np.asarray(fixed_points_mask, bool).reshape(-1))
    if fixed_pts.shape != (P,):
        raise ValueError(f"fixed_points_mask must have shape ({P},), got {fixed_pts.shape}")
    fixed_cam = (np.zeros(C, bool) if fixed_cameras is None
                 else np.asarray(fixed_cameras, bool).reshape(-1))
    if fixed_cam.shape != (C,):
        raise ValueError(f"fixed_cameras must have shape ({C},), got {fixed_cam.shape}")

    cam_ok = np.isfinite(R0).all((1, 2)) & np.isfinite(t0).all(1)
    ok = np.isfinite(uv).all(-1) & np.isfinite(X0).all(-1)[:, None] & cam_ok[None, :]
    pi, ci = np.nonzero(ok)
    if pi.size == 0:
        return BundleResult(R0.copy(), t0.copy(), X0.copy(), float("nan"), float("nan"),
                            False, "no usable observations", None, 0)
    uc, jinv = _undistort_with_jacobian(uv[pi, ci], ci, intr)
    observed_cam = np.bincount(ci, minlength=C) > 0
    observed_pt = np.bincount(pi, minlength=P) > 0
    pt_free = observed_pt & ~fixed_pts & refine_points
    cam_free = observed_cam & ~fixed_cam
    gauge_by_camera = not (fixed_pts & observed_pt).any() and not fixed_cam.any()
    anchor = -1
    if gauge_by_camera:
        anchor = int(np.flatnonzero(observed_cam)[0])
        cam_free[anchor] = False

    prob = _FrameProblem(ci, pi, uc, jinv, R0, t0, X0, intr.K(), cam_free, pt_free,
                         refine_intrinsics)
    struct = jacobian_structure(ci, pi, prob.n_cam_par, cam_free, pt_free)
    x0 = prob.x0()
    r0 = prob.residuals(x0)
    rms_before = _rms(r0)
    if x0.size == 0:
        return BundleResult(R0.copy(), t0.copy(), X0.copy(), rms_before, rms_before, True,
                            "nothing to refine", None, 1)
    if solver == "schur":
        cam0 = np.zeros((C, prob.n_cam_par))
        cam, Xs, nfev, _, ok_, msg = lm_schur(
            prob.block_residuals, prob.blocks, cam0, X0.copy(), ci, pi, ftol=ftol,
            max_iter=50 if max_nfev is None else max_nfev, loss=loss, f_scale=f_scale,
            cam_free=cam_free, pt_free=pt_free)
        xs = np.concatenate([cam[cam_free].ravel(), Xs[pt_free].ravel()])
    elif solver == "least_squares":
        sol = least_squares(
            prob.residuals, x0, jac=lambda x: prob.jacobian(x, struct), method="trf",
            loss=loss, f_scale=f_scale, x_scale="jac", tr_solver="lsmr", max_nfev=max_nfev,
            ftol=ftol, xtol=1e-10, gtol=1e-10,
        )
        xs, nfev, ok_, msg = sol.x, sol.nfev, sol.success, sol.message
    else:
        raise ValueError(f"solver must be 'schur' or 'least_squares', got {solver!r}")
    _, Rn, tn, Xn, Kn = prob.unpack(xs)
    if gauge_by_camera:
        Rn, tn, Xn = _restore_scale(Rn, tn, Xn, R0, t0, anchor, observed_cam)
    intr_out = None
    if refine_intrinsics:
        intr_out = intr.copy()
        intr_out.focal = Kn[:, 0, 0].copy()
        intr_out.principal_point = Kn[:, :2, 2].copy()
    rms_after = _rms(prob.residuals(xs))
    return BundleResult(Rn, tn, Xn, rms_before, rms_after, bool(ok_), str(msg), intr_out,
                        int(nfev))


def _restore_scale(R: NDArray[np.float64], t: NDArray[np.float64], X: NDArray[np.float64],
                   R0: NDArray[np.float64], t0: NDArray[np.float64], anchor: int,
                   observed: NDArray[np.bool_]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Scale about the fixed anchor camera so the anchor-to-next baseline keeps its length."""
    others = np.flatnonzero(observed)
    others = others[others != anchor]
    if others.size == 0:
        return R, t, X
    c0 = camera_centres(R0, t0)
    c = camera_centres(R, t)
    j = int(others[0])
    before = np.linalg.norm(c0[j] - c0[anchor])
    after = np.linalg.norm(c[j] - c[anchor])
    if not (after > 0 and np.isfinite(after)):
        return R, t, X
    s = before / after
    origin = c[anchor]
    c_new = origin + s * (c - origin)
    X_new = origin + s * (X - origin)
    t_new = -np.einsum("cij,cj->ci", R, c_new)
    return R, t_new, X_new


class SequenceBundleResult(NamedTuple):
    """Result of :func:`bundle_sequence` (per-frame arrays, NaN where not solved).

    Attributes
    ----------
    R : ndarray, shape (F, C, 3, 3)
    t : ndarray, shape (F, C, 3)
    points : ndarray, shape (F, P, 3)
    rms_before, rms_after : ndarray, shape (F,)
        Per-frame RMS reprojection error (px).
    success : ndarray of bool, shape (F,)
    frames_done : int
        Frames processed (less than F only when cancelled).
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    points: NDArray[np.float64]
    rms_before: NDArray[np.float64]
    rms_after: NDArray[np.float64]
    success: NDArray[np.bool_]
    frames_done: int


def bundle_sequence(
    observations: ArrayLike,
    points: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    *,
    brim_points_mask: ArrayLike | None = None,
    brim_model: ArrayLike | None = None,
    refine_points: bool = True,
    loss: str = "huber",
    f_scale: float = 1.0,
    max_nfev: int | None = 50,
    progress: Callable[[int, int], bool] | None = None,
) -> SequenceBundleResult:
    """Bundle Sequence [Unconstrained]: refine per-frame cameras and points over a take.

    The head rig's cameras are solved per frame and the face points move, so with the
    brim as known structure every frame is an independent problem: frames are solved one
    by one (a sparse problem each, never a dense Jacobian), each frame starting from its
    own cameras, or from the previous frame's refined cameras where its own are missing.

    Parameters
    ----------
    observations : array_like, shape (F, P, C, 2)
        Raw pixel observations, NaN where missing.
    points : array_like, shape (F, P, 3)
        Starting points (mm), NaN where unknown.
    R : array_like, shape (F, C, 3, 3)
    t : array_like, shape (F, C, 3)
        Starting per-frame extrinsics (NaN for unsolved camera-frames).
    intr : CameraIntrinsics
    brim_points_mask : array_like of bool, shape (P,), optional
        Which points are brim points.
    brim_model : array_like, shape (B, 3), optional
        Known brim positions (mm, brim frame) of the ``B = brim_points_mask.sum()`` brim
        points, in point order. They replace the starting brim points and stay fixed.
        Without a model, brim points are refined like the others and the gauge is fixed
        per frame by one camera (see :func:`bundle_frame`).
    refine_points, loss, f_scale, max_nfev
        As for :func:`bundle_frame`.
    progress : callable, optional
        ``progress(frames_done, F)``; False cancels (later frames keep NaN results).

    Returns
    -------
    SequenceBundleResult
    """
    uv = np.asarray(observations, dtype=np.float64)
    X = np.asarray(points, dtype=np.float64)
    Rs = np.asarray(R, dtype=np.float64)
    ts = np.asarray(t, dtype=np.float64)
    if uv.ndim != 4 or uv.shape[-1] != 2:
        raise ValueError(f"observations must have shape (F, P, C, 2), got {uv.shape}")
    F, P, C, _ = uv.shape
    if X.shape != (F, P, 3):
        raise ValueError(f"points must have shape ({F}, {P}, 3), got {X.shape}")
    if Rs.shape != (F, C, 3, 3) or ts.shape != (F, C, 3):
        raise ValueError(f"R and t must have shapes ({F}, {C}, 3, 3) and ({F}, {C}, 3)")
    mask = np.zeros(P, bool) if brim_points_mask is None else np.asarray(brim_points_mask, bool)
    if mask.shape != (P,):
        raise ValueError(f"brim_points_mask must have shape ({P},), got {mask.shape}")
    model = None
    if brim_model is not None:
        model = np.asarray(brim_model, dtype=np.float64)
        if model.shape != (int(mask.sum()), 3):
            raise ValueError(f"brim_model must have shape ({int(mask.sum())}, 3) to match "
                             f"brim_points_mask, got {model.shape}")

    R_out = np.full_like(Rs, np.nan)
    t_out = np.full_like(ts, np.nan)
    X_out = np.full_like(X, np.nan)
    before = np.full(F, np.nan)
    after = np.full(F, np.nan)
    success = np.zeros(F, bool)
    R_prev = t_prev = None
    done = 0
    for f in range(F):
        Rf, tf = Rs[f].copy(), ts[f].copy()
        missing = ~(np.isfinite(Rf).all((1, 2)) & np.isfinite(tf).all(1))
        if missing.any() and R_prev is not None:
            Rf[missing], tf[missing] = R_prev[missing], t_prev[missing]
        Xf = X[f].copy()
        if model is not None:
            Xf[mask] = model
        res = bundle_frame(uv[f], Xf, Rf, tf, intr,
                           fixed_points_mask=mask if model is not None else None,
                           refine_points=refine_points, loss=loss, f_scale=f_scale,
                           max_nfev=max_nfev)
        R_out[f], t_out[f], X_out[f] = res.R, res.t, res.points
        before[f], after[f], success[f] = res.rms_before, res.rms_after, res.success
        if res.success:
            R_prev, t_prev = res.R, res.t
        done = f + 1
        if progress is not None and progress(done, F) is False:
            break
    return SequenceBundleResult(R_out, t_out, X_out, before, after, success, done)
