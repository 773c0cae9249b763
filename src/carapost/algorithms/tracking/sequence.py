"""Tracking one direction through a take: :func:`track`.

Predicts, matches (:class:`~carapost.algorithms.tracking.matching.FrameMatcher`),
patch-tracks and carries lost points frame after frame; optionally adds markers found
among the unused detections (a spawner, see :mod:`carapost.algorithms.tracking.take`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.codes import (
    KIND_BRIM,
    KIND_FACE,
    POINT_FILLS,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    SOURCE_NONE,
    SOURCE_PATCH,
    blank_point_array,
)
from carapost.algorithms.patch import patch_search
from carapost.algorithms.tracking.assignment import INFEASIBLE_COST, assign, pack_detections
from carapost.algorithms.tracking.matching import FrameMatcher
from carapost.algorithms.tracking.neighbours import marker_spacing, shadows
from carapost.algorithms.tracking.params import TrackingParameters
from carapost.algorithms.tracking.records import FrameDetections, InitialState, TrackResult

#: ``spawn(frame, detections, used, positions, detection, R, t) -> (X [N, 3], det [N, C])``:
#: markers found among the detections no point uses (see :func:`make_spawner`).
Spawner = Callable[[int, FrameDetections, NDArray[np.bool_], NDArray[np.float64],
                    NDArray[np.intp], NDArray[np.float64], NDArray[np.float64]],
                   tuple[NDArray[np.float64], NDArray[np.intp]]]

#: Frames a point found by ``spawn`` must keep being triangulated to be kept.
PROBATION_FRAMES = 3


def track(
    detections: Callable[[int], FrameDetections],
    initial: InitialState,
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    params: TrackingParameters | None = None,
    *,
    start: int,
    stop: int,
    get_image: Callable[[int, int], NDArray[Any]] | None = None,
    resolve_cameras: bool = True,
    progress: Callable[[int, int], bool] | None = None,
    spawn: Spawner | None = None,
    spawn_interval: int = 1,
    guide: ArrayLike | None = None,
) -> TrackResult:
    """Track points from frame ``start`` to frame ``stop`` (either direction).

    Parameters
    ----------
    detections : callable
        ``detections(frame)`` -> one ``(centre [N, 2], axes [N, 2] or None)`` per camera
        (e.g. a :class:`RaggedDetections`). It may detect blobs on the fly.
    initial : InitialState
        Points in frame ``start``.
    R, t : array_like, shapes (C, 3, 3)/(C, 3) or (F, C, 3, 3)/(F, C, 3)
        Cameras: fixed, or per frame of the take (indexed by frame number). With brim
        points and ``resolve_cameras``, only the start frame's are used and every new
        frame is re-solved from the brim, starting from the previous frame's cameras.
    intr : CameraIntrinsics
    params : TrackingParameters, optional
    start, stop : int
        Start frame (holding ``initial``) and last frame to track (inclusive);
        ``stop < start`` tracks backwards.
    get_image : callable, optional
        ``get_image(frame, camera)`` -> grey image; enables patch tracking.
    resolve_cameras : bool
        Re-solve the cameras of each frame from the tracked brim points.
    progress : callable, optional
        ``progress(done, total)`` after each frame; False cancels and keeps what was done.
    spawn : callable, optional
        Finds markers among the detections no point uses (:data:`Spawner`, e.g.
        :func:`make_spawner`). A found marker within a third of the marker spacing of a
        lost point's neighbour-carried estimate revives that point; one far from every
        point becomes a new face point, kept only if it is triangulated in each of the
        next :data:`PROBATION_FRAMES` frames.
    spawn_interval : int
        Call ``spawn`` every this many frames.
    guide : array_like, shape (F, Pg, 3), optional
        Positions of the first ``Pg`` points from another pass over the take (mm, NaN
        where unknown): a point not tracked in a frame where the guide has it restarts
        from there (a backward pass carries every point found forwards back to its first
        appearance; see :func:`track_take`).

    Returns
    -------
    TrackResult
        Arrays for frames ``min(start, stop)..max(start, stop)`` without ``start`` (only
        those tracked when cancelled).

    Raises
    ------
    ValueError
        On inconsistent shapes.
    """
    params = TrackingParameters() if params is None else params
    C = intr.n_cameras
    X0 = np.asarray(initial.positions, np.float64)
    P = X0.shape[0]
    kind = np.asarray(initial.kind, np.int8).reshape(-1)
    if X0.shape != (P, 3) or kind.shape != (P,):
        raise ValueError(f"initial positions must be (P, 3) and kind (P,), got {X0.shape} "
                         f"and {kind.shape}")
    Ra = np.asarray(R, np.float64)
    ta = np.asarray(t, np.float64)
    per_frame = Ra.ndim == 4
    if Ra.shape[-3:] != (C, 3, 3) or ta.shape[-2:] != (C, 3):
        raise ValueError(f"R and t must be for {C} cameras, got {Ra.shape} and {ta.shape}")
    G = None if guide is None else np.asarray(guide, np.float64)
    if G is not None and (G.ndim != 3 or G.shape[2] != 3 or G.shape[1] > P):
        raise ValueError(f"guide must be (F, Pg <= {P}, 3), got {G.shape}")
    if int(spawn_interval) < 1:
        raise ValueError(f"spawn_interval must be >= 1, got {spawn_interval!r}")

    def cams(frame: int) -> tuple[NDArray, NDArray]:
        return (Ra[frame], ta[frame]) if per_frame else (Ra, ta)

    step = 1 if stop >= start else -1
    frames = list(range(start + step, stop + step, step))
    n = len(frames)
    brim = kind == KIND_BRIM
    has_brim = bool(np.any(brim & np.isfinite(X0).all(-1)))
    resolve = resolve_cameras and has_brim

    # Per-point state (grows when spawn finds new markers).
    st: dict[str, NDArray[Any]] = {
        "X_est": X0.copy(),
        "alive": np.isfinite(X0).all(-1),
        "velocity": np.zeros((P, 3)),
        "last_seen": np.isfinite(X0).all(-1),
        "prev_obs": (np.full((P, C, 2), np.nan) if initial.obs is None
                     else np.asarray(initial.obs, np.float64).copy()),
        "prev_axes": (np.full((P, C, 2), np.nan) if initial.axes is None
                      else np.asarray(initial.axes, np.float64).copy()),
        "patch_run": np.zeros((P, C), np.int32),
        "X_ref": X0.copy(),
        "born": np.full(P, -1, np.intp),
        "kind": kind.copy(),
    }
    out = {k: blank_point_array(k, n, P, C) for k in POINT_FILLS}
    st_fills = {"X_est": np.nan, "alive": False, "velocity": 0.0, "last_seen": False,
                "prev_obs": np.nan, "prev_axes": np.nan, "patch_run": 0, "X_ref": np.nan,
                "born": -1, "kind": KIND_FACE}
    out_R = np.zeros((n, C, 3, 3))
    out_t = np.zeros((n, C, 3))

    def grow(m: int) -> None:
        for d, fl, ax in ((st, st_fills, 0), (out, POINT_FILLS, 1)):
            for key, arr in d.items():
                shape = list(arr.shape)
                shape[ax] = m
                d[key] = np.concatenate([arr, np.full(shape, fl[key], arr.dtype)], axis=ax)

    def rebuild() -> tuple[FrameMatcher, NDArray, NDArray]:
        # a new neighbour graph: every point's reference restarts from the current
        # estimates (its own and its new neighbours', taken at the same time)
        rest = np.where(st["alive"][:, None], st["X_est"], np.nan)
        m = FrameMatcher(intr, st["kind"], rest, params)
        st["X_ref"] = rest.copy()
        pad = np.concatenate([rest[m.face], np.full((1, 3), np.nan)])
        return m, pad, pad[m.nb]

    matcher, face_pad, NB_ref = rebuild()
    Rc, tc = cams(start)
    Rc, tc = Rc.copy(), tc.copy()
    prev_frame = start
    images: dict[tuple[int, int], NDArray[Any]] = {}
    spacing = marker_spacing(X0[~brim])

    def image(frame: int, cam: int) -> NDArray[Any]:
        key = (frame, cam)
        if key not in images:
            images[key] = get_image(frame, cam)  # type: ignore[misc]
        return images[key]

    done = 0
    cancelled = False
    for i, frame in enumerate(frames):
        raw = detections(frame)
        fr = pack_detections(raw, C)
        if not resolve and (per_frame or i == 0):
            Rc, tc = cams(frame)
        alive, last_seen = st["alive"], st["last_seen"]
        X_pred = st["X_est"].copy()
        X_pred[alive & last_seen] += params.velocity_weight * \
            st["velocity"][alive & last_seen]
        X_pred[~alive] = np.nan
        X_pred[:P][brim] = X0[brim]  # brim points are known structure (never spawned)

        patch_fn = None
        if get_image is not None:
            pf = prev_frame

            def patch_fn(missing: NDArray[np.bool_], pred: NDArray[np.float64],
                         _pf: int = pf, _f: int = frame, _obs: NDArray = st["prev_obs"],
                         _run: NDArray = st["patch_run"]) -> tuple[NDArray, NDArray]:
                uv = np.full(pred.shape, np.nan)
                score = np.full(pred.shape[:2], -1.0)
                cand = missing & np.isfinite(_obs).all(-1) & (_run < params.max_patch_frames)
                for pp, cc in zip(*np.nonzero(cand), strict=True):
                    u, s = patch_search(image(_pf, cc), image(_f, cc), _obs[pp, cc],
                                        pred[pp, cc], params.patch_match_size,
                                        params.face_point_max_elastic_prediction_distance)
                    uv[pp, cc], score[pp, cc] = u, s
                return uv, score

        shadow = shadows(X_pred, alive & ~last_seen, alive & last_seen,
                          st["kind"] != KIND_BRIM, spacing)
        res = matcher.match_frame(
            fr, X_pred, Rc, tc, st["prev_axes"], reacquire=alive & ~last_seen,
            patch=patch_fn, resolve_cameras=resolve, ref=(st["X_ref"], NB_ref),
            blocked=shadow, hold_unsupported=True,
            wide_radius=params.consensus_radius_factor * params.face_point_tracking_distance,
            wide_rows=np.isfinite(st["prev_obs"]).all(-1),
        )
        Rc, tc = res["R"], res["t"]
        pos, X_el = res["positions"], res["X_elastic"]
        got = np.isfinite(pos).all(-1)
        restart = np.zeros_like(got)
        X_restart = np.full_like(pos, np.nan)
        if G is not None:
            g = G[frame]
            Pg = g.shape[0]
            restart[:Pg] = ~got[:Pg] & np.isfinite(g).all(-1) & (st["kind"][:Pg] != KIND_BRIM)
            X_restart[:Pg] = g
        new_rows: NDArray[np.intp] = np.zeros(0, np.intp)
        if spawn is not None and i % int(spawn_interval) == 0:
            used = np.zeros((C, max(fr.centres.shape[1], 1)), bool)
            d = res["detection"]
            for c in range(C):
                used[c, d[:, c][d[:, c] >= 0]] = True
            face_pos = np.where((st["kind"] != KIND_BRIM)[:, None], pos, np.nan)
            Xs, ds = spawn(frame, raw, used, face_pos, d, Rc, tc)
            Xs = np.asarray(Xs, np.float64).reshape(-1, 3)
            ds = np.asarray(ds, np.intp).reshape(-1, C)
            if len(Xs):
                face_now = st["kind"] != KIND_BRIM
                lost = np.flatnonzero(alive & ~got & ~restart & face_now & ~shadow
                                      & np.isfinite(X_el).all(-1))
                gate = spacing / 3.0
                take = np.full(len(Xs), -1, np.intp)
                # nearest tracked point: a find this close to one is its double, not new
                tracked = pos[got & face_now]
                dk = (cKDTree(tracked).query(Xs)[0] if len(tracked)
                      else np.full(len(Xs), np.inf))
                far = dk > 0.5 * spacing
                if lost.size:
                    # a lost point takes the find nearest its carried estimate, when no
                    # tracked point is nearer to that find
                    dd = np.linalg.norm(Xs[:, None] - X_el[lost][None], axis=-1)
                    ok = (dd <= gate) & (dd < dk[:, None])
                    cost = np.where(ok, dd / spacing, INFEASIBLE_COST)
                    take = assign(cost)
                    take = np.where(take >= 0, lost[np.maximum(take, 0)], -1)
                new = np.flatnonzero((take < 0) & far)
                old = np.flatnonzero(take >= 0)
                rows = take[old]
                if new.size:
                    P_now = st["kind"].size
                    grow(new.size)
                    new_rows = np.arange(P_now, P_now + new.size)
                    st["born"][new_rows] = i
                    pad = new.size
                    pos = np.concatenate([pos, np.full((pad, 3), np.nan)])
                    X_el = np.concatenate([X_el, np.full((pad, 3), np.nan)])
                    got = np.r_[got, np.zeros(pad, bool)]
                    restart = np.r_[restart, np.zeros(pad, bool)]
                    X_restart = np.concatenate([X_restart, np.full((pad, 3), np.nan)])
                    res = {k: (np.concatenate([v, np.full((pad,) + v.shape[1:], POINT_FILLS[k],
                                                          v.dtype)])
                               if k in POINT_FILLS else v) for k, v in res.items()}
                    rows = np.r_[rows, new_rows]
                    old = np.r_[old, new]
                if rows.size:
                    cc = np.arange(C)[None, :]
                    dsel = ds[old]
                    uv = np.where((dsel >= 0)[..., None], fr.centres[cc, np.maximum(dsel, 0)],
                                  np.nan)
                    pos[rows] = Xs[old]
                    got[rows] = True
                    res["positions"] = pos
                    res["recon"][rows] = RECON_TRIANGULATED
                    res["residual"][rows] = 0.0
                    res["obs"][rows] = uv
                    res["detection"][rows] = dsel
                    res["source"][rows] = np.where(dsel >= 0, SOURCE_BLOB, SOURCE_NONE)
                    res["quality"][rows] = np.where(dsel >= 0, 1.0, 0.0)
                    st["alive"][rows] = True
        # points on probation that were not triangulated are dropped altogether
        born = st["born"]
        probe = (born >= 0) & (i - born <= PROBATION_FRAMES) & st["alive"]
        fail = probe & ~(res["recon"] == RECON_TRIANGULATED)
        if fail.any():
            for key, fill in POINT_FILLS.items():
                res[key][fail] = fill
                out[key][:, fail] = fill
            st["alive"][fail] = False
            st["X_est"][fail] = np.nan
            st["X_ref"][fail] = np.nan
            got = got & ~fail
            pos = res["positions"]
        k = frame - min(frames[0], frames[-1])
        for key in out:
            out[key][k] = res[key]
        out_R[k], out_t[k] = Rc, tc

        alive, last_seen = st["alive"], st["last_seen"]
        X_new = np.where(got[:, None], pos, X_el)
        X_new = np.where(restart[:, None], X_restart, X_new)
        seen_now = got | restart
        moved = got & last_seen
        st["velocity"] = np.where(moved[:, None], X_new - st["X_est"], 0.0)
        joined = restart & ~alive
        st["alive"] = alive = alive | restart
        st["X_est"] = np.where(alive[:, None], X_new, st["X_est"])
        st["last_seen"] = seen_now
        d = res["detection"]
        cc = np.arange(C)[None, :]
        new_axes = fr.axes[cc, np.maximum(d, 0)]
        st["prev_axes"] = np.where((d >= 0)[..., None], new_axes, st["prev_axes"])
        has_obs = np.isfinite(res["obs"]).all(-1)
        st["prev_obs"] = np.where(has_obs[..., None], res["obs"], np.nan)
        st["patch_run"] = np.where(res["source"] == SOURCE_PATCH, st["patch_run"] + 1, 0)
        ref_now = (res["recon"] == RECON_TRIANGULATED) | restart
        st["X_ref"] = np.where(ref_now[:, None], X_new, st["X_ref"])
        if new_rows.size or joined.any() or fail.any():
            matcher, face_pad, NB_ref = rebuild()
        else:
            face = matcher.face
            tri = ref_now[face]
            if tri.any():
                face_pad[:-1] = np.where(tri[:, None], X_new[face], np.nan)
                NB_ref[tri] = face_pad[matcher.nb[tri]]
        if get_image is not None:
            for key in [key for key in images if key[0] != frame]:
                del images[key]
        prev_frame = frame
        done = i + 1
        if progress is not None and progress(done, n) is False:
            cancelled = done < n
            break

    # points that never passed probation are not returned
    P_all = st["kind"].size
    keep = np.ones(P_all, bool)
    keep[P:] = np.isfinite(out["positions"][:, P:, 0]).any(0)
    if step > 0:
        first, last = start + 1, start + done
        sl = slice(0, done)
    else:
        first, last = start - done, start - 1
        sl = slice(n - done, n)
    o = {key: arr[sl][:, keep] for key, arr in out.items()}
    return TrackResult(o["positions"], o["recon"], o["residual"], o["obs"], o["source"],
                       o["detection"], o["quality"], out_R[sl], out_t[sl], first=first,
                       last=last, frames_done=done, cancelled=cancelled,
                       n_new=int(keep[P:].sum()))
