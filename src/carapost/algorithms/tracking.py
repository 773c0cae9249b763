"""Automatic frame-to-frame tracking of 3D markers through a take.

For every point that has a 3D position in the start frame, and for every following frame
(forwards or backwards), :func:`track`:

1. Predicts the point in the new frame: its last estimate plus a damped velocity, then
   corrected elastically by how its matched neighbours moved (the neighbours are the
   nearest points in 3D in the start frame, weighted by a Gaussian of that distance).
2. Matches blob detections camera by camera. A first pass takes only matches its
   neighbours agree on (candidate displacements within Face / Brim Point Tracking
   Distance supported by the neighbours' candidates; points left out vote again over a
   wider radius, so a region moving further than the search radius in one frame is
   matched around the displacement its markers share); those anchor the elastic
   prediction, and the following passes match every point within Face Point Max Elastic
   Prediction Distance of its elastic prediction (the full Face Point Tracking Distance
   where too few neighbours are matched). Conflicts are resolved by an optimal assignment per camera
   (:func:`scipy.optimize.linear_sum_assignment` with a "no match" option for each point
   costing as much as a match at the search radius), so one detection never feeds two
   points. A blob whose width or height changed by more than Blob Size Difference
   Threshold is not a candidate. Where no blob matches and images are available, a grey
   patch around the last observation is searched by normalised cross-correlation
   (accepted at Patch Match Threshold and recorded as patch-tracked).
3. Re-solves the cameras of the new frame from the brim points (known 3D structure) by a
   few Gauss-Newton steps per camera, then triangulates the face points robustly
   (:func:`carapost.algorithms.triangulation.triangulate`, outlier rejection on).
4. Rejects bad matches: observations whose reprojection error exceeds Max Allowed 2D
   Projection Error, and points further than Max Allowed 3D Point Error from where their
   neighbours predict them (neighbours moving unlike the others left out). A point left
   with one camera is placed on that camera's ray at the neighbour-predicted depth when
   the ray passes within Single Sensor Tracking Threshold of the prediction (Allow Single
   Sensor Tracking).

A point that loses every camera keeps a predicted position carried along by its
neighbours, so it is picked up again as soon as its blob reappears near that prediction
(markers coming back after a blink) - from two cameras agreeing in 3D, or from one whose
ray passes within Single Sensor Tracking Threshold of the prediction.

Everything is vectorised per frame over points x cameras; there is no Python loop per
point-frame except for patch tracking of the few point-cameras that found no blob.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from carapost.algorithms.camera import (
    CameraIntrinsics,
    pixel_rays,
    pixels_to_normalised,
    project,
)
from carapost.algorithms.patch import patch_search
from carapost.algorithms.pose import refine_poses
from carapost.algorithms.triangulation import TriangulationParameters, triangulate

log = logging.getLogger("carapost.tracking")

# Values of the model's SOURCE_* / RECON_* / KIND_* constants (algorithms do not import the
# model; carapost.model.project defines the same numbers).
SOURCE_NONE, SOURCE_BLOB, SOURCE_PATCH = 0, 1, 2
RECON_NONE, RECON_TRIANGULATED, RECON_SINGLE_SENSOR = 0, 1, 2
KIND_FACE, KIND_BRIM = 0, 1

#: Infeasible assignment cost (anything far above the "no match" cost of 1).
_BIG = 1e6

#: Neighbours moving further than this share of the marker spacing from their median
#: motion are left out of a point's 3D prediction (wrong blobs, not deformation: on the
#: fast preset's truth the largest deviation is 0.6 spacing, the 99.9th percentile 0.4).
_OUTLIER_SHARE = 0.75

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

#: Detections of one frame: one ``(centre [N, 2], axes [N, 2] or None)`` per camera.
FrameDetections = Sequence[tuple[NDArray[Any], NDArray[Any] | None]]


@dataclass(frozen=True)
class TrackingParameters:
    """The Tracking Parameters section, plus a few settings of our own.

    The first twelve fields have the keys and defaults of the properties registry, so
    ``TrackingParameters(**props.section("Tracking Parameters"))`` works.

    Attributes
    ----------
    patch_match_threshold : float
        Minimum normalised cross-correlation (0-1) for a patch-tracked observation.
    face_point_tracking_distance : float
        Search radius (px) for face points without elastic support.
    face_point_max_elastic_prediction_distance : float
        Search radius (px) around the elastic prediction once neighbours are matched.
    brim_point_tracking_distance : float
        Search radius (px) for brim points.
    patch_match_size : int
        Side (px) of the square grey-level patch.
    remove_bad_2d_projections : bool
    max_2d_projection_error : float
        Observations further (px) than this from their point's projection are detached.
    remove_bad_3d_points : bool
    max_3d_point_error : float
        Points further (mm) than this from their neighbour-based prediction are dropped.
    allow_single_sensor_tracking : bool
    single_sensor_tracking_threshold : float
        Largest distance (mm) between a single-camera ray and the prediction.
    blob_size_difference_threshold : float
        Allowed relative change (0-1) of a blob's axes between frames (1 = any).
    velocity_weight : float
        Fraction of the last frame-to-frame motion added to the prediction (ours).
    neighbours : int
        Neighbours per point for the elastic prediction (ours).
    min_elastic_support : float
        Summed neighbour weight needed to use the elastic radius (ours; one full-weight
        neighbour = 1).
    bundle_frames : bool
        Bundle adjust each tracked frame (cameras and points; slower; ours).
    max_patch_frames : int
        Longest run of consecutive patch-tracked frames in one camera (ours).
    elastic_passes : int
        Most elastic matching passes per frame (ours): each pass predicts the points not
        yet matched from the neighbours matched in the previous one, so a region moving
        faster than the search radius is picked up from its edges inwards.
    consensus_radius_factor : float
        Points the anchor pass leaves without an anchor vote, with their neighbours, over
        candidate displacements up to this multiple of Face Point Tracking Distance
        (ours; >= 1; 1 keeps the candidates within that distance): a region moving
        further than the radius between two frames is matched as a whole around the
        displacement its markers agree on (the elastic prediction of the reference
        guide, found before any neighbour is matched).
    """

    patch_match_threshold: float = 0.8
    face_point_tracking_distance: float = 35.0
    face_point_max_elastic_prediction_distance: float = 15.0
    brim_point_tracking_distance: float = 15.0
    patch_match_size: int = 15
    remove_bad_2d_projections: bool = True
    max_2d_projection_error: float = 5.0
    remove_bad_3d_points: bool = True
    max_3d_point_error: float = 5.0
    allow_single_sensor_tracking: bool = True
    single_sensor_tracking_threshold: float = 0.5
    blob_size_difference_threshold: float = 0.75
    velocity_weight: float = 0.0
    neighbours: int = 8
    min_elastic_support: float = 1.5
    bundle_frames: bool = False
    max_patch_frames: int = 5
    elastic_passes: int = 5
    consensus_radius_factor: float = 2.0

    def __post_init__(self) -> None:
        for name in ("face_point_tracking_distance", "face_point_max_elastic_prediction_distance",
                     "brim_point_tracking_distance", "max_2d_projection_error",
                     "max_3d_point_error", "single_sensor_tracking_threshold"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"TrackingParameters.{name} must be a number >= 0, got {v!r}")
        for name in ("patch_match_threshold", "blob_size_difference_threshold",
                     "velocity_weight"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ValueError(f"TrackingParameters.{name} must be in 0-1, got {v!r}")
        if int(self.patch_match_size) < 3:
            raise ValueError(f"TrackingParameters.patch_match_size must be >= 3 px, got "
                             f"{self.patch_match_size!r}")
        if int(self.elastic_passes) < 1:
            raise ValueError(f"TrackingParameters.elastic_passes must be >= 1, got "
                             f"{self.elastic_passes!r}")
        v = self.consensus_radius_factor
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 1.0):
            raise ValueError(f"TrackingParameters.consensus_radius_factor must be >= 1, got "
                             f"{v!r}")
        if int(self.neighbours) < 1:
            raise ValueError(f"TrackingParameters.neighbours must be >= 1, got "
                             f"{self.neighbours!r}")

    @classmethod
    def from_mapping(cls, values: dict[str, Any], **overrides: Any) -> TrackingParameters:
        """Build from a properties section (unknown keys are ignored)."""
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in values.items() if k in names}
        kw.update(overrides)
        return cls(**kw)


class TrackResult(NamedTuple):
    """Output of :func:`track` for the frames it tracked (in increasing frame order).

    Attributes
    ----------
    first, last : int
        Inclusive frame range the arrays cover (the start frame is not included); when
        nothing was tracked ``last < first``.
    positions : ndarray, shape (n, P, 3) float32
    recon : ndarray, shape (n, P) int8
    residual : ndarray, shape (n, P) float32
    obs : ndarray, shape (n, P, C, 2) float32
    source : ndarray, shape (n, P, C) int8
    detection : ndarray, shape (n, P, C) int32
    quality : ndarray, shape (n, P, C) float16
    R : ndarray, shape (n, C, 3, 3)
    t : ndarray, shape (n, C, 3)
        Cameras of each tracked frame (re-solved from the brim when it is tracked).
    frames_done : int
        Frames tracked (fewer than asked only when cancelled).
    cancelled : bool
    n_new : int
        Points found during tracking (``spawn``), appended after the initial ones (face
        points; the point axis of the arrays is ``P + n_new``).
    """

    first: int
    last: int
    positions: NDArray[np.float32]
    recon: NDArray[np.int8]
    residual: NDArray[np.float32]
    obs: NDArray[np.float32]
    source: NDArray[np.int8]
    detection: NDArray[np.int32]
    quality: NDArray[np.float16]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    frames_done: int
    cancelled: bool
    n_new: int = 0


@dataclass
class InitialState:
    """The tracked points in the start frame.

    Attributes
    ----------
    positions : ndarray, shape (P, 3)
        3D positions (mm); points with NaN are carried but never tracked.
    kind : ndarray, shape (P,)
        ``KIND_FACE`` or ``KIND_BRIM``; brim points keep their start position (known
        structure) and fix the cameras of every frame.
    obs : ndarray, shape (P, C, 2), optional
        2D observations in the start frame (templates for patch tracking).
    axes : ndarray, shape (P, C, 2), optional
        Blob semi-axes of those observations (for the blob size test).
    """

    positions: NDArray[np.float64]
    kind: NDArray[np.int8]
    obs: NDArray[np.float64] | None = None
    axes: NDArray[np.float64] | None = None


class RaggedDetections:
    """Detections of a whole take as the model stores them, served frame by frame.

    Parameters
    ----------
    offsets : array_like, shape (F * C + 1,)
        Image ``(f, c)`` owns rows ``offsets[f * C + c]:offsets[f * C + c + 1]``.
    centre : array_like, shape (N, 2)
    axes : array_like, shape (N, 2), optional
    n_cameras : int
    """

    def __init__(self, offsets: ArrayLike, centre: ArrayLike, axes: ArrayLike | None,
                 n_cameras: int) -> None:
        self.offsets = np.asarray(offsets, dtype=np.int64)
        self.centre = np.asarray(centre)
        self.axes = None if axes is None else np.asarray(axes)
        self.n_cameras = int(n_cameras)

    def __call__(self, frame: int) -> list[tuple[NDArray[Any], NDArray[Any] | None]]:
        """Per camera ``(centre, axes)`` of one frame (float64 copies)."""
        C = self.n_cameras
        out = []
        for c in range(C):
            i = frame * C + c
            s, e = int(self.offsets[i]), int(self.offsets[i + 1])
            ax = None if self.axes is None else self.axes[s:e].astype(np.float64)
            out.append((self.centre[s:e].astype(np.float64), ax))
        return out


# --------------------------------------------------------------------------------------
# Small vectorised helpers
# --------------------------------------------------------------------------------------

def neighbour_graph(rest: ArrayLike, k: int) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Nearest neighbours of each point in 3D and their elastic weights.

    Parameters
    ----------
    rest : array_like, shape (P, 3)
        Rest positions (mm); NaN rows get no neighbours and are nobody's neighbour.
    k : int
        Neighbours per point.

    Returns
    -------
    index : ndarray, shape (P, k)
        Neighbour columns (P where there is none).
    weight : ndarray, shape (P, k)
        ``exp(-(d / s)^2)`` with ``s`` 1.5 times the median nearest-neighbour distance;
        0 where there is no neighbour.
    """
    X = np.asarray(rest, dtype=np.float64)
    P = X.shape[0]
    ok = np.isfinite(X).all(-1)
    cols = np.flatnonzero(ok)
    index = np.full((P, k), P, dtype=np.intp)
    weight = np.zeros((P, k))
    if cols.size < 2:
        return index, weight
    kk = min(k, cols.size - 1)
    d, j = cKDTree(X[cols]).query(X[cols], k=kk + 1)
    d, j = d[:, 1:], j[:, 1:]
    s = 1.5 * float(np.median(d[:, 0]))
    s = s if s > 0 else 1.0
    index[cols, :kk] = cols[j]
    weight[cols, :kk] = np.exp(-((d / s) ** 2))
    return index, weight


def _weighted_neighbour_mean(values: NDArray[np.float64], valid: NDArray[np.bool_],
                             nb: NDArray[np.intp], w: NDArray[np.float64]
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mean of the neighbours' ``values`` where ``valid``, and the summed weight.

    ``values`` is (P, ..., D), ``valid`` (P, ...), ``nb``/``w`` (P, k); returns the mean
    (P, ..., D) (0 where no support) and the support (P, ...).
    """
    P = values.shape[0]
    pad_v = np.concatenate([np.nan_to_num(values), np.zeros((1,) + values.shape[1:])])
    pad_m = np.concatenate([valid, np.zeros((1,) + valid.shape[1:], bool)])
    wm = w.reshape(w.shape + (1,) * (valid.ndim - 1)) * pad_m[nb]  # (P, k, ...)
    support = wm.sum(1)
    total = (wm[..., None] * pad_v[nb]).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(support[..., None] > 0, total / support[..., None], 0.0)
    return mean.reshape((P,) + values.shape[1:]), support


def _robust_mean(values: NDArray[np.float64], valid: NDArray[np.bool_],
                 w: NDArray[np.float64], gate: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted mean over neighbours without the ones far from their median.

    ``values`` (n, k, D) per neighbour (e.g. 3D motions), ``valid`` (n, k), weights ``w``
    (n, k). Neighbours further than ``gate`` from the component-wise median of the valid
    ones are left out (with three or more valid neighbours). Returns the mean (n, D), 0
    where nothing is left, and the summed weight of the neighbours used (n,).
    """
    n, k, D = values.shape
    cnt = valid.sum(1)
    srt = np.sort(np.where(valid[..., None], values, np.inf), axis=1)
    idx = np.broadcast_to((np.maximum(cnt, 1) - 1)[:, None, None] // 2, (n, 1, D))
    med = np.take_along_axis(srt, idx, axis=1)  # (n, 1, D), lower median
    dev2 = np.zeros((n, k))
    for i in range(D):
        dev2 += (values[..., i] - med[..., i]) ** 2
    keep = valid & ((dev2 <= gate * gate) | (cnt < 3)[:, None])
    wm = w * keep
    support = wm.sum(1)
    total = (wm[..., None] * np.where(keep[..., None], values, 0.0)).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(support[:, None] > 0, total / support[:, None], 0.0)
    return mean, support


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


def _pair_distances(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances between ``a`` (..., P, 2) and ``b`` (..., N, 2): (..., P, N).

    Component by component: reducing a length-2 last axis is several times slower.
    """
    dx = a[..., :, None, 0] - b[..., None, :, 0]
    dy = a[..., :, None, 1] - b[..., None, :, 1]
    return np.sqrt(dx * dx + dy * dy)


def _assign(cost: NDArray[np.float64]) -> NDArray[np.intp]:
    """Optimal one-to-one assignment with a unit "no match" cost per row.

    ``cost`` is (P, N) with values >= _BIG meaning infeasible; returns the matched column
    of each row or -1.
    """
    P, N = cost.shape
    out = np.full(P, -1, dtype=np.intp)
    if P == 0 or N == 0:
        return out
    feas = cost < _BIG
    rows = np.flatnonzero(feas.any(1))
    if rows.size == 0:
        return out
    colsel = np.flatnonzero(feas[rows].any(0))
    sub = cost[np.ix_(rows, colsel)]
    # fast path: rows with one candidate whose column nobody else wants
    cnt_r = (sub < _BIG).sum(1)
    cnt_c = (sub < _BIG).sum(0)
    j = np.argmin(sub, axis=1)
    simple = (cnt_r == 1) & (cnt_c[j] == 1) & (sub[np.arange(len(rows)), j] <= 1.0)
    out[rows[simple]] = colsel[j[simple]]
    rest = ~simple
    if not rest.any():
        return out
    r2 = np.flatnonzero(rest)
    c2 = np.flatnonzero((sub[r2] < _BIG).any(0))
    if c2.size == 0:
        return out
    block = sub[np.ix_(r2, c2)]
    n = len(r2)
    dummy = np.full((n, n), _BIG)
    np.fill_diagonal(dummy, 1.0)
    full = np.concatenate([block, dummy], axis=1)
    ri, ci = linear_sum_assignment(full)
    ok = (ci < len(c2)) & (full[ri, ci] < 1.0 + 1e-12)
    ok &= full[ri, ci] < _BIG
    out[rows[r2[ri[ok]]]] = colsel[c2[ci[ok]]]
    return out


# --------------------------------------------------------------------------------------
# The tracker
# --------------------------------------------------------------------------------------

class _Frame(NamedTuple):
    centres: NDArray[np.float64]  # (C, N, 2) NaN padded
    axes: NDArray[np.float64]     # (C, N, 2) NaN where unknown
    counts: NDArray[np.intp]      # (C,)


def _pack(dets: FrameDetections, C: int) -> _Frame:
    if len(dets) != C:
        raise ValueError(f"detections must give {C} cameras per frame, got {len(dets)}")
    counts = np.array([len(d[0]) for d in dets], dtype=np.intp)
    N = max(int(counts.max(initial=0)), 1)
    centres = np.full((C, N, 2), np.nan)
    axes = np.full((C, N, 2), np.nan)
    for c, (cen, ax) in enumerate(dets):
        n = counts[c]
        if n:
            centres[c, :n] = np.asarray(cen, np.float64).reshape(n, 2)
            if ax is not None:
                axes[c, :n] = np.asarray(ax, np.float64).reshape(n, 2)
    return _Frame(centres, axes, counts)


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
        self.spacing = _spacing(rest[self.face])  # mm
        self.tri_params = TriangulationParameters(
            minimum_cameras=min(2, self.C), use_outlier_rejection=self.C > 2,
            maximum_cameras_to_drop=1,
            target_reprojection_error=max(0.5, params.max_2d_projection_error / 5.0),
            refine_iterations=1,
        )

    # -- 2D matching -----------------------------------------------------------------
    def _size_ok(self, fr: _Frame, prev_axes: NDArray[np.float64]) -> NDArray[np.bool_]:
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
        self, fr: _Frame, pred: NDArray[np.float64], radius: NDArray[np.float64],
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
        D = _pair_distances(pred.transpose(1, 0, 2), fr.centres)  # (C, P, N)
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
        cost = np.where(ok, (D / np.maximum(rad, 1e-9)) ** 2, _BIG)
        for c in range(C):
            if fr.counts[c]:
                out[:, c] = _assign(cost[c, :, : fr.counts[c]])
        return out

    def _consensus(self, D: NDArray[np.float64], ok: NDArray[np.bool_],
                   pred: NDArray[np.float64], fr: _Frame,
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
                   pred: NDArray[np.float64], fr: _Frame, nb_index: NDArray[np.intp] | None,
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
        corr, support = _weighted_neighbour_mean(disp, matched & np.isfinite(disp).all(-1),
                                                 self.nb, self.w)
        return base + corr, support

    # -- one frame -----------------------------------------------------------------------
    def match_frame(
        self, fr: _Frame, X_pred: NDArray[np.float64], R: NDArray[np.float64],
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
        if p.remove_bad_2d_projections or True:
            # cameras left out by the robust triangulation are wrong matches
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
        # neighbours moving unlike the others are left out (_robust_mean).
        gate = _OUTLIER_SHARE * self.spacing
        disp = np.full((Pf_all + 1, 3), np.nan)
        disp[fi] = np.where(okX[fi, None], X - X_pred[f], np.nan)
        dn = disp[self.nb[fi]]  # (n, k, 3)
        corr, sup = _robust_mean(dn, np.isfinite(dn[..., 0]), self.w[fi], gate)
        Xel = X_pred[f] + corr
        if ref is not None:
            X_ref, NB_ref = ref
            Xnow = np.full((Pf_all + 1, 3), np.nan)
            Xnow[fi] = X
            moved = Xnow[self.nb[fi]] - NB_ref[fi]  # (n, k, 3)
            m = np.isfinite(moved).all(-1) & np.isfinite(X_ref[f]).all(-1)[:, None]
            mv, sup_r = _robust_mean(moved, m, self.w[fi], gate)
            Xr = X_ref[f] + mv
            use = sup_r >= self.need[fi]
            Xel = np.where(use[:, None], Xr, Xel)
            sup = np.where(use, sup_r, sup)
        Xel_out[f] = Xel
        n_obs = np.isfinite(obs[f]).all(-1).sum(1)
        err3 = np.linalg.norm(X - Xel, axis=-1)
        need = self.need[fi]
        judged = np.isfinite(X).all(-1) & (sup >= need)
        # how well neighbours predict points in this frame (mm); single-sensor depth is
        # only as good as that
        typical = float(np.median(err3[judged])) if judged.any() else np.inf
        if p.remove_bad_3d_points:
            # A point whose observation in one camera is much further from the elastic
            # prediction than is usual in this frame probably matched a wrong blob along
            # the epipolar line (invisible to the reprojection test with two cameras):
            # drop that camera and solve again. Measured in pixels because the depth of a
            # point seen by one caddy only is poorly determined.
            uvp, _ = project(Xel, R, t, intr)
            e2 = np.linalg.norm(uvp - obs[f], axis=-1)  # (n, C) NaN where no obs
            fin = np.isfinite(e2) & judged[:, None]
            if fin.sum() >= 8:
                med = float(np.median(e2[fin]))
                thr = max(8.0 * med, 3.0)
                thr_c = np.full(e2.shape, thr)
                if prev_seen is not None:
                    # A camera taking a point up again is held to a tighter limit: one
                    # biased blob there (a marker merged with a shadow, 2-3 px off) makes
                    # a two-camera point millimetres deep, which the point then keeps
                    # as its reference while one camera carries it.
                    thr_c[~prev_seen[f]] = max(4.0 * med, 1.5)
                ratio = np.where(fin, e2 / thr_c, -1.0)
                pick = np.argmax(ratio, axis=1)
                rows_n = np.arange(e2.shape[0])
                worst_e = np.where(fin[rows_n, pick], e2[rows_n, pick], -1.0)
                others = np.where(fin, e2, -1.0)
                others[rows_n, pick] = -1.0
                second_e = others.max(axis=1)
                # a bad prediction shows in every camera; one wrong blob in one camera
                suspect = np.flatnonzero(judged & (ratio[rows_n, pick] > 1.0)
                                         & (worst_e > 3.0 * np.maximum(second_e, 0.0) + 1.0))
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
                    (typical <= p.single_sensor_tracking_threshold)
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


# --------------------------------------------------------------------------------------
# Sequence tracking
# --------------------------------------------------------------------------------------

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
    out: dict[str, NDArray[Any]] = {
        "positions": np.full((n, P, 3), np.nan, np.float32),
        "recon": np.zeros((n, P), np.int8),
        "residual": np.full((n, P), np.nan, np.float32),
        "obs": np.full((n, P, C, 2), np.nan, np.float32),
        "source": np.zeros((n, P, C), np.int8),
        "detection": np.full((n, P, C), -1, np.int32),
        "quality": np.zeros((n, P, C), np.float16),
    }
    fills = {"positions": np.nan, "recon": 0, "residual": np.nan, "obs": np.nan,
             "source": 0, "detection": -1, "quality": 0}
    st_fills = {"X_est": np.nan, "alive": False, "velocity": 0.0, "last_seen": False,
                "prev_obs": np.nan, "prev_axes": np.nan, "patch_run": 0, "X_ref": np.nan,
                "born": -1, "kind": KIND_FACE}
    out_R = np.zeros((n, C, 3, 3))
    out_t = np.zeros((n, C, 3))

    def grow(m: int) -> None:
        for d, fl, ax in ((st, st_fills, 0), (out, fills, 1)):
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
    spacing = _spacing(X0[~brim])

    def image(frame: int, cam: int) -> NDArray[Any]:
        key = (frame, cam)
        if key not in images:
            images[key] = get_image(frame, cam)  # type: ignore[misc]
        return images[key]

    done = 0
    cancelled = False
    for i, frame in enumerate(frames):
        raw = detections(frame)
        fr = _pack(raw, C)
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

        shadow = _shadows(X_pred, alive & ~last_seen, alive & last_seen,
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
                    cost = np.where(ok, dd / spacing, _BIG)
                    take = _assign(cost)
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
                    res = {k: (np.concatenate([v, np.full((pad,) + v.shape[1:], fills[k],
                                                          v.dtype)])
                               if k in fills else v) for k, v in res.items()}
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
            for key in ("positions", "recon", "residual", "obs", "source", "detection",
                        "quality"):
                res[key][fail] = fills[key]
                out[key][:, fail] = fills[key]
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
    return TrackResult(first, last, o["positions"], o["recon"], o["residual"], o["obs"],
                       o["source"], o["detection"], o["quality"], out_R[sl], out_t[sl], done,
                       cancelled, int(keep[P:].sum()))


def _shadows(X: NDArray[np.float64], lost: NDArray[np.bool_], seen: NDArray[np.bool_],
             face: NDArray[np.bool_], spacing: float) -> NDArray[np.bool_]:
    """Lost face points whose carried estimate lies on a tracked face point.

    Two markers are never closer than about the marker spacing, so a lost point's
    neighbour-carried estimate (``X``, (P, 3) mm) within half the ``spacing`` of a point
    tracked in the last frame has drifted onto that marker; matching it would take the
    marker's blobs from its own point (the point then slips or is lost, and the lost one
    takes its identity). Returns (P,) bool.
    """
    out = np.zeros(lost.shape, bool)
    cand = np.flatnonzero(lost & face & np.isfinite(X).all(-1))
    ref = np.flatnonzero(seen & face & np.isfinite(X).all(-1))
    if cand.size and ref.size:
        d, _ = cKDTree(X[ref]).query(X[cand])
        out[cand] = d < 0.5 * spacing
    return out


def _spacing(X: NDArray[np.float64]) -> float:
    """Median nearest-neighbour distance of the finite rows of ``X`` (mm; 10 if unknown)."""
    X = X[np.isfinite(X).all(-1)]
    if len(X) < 2:
        return 10.0
    d, _ = cKDTree(X).query(X, k=2)
    return float(np.median(d[:, 1]))


def make_spawner(
    intr: CameraIntrinsics,
    caddies: Sequence[tuple[int, int]] | None = None,
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
    caddies : sequence of (int, int), optional
        Camera pairs of one caddy (default (0, 1), (2, 3), ...).
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
    cad = tuple(caddies) if caddies is not None else tuple(
        (i, i + 1) for i in range(0, C - 1, 2))
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

    names = ("positions", "recon", "residual", "obs", "source", "detection", "quality")
    fills = {"positions": np.nan, "recon": 0, "residual": np.nan, "obs": np.nan,
             "source": 0, "detection": -1, "quality": 0}
    shapes = {"positions": (3,), "recon": (), "residual": (), "obs": (C, 2), "source": (C,),
              "detection": (C,), "quality": (C,)}
    dtypes = {"positions": np.float32, "recon": np.int8, "residual": np.float32,
              "obs": np.float32, "source": np.int8, "detection": np.int32,
              "quality": np.float16}

    def empty(p: int) -> dict[str, NDArray[Any]]:
        return {k: np.full((F, p) + shapes[k], fills[k], dtypes[k]) for k in names}

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
        for k in names:
            A[k][sl] = getattr(fwd, k)
        Rall[sl], tall[sl] = fwd.R, fwd.t
    kind1 = np.r_[kind0, np.full(P1 - P, KIND_FACE, np.int8)]
    step1 = 1 if end1 >= start else -1
    last = start if fwd is None else start + step1 * fwd.frames_done
    lo, hi = min(start, last), max(start, last)
    if cancelled or last == end2:
        return _take_result(A, Rall, tall, lo, hi, done, cancelled, kind1, P, min_frames,
                            merge_mm)
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
    for k in names:
        B[k][:, :P1] = A[k]
    if bwd.frames_done:
        sl = slice(bwd.first, bwd.last + 1)
        fr2 = np.arange(bwd.first, bwd.last + 1)
        # the second pass fills what the first did not have (and every frame beyond start)
        beyond = fr2 < start if end2 <= start else fr2 > start
        fill = (B["recon"][sl] == RECON_NONE)
        fill[:, :P1] |= beyond[:, None]
        fill[:, P1:] = True
        for k in names:
            cur = B[k][sl]
            new = getattr(bwd, k)
            m = fill.reshape(fill.shape + (1,) * (cur.ndim - 2))
            B[k][sl] = np.where(m, new, cur)
        Rall[sl][beyond], tall[sl][beyond] = bwd.R[beyond], bwd.t[beyond]
        lo, hi = min(lo, bwd.first), max(hi, bwd.last)
    kind2 = np.r_[kind1, np.full(P2 - P1, KIND_FACE, np.int8)]
    return _take_result(B, Rall, tall, lo, hi, done, bwd.cancelled, kind2, P, min_frames,
                        merge_mm)


def _take_result(A: dict[str, NDArray[Any]], R: NDArray, t: NDArray, first: int, last: int,
                 done: int, cancelled: bool, kind: NDArray[np.int8], P: int, min_frames: int,
                 merge_mm: float) -> TrackResult:
    """Clean the joined passes and build the result.

    1. Split every point where it hops to another marker (:func:`hop_segments`): the
       pieces on another identity become points of their own.
    2. Merge found points (and pieces) into an earlier point they double (median distance
       below ``merge_mm`` where both exist), then join pieces of one marker that never
       coexist (:func:`_stitch`).
    3. Clear what still hops, drop found points triangulated in fewer than ``min_frames``
       frames and found points far from every other point (:func:`_drop_isolated`).
    """
    keep = np.ones(A["positions"].shape[1], bool)
    A, kind, keep = _split_hops(A, kind, keep)
    _merge_doubles(A, kind, keep, P, merge_mm)
    _stitch(A, kind, keep, P, merge_mm)
    _remove_hops(A, kind, keep)
    tri = (A["recon"] == RECON_TRIANGULATED).sum(0)
    keep[P:] &= tri[P:] >= min_frames
    _drop_isolated(A, kind, keep, P)
    sl = slice(first, last + 1)
    o = {k: v[sl][:, keep] for k, v in A.items()}
    return TrackResult(first, last, o["positions"], o["recon"], o["residual"], o["obs"],
                       o["source"], o["detection"], o["quality"], R[sl], t[sl], done,
                       cancelled, int(keep[P:].sum()))


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
            _absorb(A, X, others[j], q)
            keep[q] = False


def hop_segments(X: ArrayLike, nb: NDArray[np.intp], w: NDArray[np.float64],
                 gate: float, rows: ArrayLike | None = None) -> NDArray[np.intp]:
    """Which marker identity each point is on, frame by frame, judged from its neighbours.

    A point that hops to a neighbouring marker moves, between two frames where it is
    seen, by about the marker spacing relative to how its neighbours moved; normal motion
    relative to the neighbours is a small fraction of it. Each such hop starts a new
    segment; segments are labelled by the summed hop vectors (a hop away and the hop back
    cancel) and grouped when their labels agree within ``gate``. Group 0 is the identity
    the point holds longest. Neighbours whose own motion disagrees with the others' (a
    neighbour hopping itself) are left out.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm; NaN where absent).
    nb, w : ndarray, shape (P, k)
        Neighbour graph (:func:`neighbour_graph`; index ``P`` = padding).
    gate : float
        Smallest hop (mm), e.g. half the marker spacing.
    rows : array_like of int, optional
        Points to examine (default all; the others get group 0 where present).

    Returns
    -------
    ndarray of int, shape (F, P)
        Identity group per point-frame: -1 absent, 0 the point's own, 1, 2, ... others.
    """
    X = np.asarray(X, np.float64)
    F, P = X.shape[:2]
    pad = np.concatenate([X, np.full((F, 1, 3), np.nan)], axis=1)
    group = np.where(np.isfinite(X).all(-1), 0, -1).astype(np.intp)
    for p in (range(P) if rows is None else np.asarray(rows, np.intp).reshape(-1)):
        fr = np.flatnonzero(np.isfinite(X[:, p]).all(-1))
        if fr.size < 2:
            continue
        a, b = fr[:-1], fr[1:]
        dnb = pad[b][:, nb[p]] - pad[a][:, nb[p]]  # (n, k, 3)
        fin = np.isfinite(dnb).all(-1) & (w[p] > 0)
        # a neighbour that itself hops must not hide (or fake) this point's hop: only
        # neighbours moving like most of them count
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(np.where(fin[..., None], dnb, np.nan), axis=1)
        fin &= np.linalg.norm(dnb - med[:, None], axis=-1) <= 0.5 * gate
        m = fin * w[p]
        sw = m.sum(1)
        mean = (np.nan_to_num(dnb) * m[..., None]).sum(1) / np.maximum(sw, 1e-9)[:, None]
        r = X[b, p] - X[a, p] - mean
        rn = np.where(sw > 0.05, np.linalg.norm(r, axis=-1), 0.0)
        hop = rn > gate
        if not hop.any():
            continue
        # a wrong frame between right ones gives a step out and a step back of which one
        # may fall just short of the gate: a large step next to a hop counts as one too,
        # so the two cancel
        near = np.zeros_like(hop)
        near[1:] |= hop[:-1]
        near[:-1] |= hop[1:]
        hop |= near & (rn > 0.5 * gate)
        seg = np.r_[0, np.cumsum(hop)]  # segment of each frame in fr
        label = np.cumsum(np.concatenate([np.zeros((1, 3)),
                                          np.where(hop[:, None], r, 0.0)]), axis=0)
        counts = np.bincount(seg)
        # group segments by label, the longest-held identity first
        centres: list[NDArray[np.float64]] = []
        seg_group = np.zeros(counts.size, np.intp)
        for sgi in np.argsort(-counts, kind="stable"):
            lab = label[np.flatnonzero(seg == sgi)[0]]
            dist = [float(np.linalg.norm(lab - c)) for c in centres]
            if dist and min(dist) <= gate:
                seg_group[sgi] = int(np.argmin(dist))
            else:
                seg_group[sgi] = len(centres)
                centres.append(lab)
        group[fr, p] = seg_group[seg]
    return group


def _face_graph(X: NDArray[np.float64], k: int = 12, min_frames: int = 10
                ) -> tuple[NDArray, NDArray, float] | None:
    """Neighbour graph of points from their median positions over the take (or None).

    Only points present in at least ``min_frames`` frames serve as neighbours (the
    short-lived finds of a pass would otherwise be the nearest neighbours of the marker
    they double, with a random motion).
    """
    seen = np.isfinite(X[..., 0]).any(0)
    if seen.sum() < 3:
        return None
    rest = np.full((X.shape[1], 3), np.nan)
    rest[seen] = np.nanmedian(X[:, seen], axis=0)
    ref = np.flatnonzero(np.isfinite(X[..., 0]).sum(0) >= min_frames)
    if ref.size < 3:
        ref = np.flatnonzero(seen)
    P = X.shape[1]
    kk = min(k, ref.size - 1)
    d, j = cKDTree(rest[ref]).query(rest[seen], k=kk + 1)
    cols = ref[j]
    rows = np.flatnonzero(seen)
    own = cols == rows[:, None]
    # drop the point itself (or the farthest when it is not a reference)
    drop = np.where(own.any(1), np.argmax(own, axis=1), kk)
    keepc = np.ones_like(own)
    keepc[np.arange(rows.size), drop] = False
    cols = cols[keepc].reshape(rows.size, kk)
    d = d[keepc].reshape(rows.size, kk)
    spacing = _spacing(rest[ref])
    nb = np.full((P, kk), P, np.intp)
    w = np.zeros((P, kk))
    nb[rows] = cols
    w[rows] = np.exp(-((d / (1.5 * spacing)) ** 2))
    return nb, w, spacing


def _identity_groups(A: dict[str, NDArray[Any]], face: NDArray[np.intp]
                     ) -> NDArray[np.intp] | None:
    """:func:`hop_segments` of the ``face`` columns of a take's arrays (F, n).

    Judged on the triangulated frames only (a single-camera frame's depth can be off by
    a few millimetres without being on another marker); each single-camera frame takes
    the group of the nearest triangulated frame before it (after it at the start).
    """
    pos = A["positions"][:, face].astype(np.float64)
    tri = A["recon"][:, face] == RECON_TRIANGULATED
    X = np.where(tri[..., None], pos, np.nan)
    g = _face_graph(X)
    if g is None:
        return None
    group = hop_segments(X, g[0], g[1], 0.5 * g[2])
    other = np.isfinite(pos[..., 0]) & ~tri
    F = pos.shape[0]
    for j in np.flatnonzero(other.any(0)):
        fin = np.flatnonzero(tri[:, j])
        if fin.size == 0:
            continue
        idx = np.clip(np.searchsorted(fin, np.arange(F), side="right") - 1, 0, fin.size - 1)
        group[other[:, j], j] = group[fin[idx], j][other[:, j]]
    return group


_FILLS = {"positions": np.nan, "recon": 0, "residual": np.nan, "obs": np.nan, "source": 0,
          "detection": -1, "quality": 0}


def _split_hops(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_]
                ) -> tuple[dict[str, NDArray[Any]], NDArray[np.int8], NDArray[np.bool_]]:
    """Move the frames where a face point is on another marker to new points."""
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    group = _identity_groups(A, face)
    if group is None:
        return A, kind, keep
    cols, masks = [], []
    for j in np.flatnonzero((group > 0).any(0)):
        for gi in range(1, int(group[:, j].max()) + 1):
            m = group[:, j] == gi
            if m.any():
                cols.append(face[j])
                masks.append(m)
    if not cols:
        return A, kind, keep
    mk = np.stack(masks, axis=1)  # (F, n)
    src = np.asarray(cols)
    out = {}
    for k, arr in A.items():
        piece = arr[:, src].copy()
        shape = mk.shape + (1,) * (arr.ndim - 2)
        piece = np.where(mk.reshape(shape), piece, np.asarray(_FILLS[k], arr.dtype))
        arr = arr.copy()
        for i, c in enumerate(src):
            arr[mk[:, i], c] = _FILLS[k]
        out[k] = np.concatenate([arr, piece.astype(arr.dtype)], axis=1)
    kind = np.r_[kind, np.full(src.size, KIND_FACE, np.int8)]
    keep = np.r_[keep, np.ones(src.size, bool)]
    return out, kind, keep


def _remove_hops(A: dict[str, NDArray[Any]], kind: NDArray[np.int8],
                 keep: NDArray[np.bool_]) -> None:
    """Clear the frames where a face point sits on another marker (:func:`hop_segments`)."""
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    group = _identity_groups(A, face)
    if group is None:
        return
    bad = group > 0
    if bad.any():
        for k, arr in A.items():
            sub = arr[:, face]
            sub[bad] = _FILLS[k]
            arr[:, face] = sub


def _absorb(A: dict[str, NDArray[Any]], X: NDArray[np.float64], o: int, q: int) -> None:
    """Give point ``o`` point ``q``'s data in the frames where ``o`` has none."""
    gap = ~np.isfinite(X[:, o]).all(-1) & np.isfinite(X[:, q]).all(-1)
    for k in A:
        A[k][gap, o] = A[k][gap, q]
    X[gap, o] = X[gap, q]


def _stitch(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_],
            P: int, merge_mm: float) -> None:
    """Join found points that are pieces of an earlier point's marker.

    A marker lost and found again several times becomes several points that rarely
    coexist, so their distance cannot be compared. A found point joins an earlier one
    whose typical position is within half the marker spacing when, wherever both exist,
    they agree within ``merge_mm``, and the joined track has no hop relative to the
    neighbours' motion (:func:`hop_segments`), i.e. continues on the same marker.
    """
    X = A["positions"].astype(np.float64)
    X = np.where((A["recon"] == RECON_TRIANGULATED)[..., None], X, np.nan)
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    seen = np.isfinite(X[:, face, 0]).any(0)
    if seen.sum() < 4 or face.size == 0:
        return
    rest = np.full((X.shape[1], 3), np.nan)
    rest[face[seen]] = np.nanmedian(X[:, face[seen]], axis=0)
    has = np.isfinite(rest).all(-1)
    spacing = _spacing(rest[face])
    gate = 0.5 * spacing
    base = face[has[face]]
    if base.size < 4:
        return
    tree = cKDTree(rest[base])
    k = min(8, base.size - 2)
    kq = min(k + 8, base.size)
    Xall = A["positions"].astype(np.float64)
    for q in range(P, X.shape[1]):
        if not (keep[q] and has[q] and kind[q] != KIND_BRIM):
            continue
        others = face[(face < q) & keep[face] & has[face]]
        dr = np.linalg.norm(rest[others] - rest[q], axis=-1)
        order = np.argsort(dr)
        for o in others[order[dr[order] <= gate][:3]]:
            both = np.isfinite(X[:, o, 0]) & np.isfinite(X[:, q, 0])
            if both.any() and np.median(np.linalg.norm(X[both, o] - X[both, q], axis=-1)) \
                    > merge_mm:
                continue
            comb = np.where(np.isfinite(X[:, o]), X[:, o], X[:, q])
            # the nearest other markers (pieces of this one excluded) as references
            dd, jj = tree.query(rest[o], k=kq)
            nbp = base[jj]
            sel = (nbp != o) & (nbp != q) & (dd > gate) & keep[nbp]
            nbp, dd = nbp[sel][:k], dd[sel][:k]
            if nbp.size == 0:
                continue
            n = nbp.size
            loc = np.concatenate([comb[:, None], X[:, nbp]], axis=1)
            nb = np.full((1 + n, n), 1 + n, np.intp)
            nb[0] = np.arange(1, 1 + n)
            w = np.zeros((1 + n, n))
            w[0] = np.exp(-((dd / spacing) ** 2))
            g = hop_segments(loc, nb, w, gate, rows=[0])[:, 0]
            # a few isolated frames off (noisy first frames of a piece) are cleared later
            if (g > 0).sum() <= 0.02 * (g >= 0).sum():
                _absorb(A, Xall, o, q)
                X[:, o] = np.where(np.isfinite(X[:, o]), X[:, o], X[:, q])
                keep[q] = False
                break


def _drop_isolated(A: dict[str, NDArray[Any]], kind: NDArray[np.int8], keep: NDArray[np.bool_],
                   P: int, factor: float = 2.5) -> None:
    """Drop found points far from every other face point.

    Two real markers matched across the cameras of one caddy make a "ghost" that moves
    smoothly like a marker but floats off the face: its typical position is several
    marker spacings from any other point, which no real marker of the set is.
    """
    face = np.flatnonzero((kind != KIND_BRIM) & keep)
    if face.size < 4 or not (face >= P).any():
        return
    X = A["positions"][:, face].astype(np.float64)
    seen = np.isfinite(X[..., 0]).any(0)
    rest = np.full((face.size, 3), np.nan)
    rest[seen] = np.nanmedian(X[:, seen], axis=0)
    ok = np.flatnonzero(seen)
    if ok.size < 4:
        return
    d, _ = cKDTree(rest[ok]).query(rest[ok], k=2)
    spacing = float(np.median(d[:, 1]))
    far = face[ok][d[:, 1] > factor * spacing]
    keep[far[far >= P]] = False
