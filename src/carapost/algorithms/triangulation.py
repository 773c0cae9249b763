"""Multi-view triangulation with reprojection-error outlier rejection, vectorised.

Every point of every frame is triangulated in one call. Observations are raw pixels
``[F, P, C, 2]`` (NaN where a camera has no detection); cameras are either fixed
``[C, 3, 3]`` / ``[C, 3]`` or re-solved per frame ``[F, C, 3, 3]`` / ``[F, C, 3]``
(``x_cam = R X + t``, see :mod:`carapost.algorithms.camera`).

Linear step
    Each observation is undistorted in closed form and turned into a world ray
    (camera centre ``c``, unit direction ``d``). The point is the least-squares
    intersection of the rays: ``sum (I - d d^T) X = sum (I - d d^T) c``, a 3x3 system
    solved in closed form for all point-frames at once. Optional Gauss-Newton steps then
    minimise the reprojection error in pixels.

Reprojection error
    Measured in raw (distorted) pixels to first order: the residual between the
    projection and the observation in ideal pinhole pixels is mapped back through the
    inverse Jacobian of the radial model at the observation, so a target in pixels means
    the same at any focal length and lens (the reference implementation used normalised
    image coordinates instead, whose meaning in pixels scales with the focal length).

Outlier rejection
    Points whose all-camera mean reprojection error exceeds the target are re-triangulated
    from camera subsets, drop level by drop level (1 camera dropped, then 2, ...) up to
    ``maximum_cameras_to_drop`` and never below ``minimum_cameras``; the search stops
    after the first level in which a subset reaches the target. Each accepted subset
    ``i`` gets the weight ``w_i = exp(-5 e_i / e_target)`` and the result is the weighted
    mean of the subset points (the all-camera point is the level-0 candidate). When no
    subset reaches the target, the weighted result and the all-camera result are compared
    by their own mean reprojection errors and the lower one is kept. Unlike the reference
    implementation, a subset is rejected when its point lies behind one of its cameras
    or when its rays meet at less than ``min_ray_angle_deg`` (the largest angle between
    any two of its rays, taken as lines), which are the ways two-camera subsets go wrong.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.params import TRIANGULATION, param, validate

log = logging.getLogger("carapost.triangulation")

#: Sharpness of the subset weight decay, ``w = exp(-WEIGHT_DECAY * e / e_target)``.
WEIGHT_DECAY = 5.0


@dataclass(frozen=True)
class TriangulationParameters:
    """Parameters of :func:`triangulate`.

    Attributes
    ----------
    minimum_cameras : int
        Minimum number of cameras with a valid detection for a point to be triangulated
        (both plain and outlier-rejection paths). Above the camera count it is clamped to
        the camera count with a warning in the log. With 1, points seen by a single camera
        follow ``flatten_single_camera_data``.
    flatten_single_camera_data : bool
        Single-camera points: True puts them where their ray meets the world plane
        ``Z = 0`` (Z data set to 0); False uses the caller's ``single_camera_estimates``
        (NaN when none are given).
    use_outlier_rejection : bool
        Run the reprojection-error subset search (off by default).
    maximum_cameras_to_drop : int
        Largest number of cameras dropped from a point in the subset search.
    target_reprojection_error : float
        Target mean reprojection error ``e_target`` in pixels.
    min_ray_angle_deg : float
        Subsets whose largest angle between two of their rays is below this are rejected.
    refine_iterations : int
        Gauss-Newton steps on the pixel reprojection error after the linear solution.
    """

    minimum_cameras: int = param(
        3, label="Minimum Cameras for Triangulation", section=TRIANGULATION, unit="cameras",
        min=1, max=16,
        help="A 3D point is only reconstructed from at least this many cameras (lowered to "
             "the camera count of the take, with a logged warning).")
    flatten_single_camera_data: bool = param(
        True, label="Flatten Single Camera Data", section=TRIANGULATION,
        help="Put points seen by a single camera where their ray meets the world plane "
             "Z = 0 instead of using a poor single-view depth estimate.")
    use_outlier_rejection: bool = param(
        False, label="Use Outlier Rejection", section=TRIANGULATION,
        help="Re-triangulate points with high reprojection error from camera subsets and "
             "blend them by error (best with more cameras than the minimum).")
    maximum_cameras_to_drop: int = param(
        1, label="Maximum Cameras to Drop", section=TRIANGULATION, unit="cameras",
        min=0, max=14,
        help="Most cameras outlier rejection may leave out of a subset; 0 disables the "
             "search. Range is our choice.")
    target_reprojection_error: float = param(
        2.0, label="Target Reprojection Error", section=TRIANGULATION, unit="px",
        min=0.0, min_exclusive=True, max=1000.0,
        help="Mean reprojection error a subset should reach; subsets are weighted "
             "exp(-5 error / target). Default is our choice (the guide gives none). Range "
             "is our choice.")
    min_ray_angle_deg: float = param(
        2.0, label="Minimum Ray Angle", section=TRIANGULATION, unit="deg",
        min=0.0, max=90.0, max_exclusive=True,
        help="Camera subsets whose rays meet at a smaller angle are too parallel to fix "
             "depth and are not used (our own parameter).")
    refine_iterations: int = param(
        0, label="Refinement Iterations", section=TRIANGULATION, min=0, max=20,
        help="Gauss-Newton steps on the pixel reprojection error after the linear solution "
             "(our own parameter).")

    def __post_init__(self) -> None:
        validate(self)


class Triangulation(NamedTuple):
    """Per point-frame result of :func:`triangulate`.

    Attributes
    ----------
    points : ndarray, shape (F, P, 3)
        World position (mm); NaN where not triangulated.
    reprojection_error : ndarray, shape (F, P)
        Mean reprojection error over the contributing cameras (px); NaN where no point.
    residual : ndarray, shape (F, P)
        RMS distance between the point and the contributing rays (mm); NaN where no point.
    contribution : ndarray, shape (F, P, C), bool
        Cameras whose observation the point is built from.
    n_cameras : ndarray, shape (F, P), int8
        Number of contributing cameras.
    frames_done : int
        Frames processed (less than F only when cancelled through ``progress``).
    """

    points: NDArray[np.float64]
    reprojection_error: NDArray[np.float64]
    residual: NDArray[np.float64]
    contribution: NDArray[np.bool_]
    n_cameras: NDArray[np.int8]
    frames_done: int = -1


# --------------------------------------------------------------------------------------
# Per-observation quantities
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# Per-observation quantities, camera-first "structure of arrays" layout
# --------------------------------------------------------------------------------------
# Every per-observation array has the camera axis first and the point-frames after it
# ([C, Fc, P] in a chunk, [C, M] for gathered point-frames), and vector components on an
# axis before that, so each arithmetic step runs over long contiguous arrays and sums over
# cameras are sums of C arrays. Camera parameters broadcast as [C, Fc or 1, 1] / [C, M].


class _Obs(NamedTuple):
    w: NDArray[np.float64]  # [C, ...] 1 for a valid observation, 0 otherwise
    xn: NDArray[np.float64]  # [C, ...] normalised image x (0 where invalid)
    yn: NDArray[np.float64]  # [C, ...] normalised image y (0 where invalid)
    d: NDArray[np.float64]  # [3, C, ...] world unit ray directions (0 where invalid)
    c: NDArray[np.float64]  # [3, C, ...] camera centres (mm), broadcastable
    m: NDArray[np.float64]  # [4, C, ...] normalised residual -> raw pixels (row-major 2x2)
    R: NDArray[np.float64]  # [3, 3, C, ...] world->camera rotation, broadcastable
    t: NDArray[np.float64]  # [3, C, ...] world->camera translation (mm), broadcastable

    def gather(self, fi: NDArray[np.intp], pi: NDArray[np.intp]) -> _Obs:
        """The observations of point-frames ``(fi, pi)`` as ``[..., C, M]`` arrays."""
        def g(a: NDArray[np.float64]) -> NDArray[np.float64]:
            full = np.broadcast_to(a, a.shape[:-2] + self.w.shape[-2:])
            return full[..., fi, pi]
        return _Obs(*(g(a) for a in self))


def _observation_arrays(
    uv: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64],
    intr: CameraIntrinsics,
) -> _Obs:
    """Undistort ``uv [Fc, P, C, 2]``, build rays and the pixel-error metric.

    ``R`` is ``[Fcam, C, 3, 3]`` and ``t`` ``[Fcam, C, 3]`` with ``Fcam`` = Fc or 1.
    """
    Rt = np.ascontiguousarray(np.moveaxis(R, (0, 1), (3, 2)))[..., None]  # [3,3,C,Fcam,1]
    tt = np.ascontiguousarray(np.moveaxis(t, (0, 1), (2, 1)))[..., None]  # [3,C,Fcam,1]
    cam_ok = np.isfinite(Rt).all(axis=(0, 1)) & np.isfinite(tt).all(axis=0)  # [C,Fcam,1]
    Rt = np.where(cam_ok, Rt, 0.0)
    tt = np.where(cam_ok, tt, 0.0)
    u = np.moveaxis(uv, 2, 0)  # [C, Fc, P, 2] view
    ux = np.ascontiguousarray(u[..., 0])
    uy = np.ascontiguousarray(u[..., 1])
    valid = np.isfinite(ux) & np.isfinite(uy) & cam_ok
    w = valid.astype(np.float64)
    ux = np.where(valid, ux, 0.0)
    uy = np.where(valid, uy, 0.0)

    def col(a: NDArray[np.float64]) -> NDArray[np.float64]:
        return a[:, None, None]

    # Closed-form undistortion (camera.undistort_pixels) and its Jacobian at the observation.
    cdx, cdy = col(intr.distortion_centre[:, 0]), col(intr.distortion_centre[:, 1])
    a2 = col(intr.aspect**2)
    k1, k2, k3 = (col(intr.radial[:, i]) for i in range(3))
    ex = ux - cdx
    ey = uy - cdy
    r2 = ex * ex + a2 * (ey * ey)
    s = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ds = k1 + r2 * (2.0 * k2 + r2 * (3.0 * k3))  # d s / d r^2
    K = intr.K()
    fx, sk, px = col(K[:, 0, 0]), col(K[:, 0, 1]), col(K[:, 0, 2])
    fy, py = col(K[:, 1, 1]), col(K[:, 1, 2])
    yn = (cdy + s * ey - py) / fy
    xn = (cdx + s * ex - px - sk * yn) / fx
    xn *= w
    yn *= w

    # J = s I + 2 s' e g^T with e = (ex, ey), g = (ex, a^2 ey): Sherman-Morrison inverse,
    # then m = J^-1 [[fx, skew], [0, fy]] maps a normalised residual to raw pixels.
    gy = a2 * ey
    inv_s = 1.0 / s
    coef = 2.0 * ds / (s + 2.0 * ds * (ex * ex + gy * ey))
    cex = coef * ex
    cey = coef * ey
    j00 = inv_s * (1.0 - cex * ex)
    j01 = -inv_s * (cex * gy)
    j10 = -inv_s * (cey * ex)
    j11 = inv_s * (1.0 - cey * gy)
    m = np.stack([j00 * fx, j00 * sk + j01 * fy, j10 * fx, j10 * sk + j11 * fy])

    # World ray direction R^T (xn, yn, 1), normalised; zero for invalid observations.
    dx = Rt[0, 0] * xn + Rt[1, 0] * yn + Rt[2, 0]
    dy = Rt[0, 1] * xn + Rt[1, 1] * yn + Rt[2, 1]
    dz = Rt[0, 2] * xn + Rt[1, 2] * yn + Rt[2, 2]
    inv = np.divide(w, np.sqrt(dx * dx + dy * dy + dz * dz), out=np.zeros_like(w), where=valid)
    d = np.stack([dx * inv, dy * inv, dz * inv])
    c = -np.einsum("ji...,j...->i...", Rt, tt)  # centres -R^T t, [3, C, Fcam, 1]
    return _Obs(w, xn, yn, d, c, m, Rt, tt)


# --------------------------------------------------------------------------------------
# Small batched linear algebra
# --------------------------------------------------------------------------------------


def _normal_terms(o: _Obs) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-camera ``w (I - d d^T)`` (upper triangle, ``[6, C, ...]``) and ``w (I - d d^T) c``.

    ``d`` is already zero where ``w`` is zero, so ``w (I - d d^T) = w I - d d^T``.
    """
    dx, dy, dz = o.d
    w = o.w
    M = np.stack([w - dx * dx, -dx * dy, -dx * dz, w - dy * dy, -dy * dz, w - dz * dz])
    cx, cy, cz = o.c
    dc = dx * cx + dy * cy + dz * cz
    b = np.stack([w * cx - dx * dc, w * cy - dy * dc, w * cz - dz * dc])
    return M, b


def _solve_sym3(M: NDArray[np.float64], b: NDArray[np.float64],
                n: NDArray[np.float64]) -> NDArray[np.float64]:
    """Solve stacked symmetric 3x3 systems (upper triangle ``M [6, ...]``) in closed form.

    ``n`` is the ray count per system; systems whose determinant is negligible against
    ``n^3`` (parallel rays, fewer than two rays) give NaN. Returns ``[3, ...]``.
    """
    a, bb, c, d, e, f = M
    A00 = d * f - e * e
    A01 = c * e - bb * f
    A02 = bb * e - c * d
    A11 = a * f - c * c
    A12 = bb * c - a * e
    A22 = a * d - bb * bb
    det = a * A00 + bb * A01 + c * A02
    ok = det > 1e-12 * np.maximum(n, 1.0) ** 3
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), np.nan)
    x, y, z = b
    return np.stack([(A00 * x + A01 * y + A02 * z) * inv,
                     (A01 * x + A11 * y + A12 * z) * inv,
                     (A02 * x + A12 * y + A22 * z) * inv])


def _pixel_errors(X: NDArray[np.float64], o: _Obs) -> tuple[NDArray[np.float64],
                                                              NDArray[np.float64]]:
    """Raw-pixel reprojection error and depth (mm) of ``X [3, ...]`` in every camera.

    Returns two ``[C, ...]`` arrays (meaningless where the observation is invalid).
    """
    R, t = o.R, o.t
    X0, X1, X2 = X[0][None], X[1][None], X[2][None]
    # Points at a camera centre or unsolved cameras give inf/NaN here; callers mask them.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z = R[2, 0] * X0 + R[2, 1] * X1 + R[2, 2] * X2 + t[2]
        iz = 1.0 / z
        rx = (R[0, 0] * X0 + R[0, 1] * X1 + R[0, 2] * X2 + t[0]) * iz - o.xn
        ry = (R[1, 0] * X0 + R[1, 1] * X1 + R[1, 2] * X2 + t[1]) * iz - o.yn
        m = o.m
        ex = m[0] * rx + m[1] * ry
        ey = m[2] * rx + m[3] * ry
        return np.sqrt(ex * ex + ey * ey), z


def _ray_distance_sq(X: NDArray[np.float64], o: _Obs) -> NDArray[np.float64]:
    """Squared distance (mm^2) from ``X [3, ...]`` to every camera's ray, ``[C, ...]``."""
    vx = X[0][None] - o.c[0]
    vy = X[1][None] - o.c[1]
    vz = X[2][None] - o.c[2]
    along = vx * o.d[0] + vy * o.d[1] + vz * o.d[2]
    # The perpendicular part explicitly: |v|^2 - along^2 would cancel catastrophically.
    px = vx - along * o.d[0]
    py = vy - along * o.d[1]
    pz = vz - along * o.d[2]
    return px * px + py * py + pz * pz


def _gauss_newton(X: NDArray[np.float64], o: _Obs, mask: NDArray[np.bool_],
                  iterations: int) -> NDArray[np.float64]:
    """Refine ``X [3, ...]`` by Gauss-Newton on the raw-pixel error of the ``mask`` cameras."""
    R, t, m = o.R, o.t, o.m
    for _ in range(iterations):
        X0, X1, X2 = X[0][None], X[1][None], X[2][None]
        xc = [R[i, 0] * X0 + R[i, 1] * X1 + R[i, 2] * X2 + t[i] for i in range(3)]
        good = mask & (xc[2] > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            iz = np.where(good, 1.0 / xc[2], 0.0)
        nx, ny = xc[0] * iz, xc[1] * iz
        rx, ry = nx - o.xn, ny - o.yn
        # Pixel residual and its Jacobian: d(n)/dX = [[1, 0, -nx], [0, 1, -ny]] R / z.
        px = m[0] * rx + m[1] * ry
        py = m[2] * rx + m[3] * ry
        Jn0 = [(R[0, j] - nx * R[2, j]) * iz for j in range(3)]
        Jn1 = [(R[1, j] - ny * R[2, j]) * iz for j in range(3)]
        J0 = [m[0] * Jn0[j] + m[1] * Jn1[j] for j in range(3)]
        J1 = [m[2] * Jn0[j] + m[3] * Jn1[j] for j in range(3)]
        H = np.stack([(J0[i] * J0[j] + J1[i] * J1[j]).sum(0)
                      for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))])
        g = np.stack([(J0[i] * px + J1[i] * py).sum(0) for i in range(3)])
        scale = np.maximum((H[0] + H[3] + H[5]) / 3.0, 1e-300)
        step = _solve_sym3(H / scale, g / scale, np.ones_like(scale))
        X = np.where(np.isfinite(step), X - step, X)
    return X


# --------------------------------------------------------------------------------------
# Subset search
# --------------------------------------------------------------------------------------


def _drop_table(C: int, max_drop: int) -> list[tuple[int, ...]]:
    """Sets of dropped cameras, by drop level 1..max_drop (combinations of ``range(C)``)."""
    return [D for k in range(1, min(max_drop, C) + 1) for D in itertools.combinations(range(C), k)]


def _search(o: _Obs, X0: NDArray[np.float64], e0: NDArray[np.float64],
            err0: NDArray[np.float64], z0: NDArray[np.float64], floor: int,
            params: TriangulationParameters) -> tuple[NDArray[np.float64], NDArray[np.bool_],
                                                      NDArray[np.float64]]:
    """Outlier-rejection search for gathered point-frames (``o`` is ``[..., C, M]``).

    ``X0 [3, M]``, ``e0 [M]``, ``err0 [C, M]`` and ``z0 [C, M]`` are the all-camera point,
    its mean error, and its per-camera errors and depths. Returns the chosen points
    ``[3, M]``, contribution masks ``[C, M]`` and per-camera errors ``[C, M]``.
    """
    C, Mn = o.w.shape
    valid = o.w > 0
    n = valid.sum(0)
    target = float(params.target_reprojection_error)
    cos_min = math.cos(math.radians(params.min_ray_angle_deg))
    Mt, bt = _normal_terms(o)
    A_all, b_all = Mt.sum(1), bt.sum(1)
    # |cos| of the angle between every two rays, +inf when either is missing.
    pairs = list(itertools.combinations(range(C), 2))
    absdot = np.full((len(pairs), Mn), np.inf)
    for q, (i, j) in enumerate(pairs):
        dot = np.abs(o.d[0, i] * o.d[0, j] + o.d[1, i] * o.d[1, j] + o.d[2, i] * o.d[2, j])
        absdot[q] = np.where(valid[i] & valid[j], dot, np.inf)

    # Level 0 (all cameras) seeds the ensemble; its geometry is checked like any subset.
    drops = _drop_table(C, int(params.maximum_cameras_to_drop))
    S = len(drops) + 1
    Xs = np.empty((S, 3, Mn))
    es = np.empty((S, Mn))
    ok = np.empty((S, Mn), bool)
    level = np.zeros(S, np.intp)
    members = np.ones((S, C), bool)
    Xs[0], es[0] = X0, e0
    ok[0] = np.isfinite(e0) & np.where(valid, z0 > 0, True).all(0)
    ok[0] &= absdot.min(0) <= cos_min
    for s, D in enumerate(drops, start=1):
        level[s] = len(D)
        members[s, list(D)] = False
        Ds = list(D)
        # The subset is the valid cameras minus D; it exists only if D is all valid.
        exists = valid[Ds].all(0) & (n - len(D) >= floor)
        A = A_all - Mt[:, Ds].sum(1)
        b = b_all - bt[:, Ds].sum(1)
        k = n - len(D)
        X = _solve_sym3(A, b, k.astype(np.float64))
        err, z = _pixel_errors(X, o)
        inset = valid & members[s][:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            es[s] = np.where(inset, err, 0.0).sum(0) / k
        keep = [q for q, (i, j) in enumerate(pairs) if i not in D and j not in D]
        wide = absdot[keep].min(0) <= cos_min if keep else np.zeros(Mn, bool)
        ok[s] = (exists & wide & np.isfinite(es[s]) & np.isfinite(X).all(0)
                 & np.where(inset, z > 0, True).all(0))
        Xs[s] = X

    # Early stop: after the first drop level in which a subset reaches the target.
    reached = ok & (es < target)
    stop = np.full(Mn, level.max())
    for k in range(int(level.max()), 0, -1):
        stop = np.where(reached[level == k].any(0), k, stop)
    tested = ok & (level[:, None] <= stop[None, :])
    any_reached = (reached & tested)[1:].any(0)

    # w = exp(-5 e / target), shifted by the best error so it cannot underflow (the shift
    # cancels in the normalised mean).
    e_min = np.where(tested, es, np.inf).min(0)
    with np.errstate(invalid="ignore", over="ignore"):
        w = np.where(tested, np.exp(-WEIGHT_DECAY * (es - e_min) / target), 0.0)
    W = w.sum(0)
    has = W > 0
    Wd = np.where(has, W, 1.0)
    Xw = np.einsum("sm,skm->km", w, np.where(tested[:, None], Xs, 0.0)) / Wd
    participation = (members.T.astype(np.float64) @ w) / Wd  # [C, M]
    contrib_w = valid & (participation >= 0.5)

    # No subset reached the target: keep whichever of the weighted and the all-camera
    # result has the lower mean reprojection error over its own cameras.
    err_w, _ = _pixel_errors(Xw, o)
    cnt = contrib_w.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        e_w = np.where(contrib_w, err_w, 0.0).sum(0) / cnt
    use_w = has & (cnt >= 2) & (any_reached | (e_w < e0) | ~np.isfinite(e0))
    Xout = np.where(use_w, Xw, X0)
    contrib = np.where(use_w, contrib_w, valid)
    return Xout, contrib, np.where(use_w, err_w, err0)


# --------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------


def effective_minimum_cameras(params: TriangulationParameters, n_cameras: int) -> int:
    """``minimum_cameras`` clamped to the camera count, with a warning when clamped."""
    mc = int(params.minimum_cameras)
    if mc > n_cameras:
        log.warning(
            "Minimum Cameras for Triangulation (%d) is above the number of cameras (%d); "
            "using %d.", mc, n_cameras, n_cameras,
        )
        mc = n_cameras
    return mc


def _as_cameras(R: ArrayLike, t: ArrayLike, F: int, C: int) -> tuple[NDArray[np.float64],
                                                                        NDArray[np.float64]]:
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if R.shape == (C, 3, 3):
        R = R[None]
    if t.shape == (C, 3):
        t = t[None]
    if R.shape not in ((1, C, 3, 3), (F, C, 3, 3)):
        raise ValueError(f"R must have shape ({C}, 3, 3) or ({F}, {C}, 3, 3), got {R.shape}")
    if t.shape not in ((1, C, 3), (F, C, 3)):
        raise ValueError(f"t must have shape ({C}, 3) or ({F}, {C}, 3), got {t.shape}")
    if R.shape[0] != t.shape[0]:
        raise ValueError("R and t must both be fixed ([C, ...]) or both per frame ([F, C, ...])")
    return R, t


def triangulate(
    observations: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    params: TriangulationParameters | None = None,
    *,
    single_camera_estimates: ArrayLike | None = None,
    chunk_size: int = 8192,
    progress: Callable[[int, int], bool] | None = None,
) -> Triangulation:
    """Triangulate every point of every frame, optionally with outlier rejection.

    Parameters
    ----------
    observations : array_like, shape (F, P, C, 2)
        Raw (distorted) pixel observations; NaN where a camera has none.
    R : array_like, shape (C, 3, 3) or (F, C, 3, 3)
        World->camera rotations, fixed or per frame (NaN marks an unsolved camera-frame,
        whose observations are then ignored).
    t : array_like, shape (C, 3) or (F, C, 3)
        World->camera translations (mm).
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.
    params : TriangulationParameters, optional
        Defaults to ``TriangulationParameters()``.
    single_camera_estimates : array_like, shape (F, P, 3), optional
        3D estimates (mm) used for single-camera points when ``minimum_cameras`` is 1 and
        ``flatten_single_camera_data`` is False.
    chunk_size : int
        Point-frames processed together (whole frames; bounds memory). Results do not
        depend on it.
    progress : callable, optional
        ``progress(frames_done, F)`` after each chunk; returning False cancels: frames not
        yet done stay NaN and ``frames_done`` says how many were done.

    Returns
    -------
    Triangulation
        Points (mm), mean reprojection error (px), residual (mm), contribution mask and
        camera count per point-frame.

    Raises
    ------
    ValueError
        On inconsistent shapes or parameters (the message names the argument).

    Examples
    --------
    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics, project
    >>> intr = CameraIntrinsics(focal=[1000.0] * 3, principal_point=[[640.0, 360.0]] * 3)
    >>> R = np.repeat(np.eye(3)[None], 3, axis=0)
    >>> t = np.array([[-60.0, 0, 250], [0, 0, 250], [60.0, 0, 250]])
    >>> X = np.array([[[1.0, 2.0, 3.0]]])
    >>> uv, _ = project(X, R, t, intr)
    >>> res = triangulate(uv, R, t, intr)
    >>> bool(np.allclose(res.points, X, atol=1e-6)), int(res.n_cameras[0, 0])
    (True, 3)
    """
    params = TriangulationParameters() if params is None else params
    obs_all = np.asarray(observations, dtype=np.float64)
    if obs_all.ndim != 4 or obs_all.shape[-1] != 2:
        raise ValueError(f"observations must have shape (F, P, C, 2), got {obs_all.shape}")
    F, P, C, _ = obs_all.shape
    if intr.n_cameras != C:
        raise ValueError(f"intr has {intr.n_cameras} cameras but observations have {C}")
    Rf, tf = _as_cameras(R, t, F, C)
    per_frame = Rf.shape[0] == F and F != 1
    est = None
    if single_camera_estimates is not None:
        est = np.asarray(single_camera_estimates, dtype=np.float64)
        if est.shape != (F, P, 3):
            raise ValueError(
                f"single_camera_estimates must have shape ({F}, {P}, 3), got {est.shape}"
            )
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")

    mc = effective_minimum_cameras(params, C)

    points = np.full((F, P, 3), np.nan)
    reproj = np.full((F, P), np.nan)
    resid = np.full((F, P), np.nan)
    contribution = np.zeros((F, P, C), bool)
    ncam = np.zeros((F, P), np.int8)

    frames_per_chunk = max(1, chunk_size // max(P, 1))
    done = 0
    for f0 in range(0, F, frames_per_chunk):
        f1 = min(F, f0 + frames_per_chunk)
        X, mask, e_mean, r_rms = _triangulate_chunk(
            obs_all[f0:f1], Rf[f0:f1] if per_frame else Rf, tf[f0:f1] if per_frame else tf,
            intr, params, mc, None if est is None else est[f0:f1],
        )
        points[f0:f1] = np.moveaxis(X, 0, -1)
        reproj[f0:f1] = e_mean
        resid[f0:f1] = r_rms
        contribution[f0:f1] = np.moveaxis(mask, 0, -1)
        ncam[f0:f1] = mask.sum(0)
        done = f1
        if progress is not None and progress(done, F) is False:
            break
    return Triangulation(points, reproj, resid, contribution, ncam, done)


def _triangulate_chunk(
    uv: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64],
    intr: CameraIntrinsics, params: TriangulationParameters, mc: int,
    est: NDArray[np.float64] | None,
) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
    """Points ``[3, Fc, P]``, contribution ``[C, Fc, P]``, mean error and residual ``[Fc, P]``."""
    o = _observation_arrays(uv, R, t, intr)
    valid = o.w > 0
    n = valid.sum(0)
    floor = max(mc, 2)
    enough = n >= floor
    # Points below the minimum get no rays at all (weight 0), so their solve gives NaN.
    o_multi = o._replace(w=o.w * enough, d=o.d * enough)
    Mt, bt = _normal_terms(o_multi)
    X = _solve_sym3(Mt.sum(1), bt.sum(1), n * enough)
    mask = valid & enough
    err, z = _pixel_errors(X, o)
    with np.errstate(invalid="ignore", divide="ignore"):
        e_mean = np.where(mask, err, 0.0).sum(0) / n

    if params.use_outlier_rejection and params.maximum_cameras_to_drop > 0:
        need = (n >= floor + 1) & ~(e_mean <= params.target_reprojection_error)
        fi, pi = np.nonzero(need)
        if fi.size:
            Xs, cs, es = _search(o.gather(fi, pi), X[:, fi, pi], e_mean[fi, pi],
                                 err[:, fi, pi], z[:, fi, pi], floor, params)
            X[:, fi, pi] = Xs
            mask[:, fi, pi] = cs
            err[:, fi, pi] = es

    if params.refine_iterations > 0:
        X = _gauss_newton(X, o, mask, int(params.refine_iterations))
        err, _ = _pixel_errors(X, o)

    has = np.isfinite(X).all(0)
    mask &= has
    cnt = mask.sum(0)
    d2 = _ray_distance_sq(X, o)
    with np.errstate(invalid="ignore", divide="ignore"):
        e_mean = np.where(mask, err, 0.0).sum(0) / cnt
        r_rms = np.sqrt(np.where(mask, d2, 0.0).sum(0) / cnt)

    if mc <= 1:
        single = n == 1
        if single.any():
            fi, pi = np.nonzero(single)
            sel = valid[:, fi, pi]  # [C, M]
            if params.flatten_single_camera_data:
                # Where the ray meets the world plane Z = 0 (in front of the camera only).
                og = o.gather(fi, pi)
                c = (og.c * sel).sum(1)
                d = og.d.sum(1)
                with np.errstate(divide="ignore", invalid="ignore"):
                    lam = -c[2] / d[2]
                lam = np.where(lam > 0, lam, np.nan)
                Xs = c + lam * d
            elif est is not None:
                Xs = est[fi, pi].T
            else:
                Xs = np.full((3, fi.size), np.nan)
            ok = np.isfinite(Xs).all(0)
            X[:, fi, pi] = Xs
            mask[:, fi, pi] = sel & ok
            # A single ray is met exactly: no reprojection error and no residual.
            e_mean[fi, pi] = np.where(ok, 0.0, np.nan)
            r_rms[fi, pi] = np.where(ok, 0.0, np.nan)
    has = np.isfinite(X).all(0)
    X[:, ~has] = np.nan
    e_mean[~has] = np.nan
    r_rms[~has] = np.nan
    return X, mask, e_mean, r_rms
