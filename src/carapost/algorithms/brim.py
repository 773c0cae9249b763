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

Pose refinement and PnP live in :mod:`carapost.algorithms.pose`, the multi-view geometry
(epipolar matching, ray triangulation) in :mod:`carapost.algorithms.multiview`, and the
RANSAC registration of the model in :mod:`carapost.algorithms.rigid`.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics, matrix_to_rodrigues, project
from carapost.algorithms.multiview import (
    multiview_tracks,
    normalised_coordinates,
    triangulate_tracks,
)
from carapost.algorithms.params import param, validate
from carapost.algorithms.pose import pnp_candidates, refine_poses
from carapost.algorithms.rigid import register_model

log = logging.getLogger("carapost.brim")

__all__ = [
    "BrimSolveParameters",
    "BrimSolveResult",
    "brim_exclusion_mask",
    "match_by_projection",
    "solve_brim_auto",
    "solve_brim_manual",
    "rotation_error_deg",
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
        R_new, t_new, rms_new, _ = refine_poses(model, xn, R, t, scale=intr.focal,
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
        R_new, t_new, rms_new, _ = refine_poses(model, xn, R, t, scale=intr.focal,
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


def _bundle_with_face(model: NDArray, dets: list[NDArray], dets_n: list[NDArray],
                      R: NDArray, t: NDArray, intr: CameraIntrinsics, matches: NDArray,
                      params: BrimSolveParameters) -> tuple[NDArray, NDArray, NDArray] | None:
    """Refine all cameras on the brim (fixed) plus face markers seen by >= 3 cameras."""
    from carapost.algorithms.bundle import BUNDLE_OPTIONS, bundle_frame

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
                       f_scale=1.0, max_nfev=50, **BUNDLE_OPTIONS)
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
                           loss="huber", f_scale=1.0, max_nfev=50, **BUNDLE_OPTIONS)
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
    dets_n = [normalised_coordinates(dets[c], intr, c) for c in range(C)]
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
            for Rc, tc in pnp_candidates(obj, img):
                Rr, tr, rms, _ = refine_poses(obj, img[None], Rc[None], tc[None],
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
    dets_n = [normalised_coordinates(dets[c], intr, c) for c in range(C)]
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
