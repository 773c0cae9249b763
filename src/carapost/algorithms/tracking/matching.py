"""One tracking step: :class:`FrameMatcher` matches predicted points to one frame.

Steps 2-4 of :mod:`carapost.algorithms.tracking`: neighbour-consensus and elastic
matching of blobs per camera (optimal assignment), patch candidates, camera resection
from the brim, robust triangulation and the 2D / 3D rejection tests. Also used by
Initialize From ROM.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from carapost.algorithms.camera import CameraIntrinsics, pixel_rays, pixels_to_normalised, project
from carapost.algorithms.codes import (
    KIND_BRIM,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    SOURCE_NONE,
    SOURCE_PATCH,
)
from carapost.algorithms.pose import refine_poses
from carapost.algorithms.tracking.assignment import (
    INFEASIBLE_COST,
    PackedFrame,
    assign,
    pair_distances,
)
from carapost.algorithms.tracking.neighbours import (
    marker_spacing,
    neighbour_graph,
    robust_mean,
    weighted_neighbour_mean,
)
from carapost.algorithms.tracking.params import TrackingParameters
from carapost.algorithms.triangulation import TriangulationParameters, triangulate

#: Neighbours moving further than this share of the marker spacing from their median
#: motion are left out of a point's 3D prediction (wrong blobs, not deformation: on the
#: fast preset's truth the largest deviation is 0.6 spacing, the 99.9th percentile 0.4).
_OUTLIER_SHARE = 0.75
#: Judged neighbours a point needs for its own neighbourhood's error to gate its
#: single-sensor depth (`_neighbourhood_error`).
_LOCAL_TYPICAL_MIN = 3


def _neighbourhood_error(near: NDArray[np.float64], nb: NDArray[np.intp],
                         frame_median: float) -> NDArray[np.float64]:
    """Median leave-one-out error (mm) of each point's judged neighbours (``frame_median``
    with fewer than `_LOCAL_TYPICAL_MIN`): while the jaw moves, the mouth's points are
    predicted worse than the brow's. ``near`` (P + 1,): errors, inf where not judged;
    ``nb`` (n, k): neighbour indices. Sorted, since `np.nanmedian` costs ten times more.
    """
    around = np.sort(near[nb], axis=1)  # the unjudged (inf) last
    n = np.isfinite(around).sum(1)
    rows = np.arange(len(nb))
    mid = 0.5 * (around[rows, np.maximum((n - 1) // 2, 0)]
                 + around[rows, np.maximum(n // 2, 0)])
    return np.where(n >= _LOCAL_TYPICAL_MIN, mid, frame_median)


#: Candidate detections per point in the wide region vote (:meth:`FrameMatcher._wide_vote`).
_WIDE_CANDIDATES = 12
#: Largest tolerance (px) the wide vote uses for a neighbour's agreement (lookup bound).
_WIDE_SIGMA_MAX = 12.0

#: Share of a face point's total neighbour weight that counts as full elastic support
#: when that total is below ``min_elastic_support`` (points on the edge of the set), as
#: long as the share is at least ``_NEED_FLOOR`` (an isolated point or one with no
#: neighbours keeps needing the full ``min_elastic_support``).
_NEED_SHARE = 0.6
_NEED_FLOOR = 0.3


#: The per-frame suspect-camera test (:meth:`FrameMatcher._solve_face`) needs at least
#: this many judged observations: a median of fewer says little about the frame.
_SUSPECT_MIN_OBS = 8
#: An observation is suspect beyond this multiple of the frame's median distance (px)
#: from the elastic prediction, and never below the floor (px).
_SUSPECT_FACTOR = 8.0
_SUSPECT_FLOOR_PX = 3.0
#: Tighter multiple and floor (px) for a camera taking a point up again.
_RETAKE_FACTOR = 4.0
_RETAKE_FLOOR_PX = 1.5
#: The worst camera of a suspect point is blamed only when its distance exceeds this
#: multiple of the second worst plus the margin (px): a bad prediction shows in every
#: camera, one wrong blob in one.
_BLAME_RATIO = 3.0
_BLAME_MARGIN_PX = 1.0


def resect_cameras(X: ArrayLike, uv: ArrayLike, R: ArrayLike, t: ArrayLike,
                   intr: CameraIntrinsics, *, iterations: int = 4, min_points: int = 6
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Refine every camera's pose from known 3D points (the brim), Gauss-Newton per camera.

    Tracking's per-frame resection: :func:`carapost.algorithms.pose.refine_poses` with
    ``linearise="camera"`` on the raw pixel observations.

    Parameters
    ----------
    X : array_like, shape (B, 3)
        Known 3D points (mm).
    uv : array_like, shape (B, C, 2)
        Their raw pixel observations (NaN where missing).
    R, t : array_like, shapes (C, 3, 3) and (C, 3)
        Starting poses (world->camera).
    intr : CameraIntrinsics
    iterations : int
    min_points : int
        Cameras seeing fewer points keep their starting pose.

    Returns
    -------
    R, t : ndarray
        Refined poses.
    solved : ndarray, shape (C,) bool
        Cameras that were re-solved.
    """
    xn = pixels_to_normalised(np.asarray(uv, np.float64), intr)  # (B, C, 2)
    out = refine_poses(X, np.swapaxes(xn, 0, 1), R, t, scale=intr.focal,
                       iterations=iterations, huber_px=None, min_points=min_points,
                       linearise="camera")
    return out.R, out.t, out.solved


class FrameMatcher:
    """Matches a set of predicted points to one frame's detections (tracking, ROM).

    Parameters
    ----------
    intr : CameraIntrinsics
    kind : ndarray, shape (P,)
    rest : ndarray, shape (P, 3)
        Positions defining the neighbour graph of the face points.
    params : TrackingParameters
    """

    def __init__(self, intr: CameraIntrinsics, kind: NDArray[np.int8], rest: NDArray,
                 params: TrackingParameters) -> None:
        self.intr = intr
        self.params = params
        self.kind = np.asarray(kind, dtype=np.int8)
        self.C = intr.n_cameras
        self.face = np.flatnonzero(self.kind != KIND_BRIM)
        self.brim = np.flatnonzero(self.kind == KIND_BRIM)
        rest = np.asarray(rest, np.float64)
        nb, w = neighbour_graph(rest[self.face], params.neighbours)
        self.nb, self.w = nb, w  # indices into self.face (len(face) = padding)
        # Support each face point needs from its neighbours: min_elastic_support, but at
        # most a share of all the weight it has. A point on the edge of the marker set
        # (temple, jaw line) has only far neighbours and may never reach the full value;
        # without this it could be neither judged nor single-sensor placed nor picked up
        # again after a single dropout.
        share = _NEED_SHARE * w.sum(1)
        self.need = np.where(share >= _NEED_FLOOR,
                             np.minimum(params.min_elastic_support, share),
                             params.min_elastic_support)
        self.spacing = marker_spacing(rest[self.face])  # mm
        self.tri_params = TriangulationParameters(
            minimum_cameras=min(2, self.C), use_outlier_rejection=self.C > 2,
            maximum_cameras_to_drop=1,
            target_reprojection_error=max(0.5, params.max_2d_projection_error / 5.0),
            refine_iterations=1,
        )

    # -- 2D matching -----------------------------------------------------------------
    def _size_ok(self, fr: PackedFrame, prev_axes: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(C, P, N) blob size test against each point's last blob axes."""
        thr = self.params.blob_size_difference_threshold
        a = prev_axes.transpose(1, 0, 2)[:, :, None, :]  # (C, P, 1, 2)
        b = fr.axes[:, None, :, :]                        # (C, 1, N, 2)
        if thr >= 1.0:
            return np.ones(a.shape[:2] + (b.shape[2],), bool)
        bad = np.zeros(a.shape[:2] + (b.shape[2],), bool)
        with np.errstate(invalid="ignore", divide="ignore"):
            for i in range(2):  # per axis: much faster than reducing a length-2 last axis
                ai, bi = a[..., i], b[..., i]
                bad |= np.abs(ai - bi) > thr * np.maximum(ai, bi)
        return ~bad  # NaN comparisons are False: unknown sizes pass

    def match_2d(
        self, fr: PackedFrame, pred: NDArray[np.float64], radius: NDArray[np.float64],
        size_ok: NDArray[np.bool_], *, anchors_only: bool = False,
        taken: NDArray[np.bool_] | None = None, nb_index: NDArray[np.intp] | None = None,
        wide_radius: float | None = None, wide_rows: NDArray[np.bool_] | None = None,
    ) -> NDArray[np.intp]:
        """Detection index per (point, camera) (-1 = none).

        pred (P, C, 2) predicted pixels (NaN = not predicted); radius (P, C) px;
        size_ok (C, P, N); taken (C, N) detections already used elsewhere; nb_index
        (P,) rows of the points in the neighbour graph (for the anchor pass);
        wide_radius (px, anchor pass only): points left without an anchor then vote
        over candidate displacements up to this far (:meth:`_wide_vote`), only those
        of ``wide_rows`` (P, C) when given.
        """
        P, C = pred.shape[:2]
        D = pair_distances(pred.transpose(1, 0, 2), fr.centres)  # (C, P, N)
        rad = radius.T[:, :, None]
        ok = (D <= rad) & size_ok
        if taken is not None:
            ok &= ~taken[:, None, :]
        out = np.full((P, C), -1, dtype=np.intp)
        if anchors_only:
            out = self._consensus(D, ok, pred, fr, nb_index)
            if wide_radius is not None and wide_radius > 0:
                okw = (D <= wide_radius) & size_ok & (rad >= 0)
                if wide_rows is not None:
                    okw &= wide_rows.T[:, :, None]
                if taken is not None:
                    okw &= ~taken[:, None, :]
                out = self._wide_vote(D, okw, pred, fr, nb_index, out, taken)
            return out
        cost = np.where(ok, (D / np.maximum(rad, 1e-9)) ** 2, INFEASIBLE_COST)
        for c in range(C):
            if fr.counts[c]:
                out[:, c] = assign(cost[c, :, : fr.counts[c]])
        return out

    def _consensus(self, D: NDArray[np.float64], ok: NDArray[np.bool_],
                   pred: NDArray[np.float64], fr: PackedFrame,
                   nb_index: NDArray[np.intp] | None) -> NDArray[np.intp]:
        """Anchor matches by neighbourhood consensus of candidate displacements.

        Each point considers its ``K`` nearest candidates. A candidate displacement is
        supported by a neighbour when that neighbour has a candidate with nearly the same
        displacement (markers move together locally); the best-supported candidate of a
        point is an anchor when its support is high and clearly above the runner-up,
        which resolves motions larger than the marker spacing that plain nearest-
        neighbour matching gets wrong.
        """
        C, P, N = D.shape
        out = np.full((P, C), -1, dtype=np.intp)
        if N == 0 or P == 0:
            return out
        K = min(5, N)
        Dm = np.where(ok, D, np.inf)
        cand = np.argpartition(Dm, K - 1, axis=2)[..., :K] if N > K else \
            np.broadcast_to(np.arange(N), (C, P, N)).copy()
        dcand = np.take_along_axis(Dm, cand, axis=2)  # (C, P, K)
        valid = np.isfinite(dcand)
        ci = np.arange(C)[:, None, None]
        disp = fr.centres[ci, cand] - pred.transpose(1, 0, 2)[:, :, None, :]  # (C, P, K, 2)
        disp = np.where(valid[..., None], disp, np.nan)
        nb_index, nbr, w = self._neighbour_rows(nb_index, P)
        disp_pad = np.concatenate([disp, np.full((C, 1, K, 2), np.nan)], axis=1)
        nd = disp_pad[:, nbr]  # (C, P, k, K, 2)
        dx = disp[:, :, None, :, None, 0] - nd[:, :, :, None, :, 0]  # (C, P, k, K, K)
        dy = disp[:, :, None, :, None, 1] - nd[:, :, :, None, :, 1]
        dist2 = np.nan_to_num(dx * dx + dy * dy, nan=np.inf).min(-1)  # (C, P, k, K)
        sigma2 = 2.0 * 3.0**2
        vote = (w[None, :, :, None] * np.exp(-dist2 / sigma2)).sum(2)  # (C, P, K)
        vote = np.where(valid, vote, -1.0)
        order = np.argsort(-vote, axis=2)
        best = np.take_along_axis(vote, order[..., :1], 2)[..., 0]
        second = (np.take_along_axis(vote, order[..., 1:2], 2)[..., 0] if K > 1
                  else np.zeros((C, P)))
        jbest = np.take_along_axis(cand, order[..., :1], 2)[..., 0]
        good = (best >= 1.0) & (best >= 1.5 * np.maximum(second, 0.0))
        # one detection per point: the best-supported claimant keeps it
        for c in range(C):
            rows = np.flatnonzero(good[c])
            if rows.size:
                o = rows[np.argsort(-best[c, rows])]
                _, first = np.unique(jbest[c, o], return_index=True)
                keep = o[first]
                out[keep, c] = jbest[c, keep]
        return out

    def _neighbour_rows(self, nb_index: NDArray[np.intp] | None, P: int
                        ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
        """Face-point indices of the ``P`` rows at hand (all when None), each row's
        neighbours as rows (``P`` where the neighbour is not among them) and their
        weights (0 for absent neighbours)."""
        if nb_index is None:
            nb_index = np.arange(P)
        row_of = np.full(len(self.face) + 1, P, dtype=np.intp)
        row_of[nb_index] = np.arange(P)
        nbr = row_of[self.nb[nb_index]]  # (P, k)
        return nb_index, nbr, np.where(nbr < P, self.w[nb_index], 0.0)

    def _wide_vote(self, D: NDArray[np.float64], ok: NDArray[np.bool_],
                   pred: NDArray[np.float64], fr: PackedFrame, nb_index: NDArray[np.intp] | None,
                   out: NDArray[np.intp], taken: NDArray[np.bool_] | None
                   ) -> NDArray[np.intp]:
        """More anchors for points the consensus left out: a region vote on a wider radius.

        A region that moves further than the search radius in one frame (a jaw opening
        of 40-50 px between two frames with markers 32 px apart) gives the consensus no
        candidate at the true displacement, while its edge markers, the ones the motion
        uncovers or hides, find the neighbouring marker's blob where theirs was. Here
        each point without an anchor considers the ``K`` nearest free detections within
        ``ok`` (the wide radius) as candidate displacements ``h``. A neighbour supports
        ``h`` when it is anchored with nearly that displacement, or, not being anchored
        itself, has a free detection near its own prediction shifted by ``h``; the
        tolerance grows with ``|h|`` because a large motion also deforms the region.
        The best-supported candidate becomes an anchor under the consensus rule (support
        of at least one full neighbour and 1.5 times the runner-up); a detection claimed
        twice goes to the better-supported point. Static regions are unaffected: their
        points are anchored already and hold their blobs, and a point whose own blob
        dropped out gets no support for a jump onto clutter.

        D (C, P, N) distances of the predictions ``pred`` (P, C, 2) to the detections;
        ok (C, P, N) candidates within the wide radius (size test passed, not taken);
        out (P, C) anchors so far (updated copy returned).
        """
        C, P, N = D.shape
        if N == 0 or P == 0:
            return out
        out = out.copy()
        nb_index, nbr_all, w_all = self._neighbour_rows(nb_index, P)
        need = np.maximum(self.need[nb_index], 1.0)
        finite = np.isfinite(pred).all(-1)  # (P, C)
        K = min(_WIDE_CANDIDATES, N)
        for c in range(C):
            n_c = int(fr.counts[c])
            rows = np.flatnonzero((out[:, c] < 0) & finite[:, c] & ok[c].any(1))
            if rows.size == 0 or n_c == 0:
                continue
            cen = fr.centres[c, :n_c]
            anch = out[:, c]
            free = np.ones(n_c, bool)
            free[anch[anch >= 0]] = False
            if taken is not None:
                free &= ~taken[c, :n_c]
            Dm = np.where(ok[c, rows, :n_c], D[c, rows, :n_c], np.inf)
            kk = min(K, n_c)
            cand = (np.argpartition(Dm, kk - 1, axis=1)[:, :kk] if n_c > kk
                    else np.broadcast_to(np.arange(n_c), (rows.size, n_c)).copy())
            valid = np.isfinite(np.take_along_axis(Dm, cand, axis=1))  # (U, K)
            h = cen[cand] - pred[rows, c][:, None, :]  # (U, K, 2)
            nbr = nbr_all[rows]  # (U, k)
            w = w_all[rows]
            pad_pred = np.concatenate([pred[:, c], np.full((1, 2), np.nan)])
            pad_anch = np.r_[anch, -1]
            un = pad_pred[nbr]  # (U, k, 2) neighbours' predictions
            has = np.isfinite(un).all(-1) & (w > 0)
            an = pad_anch[nbr]  # (U, k) neighbour's anchor or -1
            a_disp = np.where((an >= 0)[..., None], fr.centres[c, np.maximum(an, 0)] - un,
                              np.nan)  # (U, k, 2)
            sig = np.clip(0.15 * np.linalg.norm(h, axis=-1), 3.0, _WIDE_SIGMA_MAX)
            sig2 = 2.0 * sig**2  # (U, K)
            # anchored neighbours: agreement of their displacement with h
            dA = ((h[:, None, :, 0] - a_disp[:, :, None, 0]) ** 2
                  + (h[:, None, :, 1] - a_disp[:, :, None, 1]) ** 2)  # (U, k, K)
            sA = np.exp(-np.nan_to_num(dA, nan=np.inf) / sig2[:, None, :])
            # free neighbours: a free detection where h takes them
            look = has & (an < 0)
            sF = np.zeros_like(sA)
            if free.any() and look.any():
                ui, ki = np.nonzero(look)
                q = un[ui, ki][:, None, :] + h[ui]  # (L, K, 2)
                dq, _ = cKDTree(cen[free]).query(q.reshape(-1, 2),
                                                  distance_upper_bound=4.0 * _WIDE_SIGMA_MAX)
                dq = dq.reshape(q.shape[:2])
                sF[ui, ki] = np.exp(-np.where(np.isfinite(dq), dq, np.inf) ** 2
                                    / sig2[ui])
            vote = (w[..., None] * np.where((an >= 0)[..., None], sA, sF)
                    * has[..., None]).sum(1)  # (U, K)
            vote = np.where(valid, vote, -1.0)
            order = np.argsort(-vote, axis=1)
            best = np.take_along_axis(vote, order[:, :1], 1)[:, 0]
            second = (np.take_along_axis(vote, order[:, 1:2], 1)[:, 0] if kk > 1
                      else np.zeros(rows.size))
            jbest = np.take_along_axis(cand, order[:, :1], 1)[:, 0]
            good = (best >= need[rows]) & (best >= 1.5 * np.maximum(second, 0.0))
            good &= free[jbest]
            if good.any():
                g = rows[good]
                o = np.argsort(-best[good])
                _, first = np.unique(jbest[good][o], return_index=True)
                keep = o[first]
                out[g[keep], c] = jbest[good][keep]
        return out

    def elastic_2d(self, base: NDArray[np.float64], matched_uv: NDArray[np.float64],
                   matched: NDArray[np.bool_], face_cols: NDArray[np.intp]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Elastic correction of face predictions from matched neighbours, per camera.

        Returns the corrected predictions (Pf, C, 2) and the support (Pf, C).
        """
        disp = matched_uv - base  # (Pf, C, 2)
        corr, support = weighted_neighbour_mean(disp, matched & np.isfinite(disp).all(-1),
                                                 self.nb, self.w)
        return base + corr, support

    # -- one frame -----------------------------------------------------------------------
    def match_frame(
        self, fr: PackedFrame, X_pred: NDArray[np.float64], R: NDArray[np.float64],
        t: NDArray[np.float64], prev_axes: NDArray[np.float64], *,
        face_radius: float | None = None, brim_radius: float | None = None,
        elastic_radius: float | None = None, max_3d: float | None = None,
        passes: int | None = None, reacquire: NDArray[np.bool_] | None = None,
        patch: Callable[[NDArray[np.bool_], NDArray[np.float64]],
                        tuple[NDArray[np.float64], NDArray[np.float64]]] | None = None,
        resolve_cameras: bool = True,
        ref: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
        blocked: NDArray[np.bool_] | None = None,
        hold_unsupported: bool = False,
        wide_radius: float | None = None,
        wide_rows: NDArray[np.bool_] | None = None,
    ) -> dict[str, NDArray]:
        """Match, solve cameras, triangulate and clean one frame.

        Parameters
        ----------
        fr : packed detections of the frame.
        X_pred : (P, 3) predicted positions (brim: their fixed structure).
        R, t : predicted cameras.
        prev_axes : (P, C, 2) blob axes of the last match (NaN = unknown).
        face_radius, brim_radius, elastic_radius, max_3d : overrides of the parameters.
        passes : most elastic matching passes after the anchor pass (default
            ``params.elastic_passes``; stops early once the matches no longer change).
        reacquire : (P,) points that were lost: accepted only from >= 2 cameras, or
            from one by single sensor tracking.
        patch : callable(missing (P, C) bool, pred (P, C, 2)) -> (uv (P, C, 2), score)
            patch tracking fallback for point-cameras without a blob.
        resolve_cameras : re-solve cameras from the brim points.
        ref : (X_ref (P, 3), NB_ref (P_face, k, 3)), optional
            Each face point's last multi-camera position and its neighbours' positions
            at that time: the elastic 3D prediction is X_ref plus how the neighbours
            moved since, which does not drift while a point is seen by one camera.
        blocked : (P,) bool, optional
            Face points that take no detection in this frame (their estimate is still
            carried by their neighbours), e.g. a lost point whose estimate has drifted
            onto a tracked marker: it would otherwise take that marker's blob.
        hold_unsupported : bool
            Hold points without elastic support (and no match yet) out of the elastic
            passes until the supported matches have settled (frame-to-frame tracking;
            see below). Off for a one-off match such as a ROM frame, where the search
            around the given positions is the whole mechanism.
        wide_radius : float, optional
            Face points the anchor pass leaves without an anchor vote over candidate
            displacements up to this far (px) with their neighbours
            (:meth:`_wide_vote`); None (default) keeps the anchor pass within
            ``face_radius``. :func:`track` passes ``consensus_radius_factor`` times the
            Face Point Tracking Distance.
        wide_rows : (P, C) bool, optional
            The point-cameras that may take part in that vote (:func:`track`: those with
            a blob in the previous frame; a point not seen there is most often hidden,
            and searching far for it costs time and risks a wrong blob). The same rows
            tell the rejection step which cameras take a point up again (held to a
            tighter disagreement limit).

        Returns
        -------
        dict with positions (P,3), recon (P,), residual (P,), obs (P,C,2), source, detection,
        quality (P,C), R, t, X_elastic (P,3) (neighbour-based prediction).
        """
        p = self.params
        face_radius = p.face_point_tracking_distance if face_radius is None else face_radius
        brim_radius = p.brim_point_tracking_distance if brim_radius is None else brim_radius
        elastic_radius = (p.face_point_max_elastic_prediction_distance
                          if elastic_radius is None else elastic_radius)
        max_3d = p.max_3d_point_error if max_3d is None else max_3d
        C = self.C
        P = X_pred.shape[0]
        intr = self.intr
        N = fr.centres.shape[1]
        det = np.full((P, C), -1, dtype=np.intp)
        source = np.zeros((P, C), np.int8)
        quality = np.zeros((P, C), np.float64)
        obs = np.full((P, C, 2), np.nan)
        positions = np.full((P, 3), np.nan)
        recon = np.zeros(P, np.int8)
        residual = np.full(P, np.nan)
        tracked = np.isfinite(X_pred).all(-1)
        size_ok_all = self._size_ok(fr, prev_axes)
        taken = np.zeros((C, N), bool)
        R = np.array(R, np.float64)
        t = np.array(t, np.float64)

        def gather(d: NDArray[np.intp], c_idx: NDArray[np.intp] | None = None) -> NDArray:
            cc = np.arange(C)[None, :]
            uv = fr.centres[cc, np.maximum(d, 0)]
            return np.where((d >= 0)[..., None], uv, np.nan)

        # ---- brim: match the fixed structure, then re-solve the cameras -----------------
        b = self.brim[tracked[self.brim]]
        if b.size:
            Xb = X_pred[b]
            for it in range(2):
                uvb, _ = project(Xb, R, t, intr)
                rad = np.full((b.size, C), brim_radius if it == 0 else
                              min(brim_radius, max(p.max_2d_projection_error, 3.0)))
                db = self.match_2d(fr, uvb, rad, size_ok_all[:, b])
                # a dot cut by the image border has its centre pulled inwards (1.4 px
                # for a dot half outside): it would bend the camera, so it is not used
                cc = np.broadcast_to(np.arange(C)[None, :], db.shape)
                dd = np.maximum(db, 0)
                xy = fr.centres[cc, dd]
                reach = np.nan_to_num(fr.axes[cc, dd, 0], nan=0.0) + 1.0
                size = intr.image_size[None, :, :]
                cut = ((xy - reach[..., None] < -0.5) | (xy + reach[..., None] > size - 0.5)
                       ).any(-1)
                db[(db >= 0) & cut] = -1
                ob = gather(db)
                if resolve_cameras:
                    R, t, _ = resect_cameras(Xb, ob, R, t, intr)
                    # detach brim observations that disagree with the solved cameras
                    uvb, _ = project(Xb, R, t, intr)
                    err = np.linalg.norm(ob - uvb, axis=-1)
                    # brim dots fit to a few hundredths of a px: a blob beside a hidden
                    # dot stands out against the camera's typical error long before it
                    # exceeds Max Allowed 2D Projection Error (it moved a camera 4 mm)
                    seen = db >= 0
                    n_seen = np.maximum(seen.sum(0), 1)
                    typical = np.sort(np.where(seen, err, np.inf), axis=0)[
                        (n_seen - 1) // 2, np.arange(C)]
                    lim = np.minimum(p.max_2d_projection_error,
                                     np.maximum(1.0, 4.0 * typical))
                    bad = seen & ~(err <= lim[None, :])
                    if bad.any():
                        db[bad] = -1
                        ob = gather(db)
                        R, t, _ = resect_cameras(Xb, ob, R, t, intr)
            det[b] = db
            obs[b] = ob
            nb_obs = (db >= 0).sum(1)
            positions[b[nb_obs > 0]] = Xb[nb_obs > 0]
            recon[b] = np.where(nb_obs >= 2, RECON_TRIANGULATED,
                                np.where(nb_obs == 1, RECON_SINGLE_SENSOR, RECON_NONE))
            for c in range(C):
                taken[c, db[:, c][db[:, c] >= 0]] = True

        # ---- face: anchor pass, elastic passes ---------------------------------------
        f = self.face[tracked[self.face]]
        fi = np.flatnonzero(tracked[self.face])  # positions of f within self.face
        Pf_all = len(self.face)
        Xel = X_pred.copy()
        if f.size:
            base_all = np.full((Pf_all, C, 2), np.nan)
            uvf, depth = project(X_pred[f], R, t, intr)
            w_, h_ = intr.image_size[:, 0], intr.image_size[:, 1]
            # a margin of one search radius: a marker at the image border whose estimate
            # projects just outside can still be pulled in by its neighbours' motion
            mg = float(face_radius) + 0.5
            inside = ((depth > 0) & (uvf[..., 0] > -mg) & (uvf[..., 0] < w_ + mg)
                      & (uvf[..., 1] > -mg) & (uvf[..., 1] < h_ + mg))
            uvf = np.where(inside[..., None], uvf, np.nan)
            base_all[fi] = uvf
            size_ok = size_ok_all[:, f]
            rad = np.full((f.size, C), float(face_radius))
            blk = (np.zeros(f.size, bool) if blocked is None
                   else np.asarray(blocked, bool)[f])
            rad[blk] = -1.0  # a negative radius has no candidates
            df = self.match_2d(fr, uvf, rad, size_ok, anchors_only=True, taken=taken,
                               nb_index=fi, wide_radius=wide_radius,
                               wide_rows=None if wide_rows is None else wide_rows[f])
            n_pass = max(int(p.elastic_passes if passes is None else passes), 1)
            # Points without matched neighbours (no elastic support) would search around
            # their stale position and take the nearest blob, which in a region moving
            # about one marker spacing per frame is often the next marker along the
            # motion; the whole region then slips together and supports itself. They are
            # held back while the supported matches spread inwards, and matched at the
            # wide radius only once that has settled (then at most three more passes,
            # which keeps the cost near that of the plain passes).
            hold = bool(hold_unsupported)
            released = n_pass + 2  # the pass after which the held points were let in
            for it in range(n_pass + 2):
                df_prev = df
                m_all = np.zeros((Pf_all, C), bool)
                m_all[fi] = df >= 0
                uvm_all = np.full((Pf_all, C, 2), np.nan)
                uvm_all[fi] = gather(df)
                pred_all, support = self.elastic_2d(base_all, uvm_all, m_all, self.face)
                pred = pred_all[fi]
                sup = support[fi]
                weak = sup < self.need[fi, None]
                rad_w = float(face_radius)
                rad = np.where(weak, rad_w, float(elastic_radius))
                if hold:  # weak points keep competing for what they already hold
                    rad[weak & (df_prev < 0)] = -1.0
                rad[blk] = -1.0
                df = self.match_2d(fr, pred, rad, size_ok, taken=taken)
                # matches spread inwards from the matched points pass by pass (a region
                # moving faster than the search radius); stop once nothing changes
                settled = it >= 1 and np.array_equal(df, df_prev)
                if hold and (settled or it + 2 >= n_pass):
                    hold = False
                    left = weak & ~blk[:, None] & np.isfinite(pred).all(-1) & (df < 0)
                    if left.any():
                        released = it
                        continue
                if settled or it >= released + 3:
                    break
            det[f] = df
            source[f] = np.where(df >= 0, SOURCE_BLOB, SOURCE_NONE)
            quality[f] = np.where(df >= 0, 1.0, 0.0)
            obs[f] = gather(df)
            if patch is not None:
                missing = np.zeros((P, C), bool)
                missing[f] = (df < 0) & np.isfinite(pred).all(-1) & ~blk[:, None]
                if missing.any():
                    ppred = np.full((P, C, 2), np.nan)
                    ppred[f] = pred
                    puv, score = patch(missing, ppred)
                    okp = missing & np.isfinite(puv).all(-1) & (score >= p.patch_match_threshold)
                    obs[okp] = puv[okp]
                    source[okp] = SOURCE_PATCH
                    quality[okp] = score[okp]
            self._solve_face(f, obs, det, source, quality, positions, recon, residual, X_pred,
                             R, t, max_3d, reacquire, Xel, ref, wide_rows)
        return {"positions": positions, "recon": recon, "residual": residual, "obs": obs,
                "source": source, "detection": det, "quality": quality, "R": R, "t": t,
                "X_elastic": Xel}

    def _solve_face(self, f: NDArray[np.intp], obs: NDArray, det: NDArray, source: NDArray,
                    quality: NDArray, positions: NDArray, recon: NDArray, residual: NDArray,
                    X_pred: NDArray, R: NDArray, t: NDArray, max_3d: float,
                    reacquire: NDArray[np.bool_] | None, Xel_out: NDArray,
                    ref: tuple[NDArray, NDArray] | None,
                    prev_seen: NDArray[np.bool_] | None = None) -> None:
        p = self.params
        intr = self.intr
        C = self.C

        def detach(rows: NDArray[np.intp], mask: NDArray[np.bool_]) -> None:
            sub_o = obs[rows]
            sub_o[mask] = np.nan
            obs[rows] = sub_o
            for arr, fill in ((det, -1), (source, SOURCE_NONE), (quality, 0.0)):
                sub = arr[rows]
                sub[mask] = fill
                arr[rows] = sub

        def tri(rows: NDArray[np.intp]) -> tuple[NDArray, NDArray, NDArray]:
            res = triangulate(obs[rows][None], R, t, intr, self.tri_params)
            return res.points[0], res.residual[0], res.contribution[0]

        X, res, contrib = tri(f)
        has = np.isfinite(obs[f]).all(-1)
        # Cameras the robust triangulation left out are wrong matches: they are detached
        # whatever Remove Bad 2D Projections says (that option adds the reprojection-error
        # test; a blob the solve already rejected must not stay attached as an
        # observation the point's 3D position ignores).
        drop = has & ~contrib & np.isfinite(X).all(-1)[:, None]
        if p.remove_bad_2d_projections:
            uvp, _ = project(X, R, t, intr)
            err = np.linalg.norm(uvp - obs[f], axis=-1)
            drop |= has & (err > p.max_2d_projection_error)
        if drop.any():
            detach(f, drop)
            rows = np.flatnonzero(drop.any(1))
            X[rows], res[rows], _ = tri(f[rows])
        # neighbour-based 3D prediction (leave-one-out) from the points just solved
        Pf_all = len(self.face)
        fi = np.searchsorted(self.face, f)
        okX = np.zeros(Pf_all, bool)
        okX[fi] = np.isfinite(X).all(-1)
        # A neighbour solved from a wrong blob pair (not yet rejected) can be tens of mm
        # off; its motion must not drag the prediction of every point around it, so
        # neighbours moving unlike the others are left out (robust_mean).
        gate = _OUTLIER_SHARE * self.spacing
        disp = np.full((Pf_all + 1, 3), np.nan)
        disp[fi] = np.where(okX[fi, None], X - X_pred[f], np.nan)
        dn = disp[self.nb[fi]]  # (n, k, 3)
        corr, sup = robust_mean(dn, np.isfinite(dn[..., 0]), self.w[fi], gate)
        Xel = X_pred[f] + corr
        if ref is not None:
            X_ref, NB_ref = ref
            Xnow = np.full((Pf_all + 1, 3), np.nan)
            Xnow[fi] = X
            moved = Xnow[self.nb[fi]] - NB_ref[fi]  # (n, k, 3)
            m = np.isfinite(moved).all(-1) & np.isfinite(X_ref[f]).all(-1)[:, None]
            mv, sup_r = robust_mean(moved, m, self.w[fi], gate)
            Xr = X_ref[f] + mv
            use = sup_r >= self.need[fi]
            Xel = np.where(use[:, None], Xr, Xel)
            sup = np.where(use, sup_r, sup)
        Xel_out[f] = Xel
        n_obs = np.isfinite(obs[f]).all(-1).sum(1)
        err3 = np.linalg.norm(X - Xel, axis=-1)
        need = self.need[fi]
        judged = np.isfinite(X).all(-1) & (sup >= need)
        # how well neighbours predict points in this frame and around each point (mm),
        # before any is solved again below; single-sensor depth is only as good as that
        typical = float(np.median(err3[judged])) if judged.any() else np.inf
        near = np.full(Pf_all + 1, np.inf)
        near[fi[judged]] = err3[judged]
        if p.remove_bad_3d_points:
            # A point whose observation in one camera is much further from the elastic
            # prediction than is usual in this frame probably matched a wrong blob along
            # the epipolar line (invisible to the reprojection test with two cameras):
            # drop that camera and solve again. Measured in pixels because the depth of a
            # point seen by one caddy only is poorly determined.
            uvp, _ = project(Xel, R, t, intr)
            e2 = np.linalg.norm(uvp - obs[f], axis=-1)  # (n, C) NaN where no obs
            fin = np.isfinite(e2) & judged[:, None]
            if fin.sum() >= _SUSPECT_MIN_OBS:
                med = float(np.median(e2[fin]))
                thr = max(_SUSPECT_FACTOR * med, _SUSPECT_FLOOR_PX)
                thr_c = np.full(e2.shape, thr)
                if prev_seen is not None:
                    # A camera taking a point up again is held to a tighter limit: one
                    # biased blob there (a marker merged with a shadow, 2-3 px off) makes
                    # a two-camera point millimetres deep, which the point then keeps
                    # as its reference while one camera carries it.
                    thr_c[~prev_seen[f]] = max(_RETAKE_FACTOR * med, _RETAKE_FLOOR_PX)
                ratio = np.where(fin, e2 / thr_c, -1.0)
                pick = np.argmax(ratio, axis=1)
                rows_n = np.arange(e2.shape[0])
                worst_e = np.where(fin[rows_n, pick], e2[rows_n, pick], -1.0)
                others = np.where(fin, e2, -1.0)
                others[rows_n, pick] = -1.0
                second_e = others.max(axis=1)
                # a bad prediction shows in every camera; one wrong blob in one camera
                suspect = np.flatnonzero(judged & (ratio[rows_n, pick] > 1.0)
                                         & (worst_e > _BLAME_RATIO * np.maximum(second_e, 0.0)
                                            + _BLAME_MARGIN_PX))
                if suspect.size:
                    worst = pick[suspect]
                    drop = np.zeros((suspect.size, C), bool)
                    drop[np.arange(suspect.size), worst] = True
                    detach(f[suspect], drop)
                    X[suspect], res[suspect], _ = tri(f[suspect])
                    e2s = np.where(np.isfinite(obs[f[suspect]]).all(-1), e2[suspect], np.nan)
                    still = np.nanmax(np.where(np.isfinite(e2s), e2s, -1.0), axis=1) > thr
                    if still.any():
                        detach(f[suspect[still]], np.ones((int(still.sum()), C), bool))
                        X[suspect[still]] = np.nan
                    err3[suspect] = np.linalg.norm(X[suspect] - Xel[suspect], axis=-1)
                    n_obs = np.isfinite(obs[f]).all(-1).sum(1)
            # below full support the prediction is less sure, so the limit widens in
            # proportion (a point on the edge of the set is still checked)
            with np.errstate(divide="ignore", invalid="ignore"):
                widen = np.where(sup > 0, np.maximum(need / sup, 1.0), np.inf)
            bad = np.isfinite(X).all(-1) & (err3 > max_3d * widen)
            if bad.any():
                detach(f[bad], np.ones((int(bad.sum()), C), bool))
                X[bad] = np.nan
                n_obs[bad] = 0
        # a lost point is picked up again only where its neighbours say it should be (a
        # whole region lost at once waits for its edges to return), from >= 2 cameras, or
        # from one when single sensor tracking may place it (same test as below: its ray
        # within the threshold of the prediction). Without the latter, a marker seen by
        # one camera for a while (the chin row cut by the image edge in the other) stayed
        # lost after its first dropout: rendered speech 600 coverage 0.9888 -> 0.9920.
        if reacquire is not None:
            few = (n_obs < 1) if p.allow_single_sensor_tracking else (n_obs < 2)
            lone = reacquire[f] & (few | (sup < need))
            if lone.any():
                detach(f[lone], np.ones((int(lone.sum()), C), bool))
                X[lone] = np.nan
                n_obs[lone] = 0
        # duplicates: two points reconstructed at the same place, keep the better one
        good = np.flatnonzero(np.isfinite(X).all(-1))
        if good.size > 1:
            pairs = cKDTree(X[good]).query_pairs(r=1.5, output_type="ndarray")
            if len(pairs):
                e = np.linalg.norm(X[good] - Xel[good], axis=-1)
                a, b2 = good[pairs[:, 0]], good[pairs[:, 1]]
                loser = np.where(e[pairs[:, 0]] > e[pairs[:, 1]], a, b2)
                loser = np.unique(loser)
                detach(f[loser], np.ones((loser.size, C), bool))
                X[loser] = np.nan
                n_obs[loser] = 0
        tri_ok = np.isfinite(X).all(-1) & (n_obs >= 2)
        positions[f[tri_ok]] = X[tri_ok]
        recon[f[tri_ok]] = RECON_TRIANGULATED
        residual[f[tri_ok]] = res[tri_ok]
        single = n_obs == 1
        if single.any():
            rows = np.flatnonzero(single)
            o = obs[f[rows]]
            cam = np.argmax(np.isfinite(o).all(-1), axis=1)
            uv1 = o[np.arange(rows.size), cam]
            keep = np.zeros(rows.size, bool)
            if p.allow_single_sensor_tracking:
                target = Xel[rows]
                # one "camera" per row: the rows' own cameras side by side
                origin, d = pixel_rays(uv1[None], R[cam][None], t[cam][None],
                                       intr.subset(cam))
                origin, d = origin[0], d[0]
                s = np.einsum("ni,ni->n", target - origin, d)
                Xs = origin + s[:, None] * d
                dist = np.linalg.norm(Xs - target, axis=-1)
                keep = (sup[rows] >= need[rows]) & \
                    (dist <= p.single_sensor_tracking_threshold) & (s > 0) & \
                    (_neighbourhood_error(near, self.nb[fi[rows]], typical)
                     <= p.single_sensor_tracking_threshold)
                positions[f[rows[keep]]] = Xs[keep]
                recon[f[rows[keep]]] = RECON_SINGLE_SENSOR
                residual[f[rows[keep]]] = dist[keep]
            else:
                # keep the observation when it agrees with the prediction, without 3D
                uvp, _ = project(Xel[rows], R, t, intr)
                e = np.linalg.norm(uvp[np.arange(rows.size), cam] - uv1, axis=-1)
                keep = e <= p.max_2d_projection_error
            if (~keep).any():
                drop = np.zeros((rows.size, C), bool)
                drop[~keep] = True
                detach(f[rows], drop)
