"""Tracking a whole take in two passes: :func:`track_take`, and the spawner.

Forwards from the start frame to the end, then backwards from the start frame with the
points found on the way, then identity repair (:mod:`carapost.algorithms.tracking.identity`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.blob_noise import blob_noise_scale
from carapost.algorithms.brim_discs import unbias_brim_cameras
from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.codes import (
    KIND_BRIM,
    KIND_FACE,
    POINT_FILLS,
    RECON_NONE,
    RECON_TRIANGULATED,
    blank_point_array,
)
from carapost.algorithms.depth_prior import sample_covariance, smooth_along_uncertainty
from carapost.algorithms.neighbour_prior import deformation_sigma, fuse, patch_prediction
from carapost.algorithms.pose_smoothing import smoothing_variance_factor
from carapost.algorithms.single_sensor import neighbours
from carapost.algorithms.tracking.identity import (
    absorb,
    drop_isolated,
    remove_hops,
    split_hops,
    stitch,
)
from carapost.algorithms.tracking.params import TrackingParameters
from carapost.algorithms.tracking.records import (
    FrameDetections,
    InitialState,
    RaggedDetections,
    TrackResult,
)
from carapost.algorithms.tracking.sequence import Spawner, track
from carapost.algorithms.tracking.time_checks import (
    PAIR_TARGET_FACTOR,
    detach_observations,
    place_single_sensor,
    reject_by_motion,
    reject_inconsistent_pairs,
    reject_merged_blobs,
    reject_unanchored_single_sensor,
    reject_wrong_samples,
)
from carapost.algorithms.triangulation import TriangulationParameters, triangulate
from carapost.algorithms.uncertainty import (
    brim_pose_covariance,
    noise_from_residuals,
    point_noise_factor,
    retriangulate,
    sample_sigma,
    smooth_camera_poses,
    width_noise_scale,
)


def make_spawner(
    intr: CameraIntrinsics,
    caddies: Sequence[tuple[int, int]],
    init_params: Any = None,
    *,
    brim_model: ArrayLike | None = None,
    size_ratio: float = 2.0,
    min_views: int = 2,
) -> Spawner:
    """A :data:`Spawner` that runs Initialize 3D on the detections no point uses.

    The points tracked in the frame with two or more cameras are the seeds (so growth
    starts from them and nothing is created twice); detections used by other points, and
    with ``brim_model`` those in the brim's image region, are left out.

    Parameters
    ----------
    intr : CameraIntrinsics
    caddies : sequence of (int, int)
        Camera pairs of one caddy, as for `initialize_3d` (`carapost.model.rig.caddies`
        derives them from the take).
    init_params : Init3DParameters, optional
        Initialize 3D parameters (the final bundle adjustment is always off here).
    brim_model : array_like, shape (B, 3), optional
        Brim structure (mm): detections around its projection are never face markers.
    size_ratio : float
        A found marker's blobs must be within this factor of the median blob size of the
        tracked markers in the same camera (nostrils, eyes and the like are bigger).
    min_views : int
        Fewest cameras a found marker must be seen by.

    Returns
    -------
    Spawner
    """
    from dataclasses import replace

    from carapost.algorithms.brim import brim_exclusion_mask
    from carapost.algorithms.init3d import Init3DParameters, initialize_3d

    C = intr.n_cameras
    cad = tuple(caddies)
    ip = replace(init_params or Init3DParameters(), bundle_adjust=False)
    bm = None if brim_model is None else np.asarray(brim_model, np.float64).reshape(-1, 3)
    empty = (np.zeros((0, 3)), np.zeros((0, C), np.intp))

    def spawn(frame: int, dets: FrameDetections, used: NDArray[np.bool_],
              positions: NDArray[np.float64], detection: NDArray[np.intp],
              R: NDArray[np.float64], t: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        cen = [np.asarray(d[0], np.float64).reshape(-1, 2) for d in dets]
        seed = np.isfinite(positions).all(-1) & ((detection >= 0).sum(1) >= 2)
        seeds = detection[seed]
        exclude = []
        for c in range(C):
            m = np.zeros(len(cen[c]), bool)
            u = used[c, :len(cen[c])]
            m[: u.size] = u
            s = seeds[:, c]
            m[s[s >= 0]] = False
            exclude.append(m)
        if bm is not None:
            region = brim_exclusion_mask(cen, bm, R, t, intr)
            exclude = [e | r for e, r in zip(exclude, region, strict=True)]
        free = sum(int((~e).sum()) for e in exclude) - int((seeds >= 0).sum())
        if free < min_views:
            return empty
        try:
            res = initialize_3d(cen, R, t, intr, caddies=cad,
                                seeds=[list(r) for r in seeds] or None,
                                exclude_mask=exclude, params=ip)
        except ValueError:
            return empty
        if not res.success or len(res.points) <= res.n_seeds:
            return empty
        X = res.points[res.n_seeds:]
        dn = res.detections[res.n_seeds:]
        ok = np.isfinite(X).all(-1) & ((dn >= 0).sum(1) >= min_views)
        if size_ratio > 0:
            for c in range(C):
                ax = dets[c][1]
                if ax is None or not len(seeds):
                    continue
                ax = np.asarray(ax, np.float64).reshape(-1, 2)
                s = seeds[:, c][seeds[:, c] >= 0]
                if s.size < 3:
                    continue
                ref = float(np.median(ax[s].max(1)))
                has = dn[:, c] >= 0
                a = ax[np.maximum(dn[:, c], 0)].max(1)
                ok &= ~has | ((a <= size_ratio * ref) & (a >= ref / size_ratio))
        return X[ok], dn[ok]

    return spawn


def track_take(
    detections: Callable[[int], FrameDetections],
    initial: InitialState,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    params: TrackingParameters | None = None,
    *,
    start: int,
    n_frames: int,
    spawn: Spawner | None = None,
    spawn_interval: int = 1,
    resolve_cameras: bool = True,
    progress: Callable[[int, int], bool] | None = None,
    min_frames: int = 10,
    merge_mm: float = 1.0,
    get_image: Callable[[int, int], NDArray[Any]] | None = None,
) -> TrackResult:
    """Track a whole take from one initialised frame, finding missed markers on the way.

    1. From ``start`` to the last frame (to frame 0 when ``start`` is the last frame),
       with ``spawn`` finding markers no point has yet (and reviving lost points).
    2. Over the whole take the other way, with every point, guided by the first pass: a
       point restarts wherever the first pass had it, so each marker is tracked back
       from where it was found to where it first appears.
    3. Join: the first pass where it has a point, else the second one. Then every point
       is split where it hops to another marker relative to its neighbours' motion
       (:func:`hop_segments`; the pieces become points of their own), found points that
       double an earlier one (median distance below ``merge_mm``) are merged into it,
       pieces of one marker that never coexist are joined when the joined track has no
       hop, what still hops is cleared, and found points triangulated in fewer than
       ``min_frames`` frames are dropped.

    Parameters
    ----------
    detections, initial, R, t, intr, params, spawn, spawn_interval, resolve_cameras
        As for :func:`track`.
    get_image : callable, optional
        ``get_image(frame, camera)`` -> grey image: patch tracking in both passes.
    start : int
        Frame holding ``initial``.
    n_frames : int
        Frames in the take.
    progress : callable, optional
        ``progress(done, total)`` over both passes; False cancels (``cancelled`` set).
    min_frames : int
    merge_mm : float

    Returns
    -------
    TrackResult
        Arrays for every frame ``0..n_frames - 1`` (``first`` 0, ``last`` n_frames - 1);
        the ``start`` row of the initial points holds ``initial``.
    """
    params = TrackingParameters() if params is None else params
    F = int(n_frames)
    if not 0 <= start < F:
        raise ValueError(f"start frame {start} is outside the take (0-{F - 1})")
    P = np.asarray(initial.positions).shape[0]
    kind0 = np.asarray(initial.kind, np.int8)
    C = intr.n_cameras
    L = F - 1
    end1, end2 = (L, 0) if start < L else (0, L)
    total = abs(end1 - start) + L

    def prog(offset: int) -> Callable[[int, int], bool] | None:
        if progress is None:
            return None
        return lambda d, n: progress(offset + d, total)

    def empty(p: int) -> dict[str, NDArray[Any]]:
        return {k: blank_point_array(k, F, p, C) for k in POINT_FILLS}

    Rall = np.zeros((F, C, 3, 3))
    tall = np.zeros((F, C, 3))
    R0 = np.asarray(R, np.float64)
    t0 = np.asarray(t, np.float64)
    Rs, ts = (R0[start], t0[start]) if R0.ndim == 4 else (R0, t0)
    Rall[start], tall[start] = Rs, ts
    # ---- first pass: forwards to the end (backwards when starting at the last frame) ----
    P1 = P
    fwd = None
    cancelled = False
    done = 0
    if start != end1:
        fwd = track(detections, initial, R, t, intr, params, start=start, stop=end1,
                    resolve_cameras=resolve_cameras, progress=prog(0), spawn=spawn,
                    spawn_interval=spawn_interval, get_image=get_image)
        P1 = P + fwd.n_new
        cancelled = fwd.cancelled
        done += fwd.frames_done
    A = empty(P1)
    X_start = np.asarray(initial.positions, np.float64)
    A["positions"][start, :P] = X_start
    A["recon"][start, :P] = np.where(np.isfinite(X_start).all(-1), RECON_TRIANGULATED,
                                     RECON_NONE)
    if initial.obs is not None:
        A["obs"][start, :P] = initial.obs
    if fwd is not None and fwd.frames_done:
        sl = slice(fwd.first, fwd.last + 1)
        for k in POINT_FILLS:
            A[k][sl] = getattr(fwd, k)
        Rall[sl], tall[sl] = fwd.R, fwd.t
    kind1 = np.r_[kind0, np.full(P1 - P, KIND_FACE, np.int8)]
    step1 = 1 if end1 >= start else -1
    last = start if fwd is None else start + step1 * fwd.frames_done
    lo, hi = min(start, last), max(start, last)
    if cancelled or last == end2:
        return _take_result(A, Rall, tall, lo, hi, done, cancelled, kind1, P, min_frames,
                            merge_mm, intr, start, detections, (params.pose_smoothing_frames,
                                                  params.depth_smoothing_frames,
                                                  _outlier_target_px(params),
                                                  params.allow_single_sensor_tracking,
                                                  params.single_sensor_tracking_threshold),
                            brim_offsets=params.brim_dot_offsets)
    # ---- second pass over the whole take the other way, guided by the first -------------
    guide = np.where((A["recon"] == RECON_TRIANGULATED)[..., None],
                     A["positions"].astype(np.float64), np.nan)
    guide[:, kind1 == KIND_BRIM] = np.nan
    Xl = A["positions"][last].astype(np.float64)
    brim = kind1 == KIND_BRIM
    Xl[brim] = np.r_[X_start, np.full((P1 - P, 3), np.nan)][brim]
    init_b = InitialState(Xl, kind1, A["obs"][last].astype(np.float64))
    bwd = track(detections, init_b, Rall[last], tall[last], intr, params, start=last,
                stop=end2, resolve_cameras=resolve_cameras, progress=prog(abs(end1 - start)),
                spawn=spawn if 0 < start < L else None, spawn_interval=spawn_interval,
                guide=guide, get_image=get_image)
    done += bwd.frames_done
    P2 = P1 + bwd.n_new
    B = empty(P2)
    for k in POINT_FILLS:
        B[k][:, :P1] = A[k]
    if bwd.frames_done:
        sl = slice(bwd.first, bwd.last + 1)
        fr2 = np.arange(bwd.first, bwd.last + 1)
        # the second pass fills what the first did not have (and every frame beyond start)
        beyond = fr2 < start if end2 <= start else fr2 > start
        fill = (B["recon"][sl] == RECON_NONE)
        fill[:, :P1] |= beyond[:, None]
        fill[:, P1:] = True
        for k in POINT_FILLS:
            cur = B[k][sl]
            new = getattr(bwd, k)
            m = fill.reshape(fill.shape + (1,) * (cur.ndim - 2))
            B[k][sl] = np.where(m, new, cur)
        Rall[sl][beyond], tall[sl][beyond] = bwd.R[beyond], bwd.t[beyond]
        lo, hi = min(lo, bwd.first), max(hi, bwd.last)
    kind2 = np.r_[kind1, np.full(P2 - P1, KIND_FACE, np.int8)]
    return _take_result(B, Rall, tall, lo, hi, done, bwd.cancelled, kind2, P, min_frames,
                        merge_mm, intr, start, detections, (params.pose_smoothing_frames,
                                                  params.depth_smoothing_frames,
                                                  _outlier_target_px(params),
                                                  params.allow_single_sensor_tracking,
                                                  params.single_sensor_tracking_threshold),
                            brim_offsets=params.brim_dot_offsets)


def _take_result(A: dict[str, NDArray[Any]], R: NDArray, t: NDArray, first: int, last: int,
                 done: int, cancelled: bool, kind: NDArray[np.int8], P: int, min_frames: int,
                 merge_mm: float, intr: CameraIntrinsics, start: int,
                 detections: Callable[[int], FrameDetections],
                 windows: tuple[int, int, float, bool, float],
                 brim_offsets: bool = True) -> TrackResult:
    """Clean the joined passes and build the result.

    1. Split every point where it hops to another marker (:func:`hop_segments`): the
       pieces on another identity become points of their own.
    2. Merge found points (and pieces) into an earlier point they double (median distance
       below ``merge_mm`` where both exist), then join pieces of one marker that never
       coexist (:func:`stitch`).
    3. Clear what still hops, drop found points triangulated in fewer than ``min_frames``
       frames and found points far from every other point (:func:`drop_isolated`).
    4. Fit the cameras' poses over time (:func:`smooth_camera_poses`, the start frame's
       kept), triangulate the face samples again with them, estimate each
       triangulated sample's covariance (:func:`sample_covariance`) and apply the depth
       prior from time (:func:`smooth_along_uncertainty`); ``windows`` are the frames
       of the pose fit and of the depth prior, the target reprojection error (px) of
       the outlier rejection, whether single-sensor samples are allowed and the
       Single Sensor Tracking Threshold (mm). The sigma
       is that of the result, plus what no fit over time removes: each point's excess
       noise (its noise factor) and the cameras' pose error from the brim
       (:func:`sample_sigma`); the 2D noise of each observation scales with the width
       of its blob in ``detections`` (:func:`width_noise_scale`). Between the re-solve
       and the sigma, the checks of
       :mod:`carapost.algorithms.tracking.time_checks` run, and the depth prior from
       the neighbours (:mod:`carapost.algorithms.neighbour_prior`) follows the one
       from time. With ``brim_offsets`` the cameras are first solved again without
       the brim dots' image offsets (:mod:`carapost.algorithms.brim_discs`).
    """
    keep = np.ones(A["positions"].shape[1], bool)
    A, kind, keep = split_hops(A, kind, keep)
    _merge_doubles(A, kind, keep, P, merge_mm)
    stitch(A, kind, keep, P, merge_mm)
    remove_hops(A, kind, keep)
    tri = (A["recon"] == RECON_TRIANGULATED).sum(0)
    keep[P:] &= tri[P:] >= min_frames
    drop_isolated(A, kind, keep, P)
    sl = slice(first, last + 1)
    o = {k: v[sl][:, keep] for k, v in A.items()}
    widths, lengths, scores = attached_blobs(detections, o["detection"], first)
    Rs, ts, sigma = _refine_cameras(o, R[sl], t[sl], kind[keep], intr,
                                    np.arange(first, last + 1) == start, *windows,
                                    widths=widths, blob_scale=blob_noise_scale(lengths, scores),
                                    lengths=lengths, brim_offsets=brim_offsets)
    return TrackResult(o["positions"], o["recon"], o["residual"], o["obs"], o["source"],
                       o["detection"], o["quality"], Rs, ts, first=first, last=last,
                       frames_done=done, cancelled=cancelled, n_new=int(keep[P:].sum()),
                       sigma=sigma)


def attached_blobs(detections: Callable[[int], FrameDetections],
                   detection: NDArray[np.integer], first: int = 0
                   ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Semi-minor axis, semi-major axis (px) and score of the blob of every observation.

    Parameters
    ----------
    detections : callable
        Frame -> `FrameDetections` (a :class:`RaggedDetections` is read without copies).
        A callable with a ``scores`` attribute (frame -> per camera the blobs' scores)
        gives the scores too.
    detection : ndarray of int, shape (F, P, C)
        Index of each observation's blob in its image (-1 where none), frames from
        ``first``.
    first : int
        Take frame of ``detection[0]``.

    Returns
    -------
    minor, major, score : ndarray, shape (F, P, C), float32
        NaN where no blob is attached or the detections have no axes (no scores).
    """
    det = np.asarray(detection)
    F, P, C = det.shape
    axes = np.full(det.shape + (2,), np.nan, np.float32)
    score = np.full(det.shape, np.nan, np.float32)
    has = det >= 0
    if not has.any():
        return axes[..., 1], axes[..., 0], score
    if isinstance(detections, RaggedDetections):
        f, p, c = np.nonzero(has)
        rows = detections.offsets[(f + first) * C + c] + det[f, p, c]
        if detections.axes is not None:
            axes[f, p, c] = detections.axes[rows, :2]
        if detections.score is not None:
            score[f, p, c] = detections.score[rows]
        return axes[..., 1], axes[..., 0], score
    scores = getattr(detections, "scores", None)
    for f in np.flatnonzero(has.any((1, 2))):
        frame = detections(int(f + first))
        sc = None if scores is None else scores(int(f + first))
        for c in range(C):
            m = has[f, :, c]
            if not m.any():
                continue
            ax = frame[c][1]
            if ax is not None:
                axes[f, m, c] = np.asarray(ax, np.float64).reshape(-1, 2)[det[f, m, c]]
            if sc is not None and sc[c] is not None:
                score[f, m, c] = np.asarray(sc[c], np.float64)[det[f, m, c]]
    return axes[..., 1], axes[..., 0], score


def _brim_model(positions: NDArray) -> NDArray[np.float64]:
    """(B, 3) the brim dots' model positions from their samples (F, B, 3), which are the
    model wherever a dot is placed; NaN for a dot never placed."""
    X = positions.astype(np.float64)
    seen = np.isfinite(X).all(-1)
    first = np.argmax(seen, axis=0)
    out = X[first, np.arange(X.shape[1])]
    out[~seen.any(0)] = np.nan
    return out


def _outlier_target_px(params: TrackingParameters) -> float:
    """The per-frame tracker's target reprojection error (px, `FrameMatcher`)."""
    return max(0.5, params.max_2d_projection_error / 5.0)


def _resolve_rejecting(obs: NDArray, R: NDArray, t: NDArray, intr: CameraIntrinsics,
                       mask: NDArray[np.bool_], target_px: float
                       ) -> tuple[NDArray, NDArray, NDArray[np.bool_]]:
    """Triangulate the masked samples with outlier rejection (at most one camera
    dropped): positions, residuals (mm) and the cameras each solution used."""
    sel = np.where(mask[..., None, None], obs, np.nan)
    params = TriangulationParameters(minimum_cameras=2, use_outlier_rejection=True,
                                     maximum_cameras_to_drop=1,
                                     target_reprojection_error=target_px,
                                     refine_iterations=1)
    res = triangulate(sel, R, t, intr, params)
    return res.points, res.residual, res.contribution


def _refine_cameras(o: dict[str, NDArray[Any]], R: NDArray, t: NDArray,
                    kind: NDArray[np.int8], intr: CameraIntrinsics, fixed: NDArray[np.bool_],
                    window: int, depth_window: int = 0, target_px: float = 0.0,
                    single_sensor: bool = True, single_threshold_mm: float | None = None,
                    widths: NDArray[np.float32] | None = None,
                    blob_scale: NDArray[np.float64] | None = None,
                    lengths: NDArray[np.float32] | None = None,
                    brim_offsets: bool = True
                    ) -> tuple[NDArray, NDArray, NDArray[np.float32]]:
    """Smooth the cameras over time, re-solve the face samples with them (in ``o``, in
    place, the ``fixed`` frame left alone), apply the depth prior from time over
    ``depth_window`` frames and estimate each sample's sigma. First, with ``widths``,
    the face observations on merged blobs are removed
    (:func:`carapost.algorithms.tracking.time_checks.reject_merged_blobs`).

    With ``target_px`` > 0 (the per-frame tracker's target) the re-solve rejects
    outliers (one camera may be dropped from a sample seen by three or more, see
    :func:`carapost.algorithms.triangulation.triangulate`) with a target of 6 times the
    take's measured 2D noise, between 0.5 px and ``target_px``: an observation the
    solution leaves out (a wrong match) is removed from the sample. ``widths`` (F, P,
    C): the semi-minor axis of each observation's blob (:func:`attached_blobs`), which
    scales its 2D noise in the sigma; ``blob_scale`` (F, P, C) a further factor of that
    noise from the blob's score and length (:func:`blob_noise_scale`); ``lengths`` (F,
    P, C) the semi-major axes, with which the observations on blobs merged along their
    length are removed with those on wider ones and, with ``brim_offsets``, the brim
    dots' radii are estimated: before anything else every frame's cameras are then
    solved again from the brim dots' centroids less their offset from the dots' centres
    (a flat dot seen at an angle,
    :func:`carapost.algorithms.brim_discs.unbias_brim_cameras`)."""
    face = kind != KIND_BRIM
    brim_obs = o["obs"][:, ~face].astype(np.float64)
    pose_factor = np.ones(len(R))
    unbiased = False
    if widths is not None:
        # merged blobs first: their centres are pixels off in every camera alike, so
        # neither the outlier rejection nor the motion checks below see them
        reject_merged_blobs(o, widths, R, t, face, intr, fixed, single_sensor=single_sensor,
                            lengths=lengths)
    tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
    obs = o["obs"].astype(np.float64)
    if window >= 5 and len(R) >= 5 and tri.any():
        if brim_offsets and lengths is not None and (~face).any():
            # the face samples are solved again below, so the cameras may change here
            model = _brim_model(o["positions"][:, ~face])
            corr = unbias_brim_cameras(model, brim_obs, lengths[:, ~face], R, t, intr,
                                       keep=fixed)
            if corr is not None:
                R, t, brim_obs = corr.R, corr.t, corr.obs
                unbiased = True
                # what is left of the resections' error is white, and the fit over time
                # removes most of it (without the correction the dots' offsets, the same
                # in every frame, dominate and the fit removes nothing of them)
                pose_factor = np.where(fixed, 1.0, smoothing_variance_factor(window, len(R)))
        R, t = smooth_camera_poses(R, t, window, keep=fixed)
        redo = tri & ~fixed[:, None]
        target = 0.0
        if target_px > 0:
            # a wrong match stands out against the take's own centroid noise: the target
            # is 6 times it (at least 0.5 px, at most the per-frame tracker's)
            X0 = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
            s0 = float(np.median(noise_from_residuals(
                np.where(tri[..., None, None], obs, np.nan), X0, R, t, intr)))
            target = min(target_px, max(0.5, 6.0 * s0))
        if target > 0 and intr.n_cameras > 2:
            X, res, used = _resolve_rejecting(obs, R, t, intr, redo, target)
            ok = redo & np.isfinite(X).all(-1)
            drop = ok[..., None] & np.isfinite(obs).all(-1) & ~used
            detach_observations(o, drop)
            obs[drop] = np.nan
        else:
            X, res = retriangulate(obs, R, t, intr, redo)
            ok = redo & np.isfinite(X).all(-1)
        o["positions"][ok] = X[ok].astype(o["positions"].dtype)
        o["residual"][ok] = res[ok].astype(o["residual"].dtype)
        # two-camera samples whose rays miss each other, wrong observations the motion
        # contradicts, single-sensor samples no other camera ever checked, then
        # single-sensor samples from both sides (docs/algorithms.md, "Wrong
        # observations and single-sensor depth")
        reject_inconsistent_pairs(o, R, t, face, intr, fixed, PAIR_TARGET_FACTOR * target,
                                  single_sensor=single_sensor)
        tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
        Xt = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
        nb = neighbours(Xt, tri)
        reject_by_motion(o, R, t, face, intr, fixed, nb, single_sensor=single_sensor)
        reject_unanchored_single_sensor(o, face, fixed)
        tri = (o["recon"] == RECON_TRIANGULATED) & face[None, :]
        obs = o["obs"].astype(np.float64)
    else:
        nb = None

    def placed(ref_sigma: NDArray[np.float32]) -> NDArray[np.float32]:
        """Single-sensor samples from both sides (with the time checks only), their
        sigmas; called once the triangulated samples they are predicted from are final
        (after the depth priors), so a one-caddy reference's depth noise does not go
        into its single-sensor neighbours in time."""
        if nb is None:
            return np.full(tri.shape, np.nan, np.float32)
        return place_single_sensor(o, R, t, face, intr, nb, threshold_mm=single_threshold_mm,
                                   ref_sigma=ref_sigma)

    X = np.where(tri[..., None], o["positions"].astype(np.float64), np.nan)
    obs_t = np.where(tri[..., None, None], obs, np.nan)
    scale = None if widths is None else width_noise_scale(widths)
    if scale is not None and blob_scale is not None:
        scale = scale * blob_scale
    noise = noise_from_residuals(obs_t, X, R, t, intr, scale=scale)
    phi = point_noise_factor(obs_t, X, R, t, intr, noise, scale=scale)
    brim = ~face
    pose_cov, _ = brim_pose_covariance(o["positions"][:, brim], brim_obs, R, t, intr,
                                       white_factor=pose_factor if unbiased else None)
    if depth_window < 5 or len(R) < 5 or not tri.any():
        sigma = sample_sigma(X, obs_t, R, t, intr, noise, pose_cov=pose_cov,
                             pose_independent=unbiased, point_factor=phi,
                             scale=scale).astype(np.float32)
        single_sigma = placed(sigma)
        return R, t, np.where(np.isfinite(single_sigma), single_sigma, sigma)
    # the depth prior from time: one-caddy depth follows the smooth track, well-seen
    # directions keep their measurement (docs/algorithms.md). It reduces only the error
    # that changes from frame to frame (the cameras' 2D noise, up to each point's own
    # level); what neighbouring frames share is added to the sigma unchanged: a point's
    # excess noise (phi above 1: a blob consistently off) and the cameras' pose error
    # from the brim, both through `sample_sigma` (with the excess as its point factor)
    shared = sample_sigma(X, obs_t, R, t, intr, noise, pose_cov=pose_cov,
                          pose_independent=unbiased, point_factor=np.maximum(phi - 1.0, 0.0),
                          scale=scale).astype(np.float64)
    own = np.minimum(phi, 1.0)
    F, P = X.shape[:2]
    sigma = np.full((F, P), np.nan, dtype=np.float32)
    # a few points at a time: the covariances of a long take would not fit in memory
    step = max(1, 500_000 // max(F, 1))
    # the neighbours' prediction: a prior for depths that time alone leaves poor
    pred = patch_prediction(X, tri, neighbours(X, tri) if nb is None else nb)
    for p0 in range(0, P, step):
        ps = slice(p0, p0 + step)
        cov = sample_covariance(X[:, ps], obs_t[:, ps], R, t, intr, noise,
                                None if scale is None else scale[:, ps])
        Xs, cov = smooth_along_uncertainty(X[:, ps], cov, depth_window)
        tau = deformation_sigma(Xs, pred[:, ps], cov, tri[:, ps])
        # the sigma stays that of the track alone: the prediction shares the point's
        # own offsets and its neighbours' errors, so the product of the two
        # covariances would promise more than the fused sample keeps
        Xs, _ = fuse(Xs, cov, pred[:, ps], tau, tri[:, ps])
        moved = tri[:, ps] & ~fixed[:, None] & np.isfinite(Xs).all(-1)
        block = o["positions"][:, ps]
        block[moved] = Xs[moved].astype(block.dtype)
        o["positions"][:, ps] = block
        var = np.einsum("fpii->fp", cov) * own[None, ps] + np.nan_to_num(shared[:, ps]) ** 2
        sigma[:, ps] = np.sqrt(var)
    sigma[~np.isfinite(X).all(-1)] = np.nan
    single_sigma = placed(sigma)
    # wrong whole samples (a wrong blob in every camera) last: before the depth priors
    # a one-caddy sample's depth noise is as large as such an error (on tuning take 5,
    # 50 right samples were removed there)
    bad = reject_wrong_samples(o, face, fixed, nb)
    sigma[bad] = np.nan
    return R, t, np.where(np.isfinite(single_sigma), single_sigma, sigma)


def _merge_doubles(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_],
                   P: int, merge_mm: float) -> None:
    """Merge each found point into the earlier point it doubles (median distance)."""
    X = A["positions"].astype(np.float64)
    face = np.flatnonzero(kind != KIND_BRIM)
    for q in range(P, X.shape[1]):
        if not keep[q] or kind[q] == KIND_BRIM:
            continue
        others = face[(face < q) & keep[face]]
        if others.size == 0:
            continue
        d = np.linalg.norm(X[:, others] - X[:, q:q + 1], axis=-1)  # (F, n)
        both = np.isfinite(d)
        cnt = both.sum(0)
        med = np.array([np.median(d[both[:, j], j]) if cnt[j] else np.inf
                        for j in range(others.size)])
        j = int(np.argmin(med))
        if med[j] <= merge_mm:
            absorb(A, X, others[j], q)
            keep[q] = False
