"""Camera solve from the calibration brim: manual, automatic and per-frame.

The brim is a rigid object with dark dots at known positions (the brim model, mm); its
frame is the world frame of the project. Solving the brim means finding, for every
camera, the pose ``x_cam = R X + t`` that projects the model dots onto their detections.

Manual solve (:func:`solve_brim_manual`)
    The user matched four or more brim dots to detections in every camera. Each camera
    gets an initial pose from those matches alone (several OpenCV PnP solvers on
    normalised image coordinates; the candidate that explains the most detections of the
    whole brim wins, which removes the ambiguities of 4-point PnP). The whole model is
    then projected and each dot takes the nearest detection that is unambiguous, and the
    poses are refined on all matches; matching and refinement alternate a few times.

Automatic solve (:func:`solve_brim_auto`)
    When an XCP calibration gives the rig geometry (cameras in some world frame), brim
    detections are triangulated with it: detections of every camera pair that satisfy the
    epipolar constraint and are confirmed by a detection in a third camera become 3D
    points. The brim model is registered to that cloud (which also holds face markers)
    by RANSAC over model triplets matched to cloud triplets with equal side lengths, then
    Kabsch; the best hypotheses are checked by projecting the model into every camera.
    The rig moved into the brim frame is the initial pose, refined as in the manual solve.

Per-frame re-solve (:func:`resolve_frame_cameras`)
    Tracking re-solves the cameras of every frame from the previous frame's poses and the
    brim observations of the frame (or the detections, matched by projection): a few
    Gauss-Newton steps vectorised over cameras, ~1 ms for 4 cameras.

Refinement minimises the reprojection error in normalised image coordinates scaled by the
focal length, i.e. in pinhole pixels (within a fraction of a percent of raw pixels for
the mild radial distortion of head-mounted cameras).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    cross_matrix,
    matrix_to_rodrigues,
    pixels_to_normalised,
    project,
    rodrigues_to_matrix,
)
from carapost.algorithms.params import param, validate

log = logging.getLogger("carapost.brim")

__all__ = [
    "BrimSolveParameters",
    "BrimSolveResult",
    "FrameCameras",
    "brim_exclusion_mask",
    "match_by_projection",
    "multiview_tracks",
    "refine_poses",
    "register_model",
    "resolve_frame_cameras",
    "solve_brim_auto",
    "solve_brim_manual",
    "rotation_error_deg",
    "triangulate_tracks",
    "symmetric_epipolar_distance",
]


@dataclass(frozen=True)
class BrimSolveParameters:
    """Parameters of the brim solves.

    Attributes
    ----------
    min_correspondences : int
        Fewest brim dots matched by hand in a camera for the manual solve (>= 4).
    match_distance_px : float
        Largest distance between a projected brim dot and the detection it takes (px).
    ambiguity_ratio : float
        A dot takes its nearest detection only when the second nearest is at least this
        many times further away (and the detection's nearest dot is that dot).
    match_rounds : int
        Alternations of matching by projection and pose refinement.
    min_matches : int
        Fewest matched brim dots for a camera pose to be refined or accepted.
    max_rms_px : float
        The solve fails when a camera's final RMS reprojection error exceeds this (px).
    refine_iterations : int
        Gauss-Newton steps per refinement.
    epipolar_distance_px : float
        Automatic solve: largest symmetric epipolar distance (pinhole px) of a detection
        pair and largest reprojection distance of its confirming third view.
    registration_tolerance_mm : float
        Automatic solve: a model dot within this distance of a cloud point is an inlier,
        and side lengths of matched triplets may differ by this much.
    ransac_samples : int
        Automatic solve: number of model triplets tried.
    seed : int
        Seed of the random triplet sampling (results are reproducible).
    use_face_points : bool
        Finish with a bundle adjustment that also uses face markers found in three or
        more cameras (brim dots fixed): they tie the cameras to each other, which the
        narrow brim band alone does poorly (our addition to the reference algorithm).
    face_outlier_px : float
        Face observations further than this from their projection after a first bundle
        pass are dropped before the second pass (px).
    outlier_px : float
        A matched dot further than this (px, and 4 times the camera's median) from its
        projection after a robust refinement is unmatched before the final refinement.
    """

    # internal tunables: the guide has no brim solve properties
    min_correspondences: int = param(4, min=4)
    match_distance_px: float = param(8.0, min=0.0, min_exclusive=True)
    ambiguity_ratio: float = param(1.5, min=1.0)
    match_rounds: int = 3
    min_matches: int = param(4, min=3)
    max_rms_px: float = param(2.0, min=0.0, min_exclusive=True)
    refine_iterations: int = 8
    epipolar_distance_px: float = param(3.0, min=0.0, min_exclusive=True)
    registration_tolerance_mm: float = param(2.0, min=0.0, min_exclusive=True)
    ransac_samples: int = 300
    seed: int = 0
    use_face_points: bool = True
    face_outlier_px: float = 0.75
    outlier_px: float = 1.0

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class BrimSolveResult:
    """Outcome of a brim solve.

    Attributes
    ----------
    R : ndarray, shape (C, 3, 3)
        World (brim frame) -> camera rotations; meaningless when ``success`` is False.
    t : ndarray, shape (C, 3)
        Translations (mm).
    matches : ndarray of int, shape (B, C)
        Index of the detection each brim dot is matched to in each camera, -1 if none.
    rms_px : ndarray, shape (C,)
        RMS reprojection error of the matched dots per camera (px); NaN if unsolved.
    success : bool
    message : str
        What was done or why it failed, suitable for the log.
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    matches: NDArray[np.intp]
    rms_px: NDArray[np.float64]
    success: bool
    message: str


class FrameCameras(NamedTuple):
    """Result of :func:`resolve_frame_cameras`.

    Attributes
    ----------
    R : ndarray, shape (C, 3, 3)
    t : ndarray, shape (C, 3)
    rms_px : ndarray, shape (C,)
        RMS reprojection error of the brim dots used (px); NaN where a camera had too
        few brim observations and kept its previous pose.
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    rms_px: NDArray[np.float64]


# ------------------------------------------------------------------------------------------
# Small helpers
# ------------------------------------------------------------------------------------------
def _as_detections(detections: Sequence[ArrayLike], n_cameras: int) -> list[NDArray]:
    if len(detections) != n_cameras:
        raise ValueError(f"detections has {len(detections)} cameras, the intrinsics have "
                         f"{n_cameras}")
    out = []
    for c, d in enumerate(detections):
        a = np.asarray(d, dtype=np.float64).reshape(-1, 2)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"detections of camera {c} hold NaN or inf")
        out.append(a)
    return out


def _normalised(det: NDArray, intr: CameraIntrinsics, c: int) -> NDArray[np.float64]:
    """Normalised coordinates [N, 2] of raw pixels [N, 2] of camera ``c``."""
    if len(det) == 0:
        return np.zeros((0, 2))
    return pixels_to_normalised(det[:, None, :], intr.subset([c]))[:, 0]


def _project_one(X: NDArray, R: NDArray, t: NDArray, intr: CameraIntrinsics, c: int
                 ) -> NDArray[np.float64]:
    """Raw pixels [B, 2] of points [B, 3] in camera ``c`` (NaN behind it)."""
    uv, _ = project(X, R[None], t[None], intr.subset([c]))
    return uv[:, 0]


def _fail(C: int, B: int, message: str) -> BrimSolveResult:
    log.warning("%s", message)
    return BrimSolveResult(
        R=np.broadcast_to(np.eye(3), (C, 3, 3)).copy(), t=np.zeros((C, 3)),
        matches=np.full((B, C), -1, dtype=np.intp), rms_px=np.full(C, np.nan),
        success=False, message=message,
    )


# ------------------------------------------------------------------------------------------
# Pose refinement, vectorised over cameras
# ------------------------------------------------------------------------------------------
def refine_poses(
    X: ArrayLike,
    xn: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    *,
    scale: ArrayLike | None = None,
    iterations: int = 8,
    huber_px: float = 2.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Refine camera poses against fixed 3D points (Gauss-Newton, all cameras at once).

    Parameters
    ----------
    X : array_like, shape (B, 3) or (C, B, 3)
        Known 3D points (mm), shared by all cameras or per camera.
    xn : array_like, shape (C, B, 2)
        Observed normalised image coordinates; NaN where a camera does not see a point.
    R : array_like, shape (C, 3, 3)
        Initial world->camera rotations.
    t : array_like, shape (C, 3)
        Initial translations (mm).
    scale : array_like, shape (C,), optional
        Pixels per normalised unit (the focal length) used to express errors in pixels.
    iterations : int
        Gauss-Newton steps (stops early when every update is tiny).
    huber_px : float
        Observations further than this (px) from their projection are down-weighted
        (Huber), so a single wrong match cannot drag a pose.

    Returns
    -------
    R : ndarray, shape (C, 3, 3)
    t : ndarray, shape (C, 3)
    rms_px : ndarray, shape (C,)
        RMS reprojection error (px) of the observed points; NaN for a camera with fewer
        than 3 observations (its pose is returned unchanged).
    """
    xn = np.asarray(xn, dtype=np.float64)
    C, B = xn.shape[:2]
    X = np.broadcast_to(np.asarray(X, dtype=np.float64), (C, B, 3))
    R = np.array(R, dtype=np.float64).reshape(C, 3, 3)
    t = np.array(t, dtype=np.float64).reshape(C, 3)
    f = np.ones(C) if scale is None else np.asarray(scale, dtype=np.float64).reshape(C)
    valid = np.isfinite(xn).all(-1)
    ok = valid.sum(1) >= 3
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
    return R, t, rms


# ------------------------------------------------------------------------------------------
# Matching by projection
# ------------------------------------------------------------------------------------------
def match_by_projection(
    projected: ArrayLike,
    detections: ArrayLike,
    *,
    max_distance: float,
    ambiguity_ratio: float = 1.5,
    excluded: ArrayLike | None = None,
) -> NDArray[np.intp]:
    """Match projected points to detections of one image: mutual nearest, unambiguous.

    Parameters
    ----------
    projected : array_like, shape (B, 2)
        Predicted pixel positions (NaN for points not predicted).
    detections : array_like, shape (N, 2)
        Detection centres (px).
    max_distance : float
        Largest accepted distance (px).
    ambiguity_ratio : float
        A point's second-nearest detection must be at least this many times further than
        its nearest, and the detection's second-nearest point likewise.
    excluded : array_like of bool, shape (N,), optional
        Detections that may not be taken.

    Returns
    -------
    ndarray of int, shape (B,)
        Detection index per point, -1 where none.
    """
    P = np.asarray(projected, dtype=np.float64).reshape(-1, 2)
    D = np.asarray(detections, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(P), -1, dtype=np.intp)
    if len(P) == 0 or len(D) == 0:
        return out
    d = np.linalg.norm(P[:, None, :] - D[None, :, :], axis=-1)
    d[~np.isfinite(d)] = np.inf
    if excluded is not None:
        d[:, np.asarray(excluded, dtype=bool)] = np.inf
    nearest = np.argmin(d, axis=1)
    d_sorted = np.sort(d, axis=1)
    first = d_sorted[:, 0]
    second = d_sorted[:, 1] if d.shape[1] > 1 else np.full(len(P), np.inf)
    col_sorted = np.sort(d, axis=0)
    col_second = col_sorted[1] if d.shape[0] > 1 else np.full(len(D), np.inf)
    back = np.argmin(d, axis=0)
    rows = np.arange(len(P))
    ok = (
        (first <= max_distance)
        & (second >= ambiguity_ratio * first)
        & (back[nearest] == rows)
        & (col_second[nearest] >= ambiguity_ratio * first)
    )
    out[ok] = nearest[ok]
    return out


def _match_all(model: NDArray, dets: list[NDArray], R: NDArray, t: NDArray,
               intr: CameraIntrinsics, params: BrimSolveParameters,
               solved: NDArray[np.bool_], max_distance: float) -> NDArray[np.intp]:
    B, C = len(model), len(dets)
    matches = np.full((B, C), -1, dtype=np.intp)
    if not solved.any():
        return matches
    uv, _ = project(model, R, t, intr)  # (B, C, 2)
    for c in np.flatnonzero(solved):
        matches[:, c] = match_by_projection(uv[:, c], dets[c], max_distance=max_distance,
                                            ambiguity_ratio=params.ambiguity_ratio)
    return matches


def _obs_from_matches(matches: NDArray, dets_n: list[NDArray]) -> NDArray[np.float64]:
    """Normalised observations (C, B, 2) of the matched dots (NaN where unmatched)."""
    B, C = matches.shape
    xn = np.full((C, B, 2), np.nan)
    for c in range(C):
        m = matches[:, c] >= 0
        xn[c, m] = dets_n[c][matches[m, c]]
    return xn


def _keep_fixed(matches: NDArray[np.intp], fixed: NDArray | None) -> NDArray[np.intp]:
    """Impose the ``fixed`` (hand) matches >= 0 on ``matches`` (B, C), in place.

    A hand match wins; the detection it uses cannot serve another dot.
    """
    if fixed is None:
        return matches
    keep = fixed >= 0
    for c in range(matches.shape[1]):
        taken = np.isin(matches[:, c], fixed[keep[:, c], c])
        matches[taken & ~keep[:, c], c] = -1
    matches[keep] = fixed[keep]
    return matches


def _match_and_refine(model: NDArray, dets: list[NDArray], dets_n: list[NDArray],
                      R: NDArray, t: NDArray, intr: CameraIntrinsics,
                      params: BrimSolveParameters, solved: NDArray[np.bool_],
                      fixed: NDArray | None = None
                      ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Alternate matching by projection and refinement; ``fixed`` matches are kept."""
    radius = params.match_distance_px
    matches = np.full((len(model), len(dets)), -1, dtype=np.intp)
    rms = np.full(len(dets), np.nan)
    for k in range(max(1, int(params.match_rounds))):
        # the first round searches wider: the initial pose may be a few px off
        r = radius * (2.0 if k == 0 else 1.0)
        matches = _keep_fixed(_match_all(model, dets, R, t, intr, params, solved, r), fixed)
        enough = (matches >= 0).sum(0) >= params.min_matches
        use = solved & enough
        xn = _obs_from_matches(matches, dets_n)
        xn[~use] = np.nan
        R_new, t_new, rms_new = refine_poses(model, xn, R, t, scale=intr.focal,
                                             iterations=params.refine_iterations)
        R[use], t[use], rms[use] = R_new[use], t_new[use], rms_new[use]
    # final matching with the refined poses, then a last refinement without Huber
    matches = _keep_fixed(_match_all(model, dets, R, t, intr, params, solved, radius), fixed)
    # a dot that is hidden can still find a face marker or clutter within the match
    # radius; its residual stands out after the refinement, so it is unmatched and the
    # camera refined again (one such match in a camera seeing 9 dots moved it by 2.5 mm)
    for _ in range(3):
        use = solved & ((matches >= 0).sum(0) >= params.min_matches)
        xn = _obs_from_matches(matches, dets_n)
        xn[~use] = np.nan
        R_new, t_new, rms_new = refine_poses(model, xn, R, t, scale=intr.focal,
                                             iterations=params.refine_iterations,
                                             huber_px=1e9)
        R[use], t[use], rms[use] = R_new[use], t_new[use], rms_new[use]
        uv, _ = project(model, R, t, intr)  # (B, C, 2)
        pruned = False
        for c in np.flatnonzero(use):
            m = np.flatnonzero(matches[:, c] >= 0)
            err = np.linalg.norm(uv[m, c] - dets[c][matches[m, c]], axis=1)
            bad = (err > max(params.outlier_px, 4.0 * float(np.median(err))))
            bad &= err >= err.max()  # the worst one at a time: it drags the others
            if fixed is not None:
                bad &= fixed[m, c] < 0  # hand matches are the user's call
            if bad.any() and len(m) - int(bad.sum()) >= params.min_matches:
                matches[m[bad], c] = -1
                pruned = True
        if not pruned:
            break
    matches[:, ~solved] = -1
    return R, t, matches, rms


def _bundle_options(bundle_frame: Any) -> dict[str, Any]:
    """Ask for scipy's trust-region solver when bundle_frame offers a choice: on these
    small, well-conditioned problems it converges to the minimum where the fast Schur
    solver was seen to stop early (0.09 px instead of 0.035 px on one synthetic frame)."""
    import inspect

    try:
        params = inspect.signature(bundle_frame).parameters
    except (TypeError, ValueError):
        return {}
    return {"solver": "least_squares"} if "solver" in params else {}


def _bundle_with_face(model: NDArray, dets: list[NDArray], dets_n: list[NDArray],
                      R: NDArray, t: NDArray, intr: CameraIntrinsics, matches: NDArray,
                      params: BrimSolveParameters) -> tuple[NDArray, NDArray, NDArray] | None:
    """Refine all cameras on the brim (fixed) plus face markers seen by >= 3 cameras."""
    from carapost.algorithms.bundle import bundle_frame

    kw = _bundle_options(bundle_frame)
    B, C = matches.shape
    excluded = []
    for c in range(C):
        e = np.zeros(len(dets[c]), dtype=bool)
        e[matches[matches[:, c] >= 0, c]] = True
        excluded.append(e)
    tracks, X = multiview_tracks(dets_n, R, t, intr.focal, params.epipolar_distance_px,
                                 min_views=3, excluded=excluded)
    # the brim-only cameras are good to a fraction of a pixel: a track they cannot
    # explain holds a wrong detection
    X, _, rep = triangulate_tracks(tracks, dets_n, R, t, intr.focal)
    good = np.isfinite(rep) & (rep < 2.0 * params.face_outlier_px)
    tracks, X = tracks[good], X[good]
    if len(tracks) < 6:
        return None
    rows = np.concatenate([matches, tracks])
    obs = np.full(rows.shape + (2,), np.nan)
    for c in range(C):
        m = rows[:, c] >= 0
        obs[m, c] = dets[c][rows[m, c]]
    points = np.concatenate([model, X])
    fixed = np.zeros(len(points), dtype=bool)
    fixed[:B] = True
    res = bundle_frame(obs, points, R, t, intr, fixed_points_mask=fixed, loss="huber",
                       f_scale=1.0, max_nfev=50, **kw)
    if not np.isfinite(res.rms_after):
        return None
    # a face track with a wrong detection would bend the rig: drop the observations a
    # pass cannot explain (relative to the typical error, never above face_outlier_px)
    # and run again
    for _ in range(2):
        uvp, _ = project(res.points, res.R, res.t, intr)
        err = np.linalg.norm(uvp - obs, axis=-1)
        fin = np.isfinite(err)
        if not fin.any():
            break
        thr = min(params.face_outlier_px, max(0.2, 6.0 * float(np.median(err[fin]))))
        bad = fin & (err > thr)
        bad[:B] = False
        if not bad.any():
            break
        obs[bad] = np.nan
        weak = np.isfinite(obs).all(-1).sum(1) < 2
        weak[:B] = False
        obs[weak] = np.nan
        res = bundle_frame(obs, res.points, res.R, res.t, intr, fixed_points_mask=fixed,
                           loss="huber", f_scale=1.0, max_nfev=50, **kw)
        if not np.isfinite(res.rms_after):
            return None
    # per-camera RMS of the brim dots with the new cameras
    uv, _ = project(model, res.R, res.t, intr)
    d2 = np.where(matches >= 0, ((uv - obs[:B]) ** 2).sum(-1), np.nan)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(d2, axis=0))
    return res.R, res.t, rms


def _result(model: NDArray, R: NDArray, t: NDArray, matches: NDArray, rms: NDArray,
            params: BrimSolveParameters, what: str, names: list[str]) -> BrimSolveResult:
    n = (matches >= 0).sum(0)
    bad = [c for c in range(len(n)) if n[c] < params.min_matches or not np.isfinite(rms[c])
           or rms[c] > params.max_rms_px]
    per_cam = ", ".join(f"{names[c]} {n[c]} dots {rms[c]:.2f} px" for c in range(len(n)))
    if bad:
        msg = (f"{what} failed for camera(s) {', '.join(names[c] for c in bad)} "
               f"(fewer than {params.min_matches} matched dots or RMS above "
               f"{params.max_rms_px:g} px): {per_cam}")
        log.warning("%s", msg)
        return BrimSolveResult(R, t, matches, rms, False, msg)
    msg = f"{what}: {per_cam}"
    log.info("%s", msg)
    return BrimSolveResult(R, t, matches, rms, True, msg)


# ------------------------------------------------------------------------------------------
# Manual solve
# ------------------------------------------------------------------------------------------
_PNP_METHODS = ("SOLVEPNP_SQPNP", "SOLVEPNP_EPNP", "SOLVEPNP_AP3P", "SOLVEPNP_IPPE",
                "SOLVEPNP_ITERATIVE")


def _pnp_candidates(obj: NDArray, img_n: NDArray) -> list[tuple[NDArray, NDArray]]:
    """Pose candidates (R, t) from OpenCV's PnP solvers on normalised points."""
    K = np.eye(3)
    out = []
    o = np.ascontiguousarray(obj, dtype=np.float64).reshape(-1, 1, 3)
    i = np.ascontiguousarray(img_n, dtype=np.float64).reshape(-1, 1, 2)
    for name in _PNP_METHODS:
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


def solve_brim_manual(
    detections_per_camera: Sequence[ArrayLike],
    correspondences: Mapping[int, Sequence[tuple[int, int]]],
    brim_model: ArrayLike,
    intr: CameraIntrinsics,
    *,
    initial: tuple[ArrayLike, ArrayLike] | None = None,
    params: BrimSolveParameters | None = None,
) -> BrimSolveResult:
    """Solve the cameras from brim dots matched to detections by hand.

    Parameters
    ----------
    detections_per_camera : sequence of array_like, each shape (N_c, 2)
        Detection centres of one frame per camera (raw px).
    correspondences : mapping camera -> sequence of (brim_index, detection_index)
        The hand matches: at least ``params.min_correspondences`` (4) per camera.
    brim_model : array_like, shape (B, 3)
        Brim dot positions (mm) in the brim frame.
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.
    initial : (R [C,3,3], t [C,3]), optional
        Initial poses; when given, PnP is skipped and they are only refined.
    params : BrimSolveParameters, optional

    Returns
    -------
    BrimSolveResult
        ``success`` False (with the reason in ``message``) for too few or invalid
        correspondences, a camera with no detections, or a poor fit. Never raises for
        bad data; ``ValueError`` only for arrays of the wrong shape.

    Examples
    --------
    >>> from carapost.synth.scene import SynthConfig, build_scene
    >>> s = build_scene(SynthConfig(frames=1))
    >>> dets = [s.brim_uv[0, s.brim_visible[0, :, c], c] for c in range(4)]
    >>> idx = [list(np.flatnonzero(s.brim_visible[0, :, c])) for c in range(4)]
    >>> corr = {c: [(idx[c][k], k) for k in (0, 5, 10, 15)] for c in range(4)}
    >>> res = solve_brim_manual(dets, corr, s.brim3d, s.intrinsics)
    >>> bool(res.success), bool(np.all(res.rms_px < 0.01))
    (True, True)
    """
    params = params or BrimSolveParameters()
    model = np.asarray(brim_model, dtype=np.float64).reshape(-1, 3)
    C, B = intr.n_cameras, len(model)
    names = list(intr.names)
    dets = _as_detections(detections_per_camera, C)
    if B < 4:
        return _fail(C, B, f"Solve Calibration Brim: the brim model has {B} dots, at least "
                           "4 are needed")
    empty = [names[c] for c in range(C) if len(dets[c]) == 0]
    if empty:
        return _fail(C, B, "Solve Calibration Brim: no detections in camera(s) "
                           f"{', '.join(empty)} (run Detect Blobs first)")
    fixed = np.full((B, C), -1, dtype=np.intp)
    for c in range(C):
        pairs = list(correspondences.get(c, ()))
        if len(pairs) < params.min_correspondences:
            return _fail(C, B, f"Solve Calibration Brim: camera {names[c]} has {len(pairs)} "
                               f"brim correspondence(s), at least "
                               f"{params.min_correspondences} are needed")
        for b, k in pairs:
            b, k = int(b), int(k)
            if not (0 <= b < B):
                return _fail(C, B, f"Solve Calibration Brim: brim dot {b} does not exist "
                                   f"(the model has {B})")
            if not (0 <= k < len(dets[c])):
                return _fail(C, B, f"Solve Calibration Brim: camera {names[c]} has no "
                                   f"detection {k}")
            if fixed[b, c] >= 0 and fixed[b, c] != k:
                return _fail(C, B, f"Solve Calibration Brim: brim dot {b} is matched twice "
                                   f"in camera {names[c]}")
            fixed[b, c] = k
        used = fixed[:, c][fixed[:, c] >= 0]
        if len(np.unique(used)) != len(used):
            return _fail(C, B, f"Solve Calibration Brim: one detection of camera {names[c]} "
                               "is matched to two brim dots")
    dets_n = [_normalised(dets[c], intr, c) for c in range(C)]
    R = np.zeros((C, 3, 3))
    t = np.zeros((C, 3))
    if initial is not None:
        R[:] = np.asarray(initial[0], dtype=np.float64).reshape(C, 3, 3)
        t[:] = np.asarray(initial[1], dtype=np.float64).reshape(C, 3)
    else:
        for c in range(C):
            sel = np.flatnonzero(fixed[:, c] >= 0)
            obj, img = model[sel], dets_n[c][fixed[sel, c]]
            spread = np.linalg.svd(obj - obj.mean(0), compute_uv=False)
            if spread[1] < 1e-3 * max(spread[0], 1e-12):
                return _fail(C, B, f"Solve Calibration Brim: the brim dots matched in camera "
                                   f"{names[c]} are collinear; pick dots spread over the brim")
            best = None
            for Rc, tc in _pnp_candidates(obj, img):
                Rr, tr, rms = refine_poses(obj, img[None], Rc[None], tc[None],
                                           scale=intr.focal[c:c + 1], iterations=5)
                if not np.isfinite(rms[0]):
                    continue
                depth_ok = np.all((obj @ Rr[0].T + tr[0])[:, 2] > 0)
                # score: dots of the whole model that find a detection, then hand-match fit
                uv = _project_one(model, Rr[0], tr[0], intr, c)
                m = match_by_projection(uv, dets[c], max_distance=params.match_distance_px,
                                        ambiguity_ratio=params.ambiguity_ratio)
                score = (bool(depth_ok), int((m >= 0).sum()), -float(rms[0]))
                if best is None or score > best[0]:
                    best = (score, Rr[0], tr[0])
            if best is None or not best[0][0]:
                return _fail(C, B, f"Solve Calibration Brim: no camera pose of {names[c]} "
                                   "fits its brim correspondences")
            if -best[0][2] > 5.0 * params.max_rms_px:
                return _fail(C, B, f"Solve Calibration Brim: the brim correspondences of "
                                   f"camera {names[c]} do not fit one pose (RMS "
                                   f"{-best[0][2]:.1f} px); check the matches")
            R[c], t[c] = best[1], best[2]
    R, t, matches, rms = _match_and_refine(model, dets, dets_n, R, t, intr, params,
                                           np.ones(C, dtype=bool), fixed)
    if params.use_face_points:
        joint = _bundle_with_face(model, dets, dets_n, R, t, intr, matches, params)
        if joint is not None:
            R, t, rms = joint
    return _result(model, R, t, matches, rms, params, "Solve Calibration Brim [Manual]", names)


# ------------------------------------------------------------------------------------------
# Automatic solve
# ------------------------------------------------------------------------------------------
def _fundamental(Ra: NDArray, ta: NDArray, Rb: NDArray, tb: NDArray) -> NDArray[np.float64]:
    """Essential matrix E with ``xb^T E xa = 0`` in normalised coordinates."""
    Rr = Rb @ Ra.T
    tr = tb - Rr @ ta
    return cross_matrix(tr) @ Rr


def symmetric_epipolar_distance(xa: NDArray, xb: NDArray, E: NDArray, fa: float, fb: float
                                ) -> NDArray[np.float64]:
    """Symmetric epipolar distance [Na, Nb] (px) between normalised points of two cameras.

    The mean of the distance of ``xb`` to the epipolar line of ``xa`` and the reverse,
    each converted to pixels with its camera's focal length.
    """
    ha = np.concatenate([xa, np.ones((len(xa), 1))], 1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], 1)
    la = ha @ E.T  # lines in b: l = E xa   (Na, 3)
    lb = hb @ E    # lines in a: l = E^T xb (Nb, 3)
    num = np.abs(hb @ la.T).T  # (Na, Nb) |xb^T E xa|
    da = num / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-15)[:, None] * fb
    db = num / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-15)[None, :] * fa
    return 0.5 * (da + db)


def _midpoints(ca: NDArray, da: NDArray, cb: NDArray, db: NDArray) -> NDArray[np.float64]:
    """Midpoints of the closest approach of ray pairs (N, 3)."""
    w = ca - cb
    a = np.einsum("ni,ni->n", da, da)
    b = np.einsum("ni,ni->n", da, db)
    c = np.einsum("ni,ni->n", db, db)
    d = np.einsum("ni,ni->n", da, w)
    e = np.einsum("ni,ni->n", db, w)
    den = np.maximum(a * c - b * b, 1e-12)
    s = (b * e - c * d) / den
    u = (a * e - b * d) / den
    return 0.5 * (ca + s[:, None] * da + cb + u[:, None] * db)


def _rays(xn: NDArray, R: NDArray, t: NDArray) -> tuple[NDArray, NDArray]:
    d = np.concatenate([xn, np.ones((len(xn), 1))], 1) @ R  # R^T d_cam, row-wise
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(camera_centres(R, t), d.shape), d


def multiview_tracks(
    dets_n: Sequence[NDArray],
    R: NDArray,
    t: NDArray,
    focal: NDArray,
    max_px: float,
    *,
    min_views: int = 3,
    excluded: Sequence[NDArray] | None = None,
    max_range: float = 600.0,
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Detections of the same marker in several cameras, under known camera geometry.

    Every camera pair proposes the detection pairs within ``max_px`` of each other's
    epipolar line; each proposal is triangulated (ray midpoint) and projected into the
    other cameras, where it takes the nearest detection within ``max_px``. Proposals seen
    in at least ``min_views`` cameras are accepted greedily, most views and smallest
    error first, never reusing a detection, so every detection belongs to one track.

    Parameters
    ----------
    dets_n : sequence of ndarray (N_c, 2)
        Normalised detection coordinates per camera.
    R, t : ndarray, shapes (C, 3, 3), (C, 3)
    focal : ndarray, shape (C,)
        Pixels per normalised unit, to express ``max_px``.
    max_px : float
        Epipolar and reprojection tolerance (px).
    min_views : int
        Fewest cameras per track (3 makes chance matches very unlikely).
    excluded : sequence of bool arrays (N_c,), optional
        Detections that may not be used.
    max_range : float
        Points further than this (mm) from either camera of the pair are rejected: on a
        head-mounted rig everything is within reach, while nearly parallel rays of
        unrelated detections "meet" far away and can fit every view.

    Returns
    -------
    tracks : ndarray of int, shape (N, C)
        Detection index per camera, -1 where the marker was not found.
    points : ndarray, shape (N, 3)
        Midpoint triangulation of each track's first pair (mm).
    """
    C = len(dets_n)
    usable = [np.ones(len(d), dtype=bool) if excluded is None else ~np.asarray(excluded[c], bool)
              for c, d in enumerate(dets_n)]
    props_idx, props_X, props_err = [], [], []
    for a in range(C):
        for b in range(a + 1, C):
            if not usable[a].any() or not usable[b].any():
                continue
            E = _fundamental(R[a], t[a], R[b], t[b])
            dist = symmetric_epipolar_distance(dets_n[a], dets_n[b], E, focal[a], focal[b])
            dist[~usable[a]] = np.inf
            dist[:, ~usable[b]] = np.inf
            ia, ib = np.nonzero(dist < max_px)
            if ia.size == 0:
                continue
            ca, da = _rays(dets_n[a][ia], R[a], t[a])
            cb, db = _rays(dets_n[b][ib], R[b], t[b])
            X = _midpoints(ca, da, cb, db)
            sa, sb = ((X - ca) * da).sum(1), ((X - cb) * db).sum(1)
            ok = (sa > 0) & (sb > 0) & (sa < max_range) & (sb < max_range)
            idx = np.full((len(X), C), -1, dtype=np.intp)
            idx[:, a], idx[:, b] = ia, ib
            err = dist[ia, ib].copy()
            for c in range(C):
                if c in (a, b) or not usable[c].any():
                    continue
                p = X @ R[c].T + t[c]
                front = p[:, 2] > 0
                proj = p[:, :2] / np.where(front, p[:, 2], 1.0)[:, None]
                dd = np.linalg.norm(proj[:, None, :] - dets_n[c][None], axis=-1) * focal[c]
                dd[:, ~usable[c]] = np.inf
                k = np.argmin(dd, axis=1)
                dk = dd[np.arange(len(X)), k]
                hit = front & (dk < max_px)
                idx[hit, c] = k[hit]
                err = err + np.where(hit, dk, 0.0)
            n = (idx >= 0).sum(1)
            keep = ok & (n >= min_views)
            props_idx.append(idx[keep])
            props_X.append(X[keep])
            props_err.append(err[keep] / n[keep])
    if not props_idx or sum(len(p) for p in props_idx) == 0:
        return np.zeros((0, C), dtype=np.intp), np.zeros((0, 3))
    idx = np.concatenate(props_idx)
    X = np.concatenate(props_X)
    err = np.concatenate(props_err)
    order = np.lexsort((err, -(idx >= 0).sum(1)))
    used = [np.zeros(len(d), dtype=bool) for d in dets_n]
    tracks, pts = [], []
    for i in order:
        row = idx[i]
        cams = np.flatnonzero(row >= 0)
        if any(used[c][row[c]] for c in cams):
            continue
        for c in cams:
            used[c][row[c]] = True
        tracks.append(row)
        pts.append(X[i])
    return np.array(tracks, dtype=np.intp).reshape(-1, C), np.array(pts).reshape(-1, 3)


def triangulate_tracks(
    tracks: NDArray, dets_n: Sequence[NDArray], R: NDArray, t: NDArray, focal: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares ray intersection of tracks, vectorised.

    Parameters
    ----------
    tracks : ndarray of int, shape (N, C)
        Detection index per camera (-1 = not seen).
    dets_n : sequence of ndarray (N_c, 2)
        Normalised detection coordinates.
    R, t : ndarray, shapes (C, 3, 3), (C, 3)
    focal : ndarray, shape (C,)

    Returns
    -------
    X : ndarray, shape (N, 3)
        Points (NaN for fewer than 2 views).
    residual : ndarray, shape (N,)
        RMS distance of the point to its rays (mm).
    reproj : ndarray, shape (N,)
        RMS reprojection error (px).
    """
    N, C = tracks.shape
    centres = -np.einsum("cji,cj->ci", R, t)
    A = np.zeros((N, 3, 3))
    b = np.zeros((N, 3))
    xn = np.full((N, C, 2), np.nan)
    for c in range(C):
        m = tracks[:, c] >= 0
        if not m.any():
            continue
        xn[m, c] = dets_n[c][tracks[m, c]]
        _, d = _rays(xn[m, c], R[c], t[c])
        P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
        A[m] += P
        b[m] += P @ centres[c]
    n = (tracks >= 0).sum(1)
    ok = n >= 2
    X = np.full((N, 3), np.nan)
    if ok.any():
        X[ok] = np.linalg.solve(A[ok] + 1e-12 * np.eye(3), b[ok][..., None])[..., 0]
    res = np.full(N, np.nan)
    rep = np.full(N, np.nan)
    d2 = np.zeros(N)
    e2 = np.zeros(N)
    for c in range(C):
        m = (tracks[:, c] >= 0) & ok
        if not m.any():
            continue
        _, d = _rays(xn[m, c], R[c], t[c])
        v = X[m] - centres[c]
        perp = v - (v * d).sum(1, keepdims=True) * d
        d2[m] += (perp**2).sum(1)
        p = X[m] @ R[c].T + t[c]
        proj = p[:, :2] / p[:, 2:3]
        e2[m] += (((proj - xn[m, c]) * focal[c]) ** 2).sum(1)
    res[ok] = np.sqrt(d2[ok] / n[ok])
    rep[ok] = np.sqrt(e2[ok] / n[ok])
    return X, res, rep


def _kabsch(A: NDArray, B: NDArray) -> tuple[NDArray, NDArray]:
    """Rotation and translation with ``B ~ A @ R.T + t`` (least squares), batched."""
    ca = A.mean(-2, keepdims=True)
    cb = B.mean(-2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb[..., 0, :] - np.einsum("...ij,...j->...i", R, ca[..., 0, :])
    return R, t


def register_model(
    model: NDArray, cloud: NDArray, *, tolerance: float, samples: int, seed: int,
    keep: int = 5,
) -> list[tuple[int, NDArray, NDArray]]:
    """Rigid registrations of a model to a cloud with unknown correspondences.

    Returns up to ``keep`` distinct hypotheses ``(inliers, R, t)`` with
    ``cloud ~ model @ R.T + t``, best first.
    """
    B, N = len(model), len(cloud)
    if B < 3 or N < 3:
        return []
    rng = np.random.default_rng(seed)
    Dm = np.linalg.norm(model[:, None] - model[None], axis=-1)
    Dq = np.linalg.norm(cloud[:, None] - cloud[None], axis=-1)
    hyps: list[tuple[int, float, NDArray, NDArray]] = []
    tol = tolerance
    tree = cKDTree(cloud)
    for n_sample in range(int(samples)):
        # enough tries once most of the brim is explained
        if n_sample >= 60 and hyps and max(h[0] for h in hyps) >= 0.6 * min(B, N):
            break
        i, j, k = rng.choice(B, 3, replace=False)
        # wide, non-degenerate triangles pin the pose best
        if min(Dm[i, j], Dm[i, k], Dm[j, k]) < 10.0:
            continue
        P, Q = np.nonzero(np.abs(Dq - Dm[i, j]) < tol)
        if P.size == 0:
            continue
        okr = (np.abs(Dq[P][:, :] - Dm[i, k]) < tol) & (np.abs(Dq[Q][:, :] - Dm[j, k]) < tol)
        pi, r = np.nonzero(okr)
        if pi.size == 0:
            continue
        tri_q = np.stack([cloud[P[pi]], cloud[Q[pi]], cloud[r]], 1)  # (H, 3, 3)
        tri_m = np.broadcast_to(model[[i, j, k]], tri_q.shape)
        Rh, th = _kabsch(tri_m, tri_q)
        moved = np.einsum("hij,bj->hbi", Rh, model) + th[:, None, :]
        dist, _ = tree.query(moved.reshape(-1, 3), distance_upper_bound=tol)
        inl = (dist < tol).reshape(moved.shape[:2])
        n_in = inl.sum(1)
        best = int(np.argmax(n_in))
        if n_in[best] < 4:
            continue
        # refit on the inliers of the best hypothesis of this sample
        m = inl[best]
        _, nn = tree.query(moved[best][m])
        R2, t2 = _kabsch(model[m], cloud[nn])
        d2, _ = tree.query(model @ R2.T + t2)
        n2 = int((d2 < tol).sum())
        rms = float(np.sqrt(np.mean(d2[d2 < tol] ** 2))) if n2 else np.inf
        hyps.append((n2, rms, R2, t2))
    hyps.sort(key=lambda h: (-h[0], h[1]))
    out: list[tuple[int, NDArray, NDArray]] = []
    for n, _, Rh, th in hyps:
        if any(np.abs(Rh - R0).max() < 1e-3 and np.abs(th - t0).max() < 0.5
               for _, R0, t0 in out):
            continue
        out.append((n, Rh, th))
        if len(out) >= keep:
            break
    return out


def solve_brim_auto(
    detections_per_camera: Sequence[ArrayLike],
    brim_model: ArrayLike,
    intr: CameraIntrinsics,
    rig_R: ArrayLike,
    rig_t: ArrayLike,
    *,
    params: BrimSolveParameters | None = None,
) -> BrimSolveResult:
    """Solve the cameras from the brim with no hand matches, given the rig geometry.

    Parameters
    ----------
    detections_per_camera : sequence of array_like, each shape (N_c, 2)
        Detection centres of one frame (raw px), face markers included.
    brim_model : array_like, shape (B, 3)
        Brim dot positions (mm).
    intr : CameraIntrinsics
    rig_R : array_like, shape (C, 3, 3)
        Rotations of the rig in any world frame (from an XCP calibration): only the
        cameras' relative geometry is used.
    rig_t : array_like, shape (C, 3)
        Translations of the rig (mm).
    params : BrimSolveParameters, optional

    Returns
    -------
    BrimSolveResult
        Cameras in the brim frame; ``success`` False with a reason when the brim could
        not be found.
    """
    params = params or BrimSolveParameters()
    model = np.asarray(brim_model, dtype=np.float64).reshape(-1, 3)
    C, B = intr.n_cameras, len(model)
    names = list(intr.names)
    dets = _as_detections(detections_per_camera, C)
    rig_R = np.asarray(rig_R, dtype=np.float64).reshape(C, 3, 3)
    rig_t = np.asarray(rig_t, dtype=np.float64).reshape(C, 3)
    what = "Solve Calibration Brim [Automatic]"
    if B < 4:
        return _fail(C, B, f"{what}: the brim model has {B} dots, at least 4 are needed")
    empty = [names[c] for c in range(C) if len(dets[c]) == 0]
    if empty:
        return _fail(C, B, f"{what}: no detections in camera(s) {', '.join(empty)} "
                           "(run Detect Blobs first)")
    if C < 3:
        return _fail(C, B, f"{what}: needs at least 3 cameras, the take has {C}")
    dets_n = [_normalised(dets[c], intr, c) for c in range(C)]
    _, cloud = multiview_tracks(dets_n, rig_R, rig_t, intr.focal, params.epipolar_distance_px)
    if len(cloud) < 4:
        return _fail(C, B, f"{what}: only {len(cloud)} detections could be triangulated "
                           "with the rig calibration; is it the right XCP?")
    hyps = register_model(model, cloud, tolerance=params.registration_tolerance_mm,
                          samples=params.ransac_samples, seed=params.seed)
    if not hyps:
        return _fail(C, B, f"{what}: the brim model was not found among the "
                           f"{len(cloud)} triangulated detections")
    best: tuple | None = None
    for _n_in, Rw, tw in hyps:
        # rig world -> brim frame: X_b = Rw^T (X_w - tw)
        R = rig_R @ Rw
        t = rig_t + np.einsum("cij,j->ci", rig_R, tw)
        R2, t2, matches, rms = _match_and_refine(model, dets, dets_n, R.copy(), t.copy(),
                                                 intr, params, np.ones(C, dtype=bool))
        n = int((matches >= 0).sum())
        score = (n, -float(np.nanmean(rms)) if np.isfinite(rms).any() else -np.inf)
        if best is None or score > best[0]:
            best = (score, R2, t2, matches, rms)
    assert best is not None
    _, R, t, matches, rms = best
    if params.use_face_points:
        joint = _bundle_with_face(model, dets, dets_n, R, t, intr, matches, params)
        if joint is not None:
            R, t, rms = joint
    return _result(model, R, t, matches, rms, params, what, names)


# ------------------------------------------------------------------------------------------
# Per-frame re-solve
# ------------------------------------------------------------------------------------------
def resolve_frame_cameras(
    brim_model: ArrayLike,
    intr: CameraIntrinsics,
    R_prev: ArrayLike,
    t_prev: ArrayLike,
    *,
    brim_obs: ArrayLike | None = None,
    detections: Sequence[ArrayLike] | None = None,
    max_distance_px: float = 15.0,
    min_matches: int = 4,
    iterations: int = 5,
) -> FrameCameras:
    """Re-solve the cameras of one frame from the brim, starting at the previous frame.

    Parameters
    ----------
    brim_model : array_like, shape (B, 3)
        Brim dot positions (mm).
    intr : CameraIntrinsics
    R_prev, t_prev : array_like, shapes (C, 3, 3), (C, 3)
        Cameras of the previous frame (the starting point).
    brim_obs : array_like, shape (B, C, 2), optional
        Raw pixel observations of the brim dots in this frame (NaN where missing).
    detections : sequence of array_like (N_c, 2), optional
        Used when ``brim_obs`` is None: the dots are matched to these detections by
        projection with the previous cameras (mutual nearest within ``max_distance_px``).
    max_distance_px : float
        Search radius of the matching (the Brim Point Tracking Distance).
    min_matches : int
        Cameras with fewer brim observations keep their previous pose (rms NaN).
    iterations : int
        Gauss-Newton steps.

    Returns
    -------
    FrameCameras
        ``(R, t, rms_px)``.
    """
    model = np.asarray(brim_model, dtype=np.float64).reshape(-1, 3)
    C, B = intr.n_cameras, len(model)
    R_prev = np.asarray(R_prev, dtype=np.float64).reshape(C, 3, 3)
    t_prev = np.asarray(t_prev, dtype=np.float64).reshape(C, 3)
    if brim_obs is None:
        if detections is None:
            raise ValueError("resolve_frame_cameras needs brim_obs or detections")
        dets = _as_detections(detections, C)
        uv, _ = project(model, R_prev, t_prev, intr)
        obs = np.full((B, C, 2), np.nan)
        for c in range(C):
            m = match_by_projection(uv[:, c], dets[c], max_distance=max_distance_px)
            obs[m >= 0, c] = dets[c][m[m >= 0]]
    else:
        obs = np.asarray(brim_obs, dtype=np.float64).reshape(B, C, 2)
    xn = pixels_to_normalised(obs, intr)  # (B, C, 2), NaN passes through
    xn = np.swapaxes(xn, 0, 1)
    enough = np.isfinite(xn).all(-1).sum(1) >= max(int(min_matches), 3)
    xn[~enough] = np.nan
    R, t, rms = refine_poses(model, xn, R_prev, t_prev, scale=intr.focal,
                             iterations=iterations)
    R[~enough], t[~enough] = R_prev[~enough], t_prev[~enough]
    rms[~enough] = np.nan
    return FrameCameras(R, t, rms)


# ------------------------------------------------------------------------------------------
# Brim regions of the images
# ------------------------------------------------------------------------------------------
def brim_exclusion_mask(
    detections_per_camera: Sequence[ArrayLike],
    brim_model: ArrayLike,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    *,
    radius_px: float | None = None,
) -> list[NDArray[np.bool_]]:
    """Detections lying in the image region of the brim (for Initialize 3D to skip).

    A detection is in the brim region when it is within ``radius_px`` of a projected
    brim dot: that catches the dots left unmatched by the brim solve without eating the
    forehead markers that appear just below the brim in the images.

    Parameters
    ----------
    detections_per_camera : sequence of array_like (N_c, 2)
    brim_model : array_like, shape (B, 3)
    R, t : array_like, shapes (C, 3, 3), (C, 3)
    intr : CameraIntrinsics
    radius_px : float, optional
        Margin (px); default 0.4 x the median spacing of neighbouring projected dots.

    Returns
    -------
    list of ndarray of bool, one (N_c,) per camera
    """
    model = np.asarray(brim_model, dtype=np.float64).reshape(-1, 3)
    C = intr.n_cameras
    dets = _as_detections(detections_per_camera, C)
    uv, _ = project(model, np.asarray(R, float), np.asarray(t, float), intr)
    out = []
    for c in range(C):
        d = dets[c]
        p = uv[:, c]
        p = p[np.isfinite(p).all(1)]
        if len(d) == 0 or len(p) == 0:
            out.append(np.zeros(len(d), dtype=bool))
            continue
        if radius_px is None:
            dd = np.linalg.norm(p[:, None] - p[None], axis=-1)
            np.fill_diagonal(dd, np.inf)
            r = 0.4 * float(np.median(dd.min(1))) if len(p) > 1 else 8.0
        else:
            r = float(radius_px)
        out.append(np.linalg.norm(d[:, None] - p[None], axis=-1).min(1) < r)
    return out


def rotation_error_deg(Ra: ArrayLike, Rb: ArrayLike) -> NDArray[np.float64]:
    """Angle (deg) of ``Ra Rb^T`` for rotation stacks ``(..., 3, 3)``."""
    Ra = np.asarray(Ra, dtype=np.float64)
    Rb = np.asarray(Rb, dtype=np.float64)
    rv = matrix_to_rodrigues(Ra @ np.swapaxes(Rb, -1, -2))
    return np.degrees(np.linalg.norm(rv, axis=-1))
