"""Initialize 3D: match the face detections of one frame across cameras and triangulate.

The cameras are known (solved from the brim) and a few seed markers may have been matched
by hand. Following the reference guide's outline, in our own formulation:

1. Brim dots and detections in the brim's image region are left out.
2. For each caddy pair (two neighbouring cameras on one side of the face; the caller
   says which, see `carapost.model.rig.caddies`), every detection pair
   within the Max Allowed Symmetric Epipolar Distance is a candidate; all candidates are
   triangulated at once (an ``[Na, Nb]`` distance matrix per caddy). Starting from the
   seeds, candidates are accepted in rounds: a candidate must lie within Max Allowed
   Depth of an already accepted 3D point (so the set grows outwards over the face), lie
   near the local surface spanned by its nearest accepted points (our addition, which
   stops a wrong pairing along an epipolar line from passing as a new marker), and be
   the only valid candidate of both its detections. Rounds repeat until nothing new.
3. The points of the caddy pairs closer than Max 3D Distance To Merge are merged.
4. Beyond the reference: every point is projected into the cameras that do not see it
   yet and takes an unambiguous detection there; leftover detections of every camera
   pair that is not a caddy pair are paired the same way as in step 2 (markers seen by
   one camera of each caddy only, or by two non-neighbouring cameras of one caddy).
5. All points are re-triangulated from all their detections and, when the brim is
   given, the frame is bundle adjusted with the brim dots fixed.

With no seeds and a good calibration, seeds are found automatically: detections that
agree across all four cameras (three epipolar-consistent views confirmed by a fourth)
are unambiguous enough to start from, so a take can be initialised with no clicks.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.multiview import (
    camera_rays,
    essential_matrix,
    multiview_tracks,
    normalised_coordinates,
    ray_midpoints,
    symmetric_epipolar_distance,
    triangulate_tracks,
)
from carapost.algorithms.params import INITIALIZE_3D, param, validate

log = logging.getLogger("carapost.init3d")

__all__ = ["Init3DParameters", "Init3DResult", "initialize_3d", "triangulate_tracks"]


@dataclass(frozen=True)
class Init3DParameters:
    """Parameters of :func:`initialize_3d` (the first three are the Initialize 3D section).

    Attributes
    ----------
    max_3d_distance_to_merge : float
        Points of the two caddies closer than this (mm) are the same marker.
    max_allowed_depth : float
        A new point must lie within this distance (mm) of an accepted point: the growth
        radius (lower for dense marker sets, higher for sparse ones).
    max_symmetric_epipolar_distance : float
        Largest symmetric epipolar distance (px) of a detection pair of one caddy.
    max_surface_distance : float
        A new point must lie within this distance (mm) of the plane through its nearest
        accepted points (our addition, off by default: faces curve too much between
        sparse markers for a plane to be a reliable guide; 0 disables the test).
    max_reprojection_px : float
        A point takes a detection of another camera within this distance of its
        projection (px).
    ambiguity_ratio : float
        When extending a point to another camera, the second-nearest detection must be
        this many times further than the nearest.
    auto_seeds : bool
        Find seeds automatically (4-view matches) when none are given.
    cross_caddy : bool
        Run step 4 (extension to other cameras and cross-caddy pairs).
    bundle_adjust : bool
        Bundle adjust at the end (needs the brim dots to fix the frame).
    min_auto_seeds : int
        Fewest automatic seeds for the automatic start to proceed.
    epipolar_noise_factor : float
        A new match must lie within this many times the seeds' RMS epipolar distance of
        its epipolar line (our addition: rivals within Max Allowed Symmetric Epipolar
        Distance still make a match ambiguous, but the winner must fit as well as the
        seeds do, which rejects a wrong partner when the true one is hidden).
    min_strict_epipolar_px : float
        Lower bound of that tolerance (px).
    surface_tiebreak : bool
        When no unambiguous candidate is left, let candidates that lie on the surface of
        their accepted neighbours win over rivals far off it (our addition).
    max_range : float
        Candidates further than this from a camera (mm) are not markers of the face.
    reach_steps : tuple of float
        When growth stops, it resumes with the reach widened to these multiples of Max
        Allowed Depth, for candidates that are unambiguous by ``reach_ambiguity_ratio``
        (our addition: a cluster of markers seen by one caddy only, such as the side of the
        nose in a dense set, can lie slightly further than Max Allowed Depth from every
        accepted point; () disables it).
    reach_ambiguity_ratio : float
        Ambiguity ratio required while the reach is widened.
    """

    # the Initialize 3D Parameters section, in the guide's order
    max_allowed_depth: float = param(
        35.0, label="Max Allowed Depth", section=INITIALIZE_3D, unit="mm",
        # no upper bound: the reach steps below multiply it, so a cap would be hit inside
        # initialize_3d rather than when the value is set
        min=0.0, min_exclusive=True,
        help="How far a newly initialised point may lie from an existing point; a little "
             "more than the widest marker spacing (lower it for dense marker sets).")
    max_3d_distance_to_merge: float = param(
        5.0, label="Max 3D Distance To Merge", section=INITIALIZE_3D, unit="mm",
        min=0.0, min_exclusive=True, max=100.0,
        help="Points from the two caddies closer than this are treated as the same marker. "
             "Upper bound is our choice.")
    max_symmetric_epipolar_distance: float = param(
        5.0, label="Max Allowed Symmetric Epipolar Distance", section=INITIALIZE_3D,
        unit="px", min=0.0, min_exclusive=True, max=100.0,
        help="Largest epipolar error allowed when pairing detections of the two cameras of "
             "one caddy. Upper bound is our choice.")
    # internal tunables
    max_surface_distance: float = param(0.0, min=0.0)
    max_reprojection_px: float = param(3.0, min=0.0, min_exclusive=True)
    ambiguity_ratio: float = param(2.0, min=1.0)
    auto_seeds: bool = True
    cross_caddy: bool = True
    bundle_adjust: bool = True
    min_auto_seeds: int = 3
    epipolar_noise_factor: float = 4.0
    min_strict_epipolar_px: float = 0.5
    surface_tiebreak: bool = True
    max_range: float = 600.0
    reach_steps: tuple[float, ...] = param((1.5, 2.0), min=1.0)
    reach_ambiguity_ratio: float = param(4.0, min=1.0)

    def __post_init__(self) -> None:
        validate(self)


@dataclass
class Init3DResult:
    """Outcome of :func:`initialize_3d`.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        3D positions (mm); the first ``n_seeds`` rows are the seeds, in the given order.
    detections : ndarray of int, shape (N, C)
        Detection index of each point in each camera, -1 where not attached.
    residual : ndarray, shape (N,)
        RMS distance of each point to its rays (mm).
    reprojection_px : ndarray, shape (N,)
        RMS reprojection error of each point (px).
    n_seeds : int
        Number of seed rows (given or automatic).
    R, t : ndarray, shapes (C, 3, 3), (C, 3)
        Cameras after the final bundle adjustment (the input ones when not run).
    success : bool
    message : str
    """

    points: NDArray[np.float64]
    detections: NDArray[np.intp]
    residual: NDArray[np.float64]
    reprojection_px: NDArray[np.float64]
    n_seeds: int
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    success: bool
    message: str


def _surface_distance(X: NDArray, existing: NDArray, k: int = 6) -> NDArray[np.float64]:
    """Distance (mm) of candidate points to the plane through their k nearest existing
    points; +inf when fewer than 3 existing points are near (within the growth radius is
    checked separately)."""
    if len(existing) < 3 or len(X) == 0:
        return np.zeros(len(X))
    k = min(k, len(existing))
    d = np.linalg.norm(X[:, None] - existing[None], axis=-1)
    nn = np.argpartition(d, k - 1, axis=1)[:, :k]
    Q = existing[nn]  # (K, k, 3)
    c = Q.mean(1)
    _, _, Vt = np.linalg.svd(Q - c[:, None])
    normal = Vt[:, 2]
    return np.abs(((X - c) * normal).sum(1))


class _State:
    """Accepted points (tracks [N, C]) and the detections they use."""

    def __init__(self, dets_n: Sequence[NDArray]) -> None:
        C = len(dets_n)
        self.tracks = np.zeros((0, C), dtype=np.intp)
        self.X = np.zeros((0, 3))
        self.used = [np.zeros(len(d), dtype=bool) for d in dets_n]

    def add(self, tracks: NDArray, X: NDArray) -> None:
        self.tracks = np.concatenate([self.tracks, tracks])
        self.X = np.concatenate([self.X, X])
        for c in range(tracks.shape[1]):
            k = tracks[:, c]
            self.used[c][k[k >= 0]] = True


def _grow_pair(a: int, b: int, dets_n: Sequence[NDArray], usable: list[NDArray],
               R: NDArray, t: NDArray, focal: NDArray, start_X: NDArray,
               params: Init3DParameters, strict: float) -> tuple[NDArray, NDArray]:
    """Grow matches between cameras a and b from the points ``start_X``.

    Candidates within Max Allowed Symmetric Epipolar Distance compete; a winner must be
    within ``strict`` px of the epipolar line (the tolerance learnt from the seeds).

    Returns new tracks [K, C] (views a and b) and their points [K, 3].
    """
    C = len(dets_n)
    empty = (np.zeros((0, C), dtype=np.intp), np.zeros((0, 3)))
    if not usable[a].any() or not usable[b].any() or len(start_X) == 0:
        return empty
    E = essential_matrix(R[a], t[a], R[b], t[b])
    dist = symmetric_epipolar_distance(dets_n[a], dets_n[b], E, focal[a], focal[b])
    dist[~usable[a]] = np.inf
    dist[:, ~usable[b]] = np.inf
    ia, ib = np.nonzero(dist < params.max_symmetric_epipolar_distance)
    if ia.size == 0:
        return empty
    ca, da = camera_rays(dets_n[a][ia], R[a], t[a])
    cb, db = camera_rays(dets_n[b][ib], R[b], t[b])
    X = ray_midpoints(ca, da, cb, db)
    sa, sb = ((X - ca) * da).sum(1), ((X - cb) * db).sum(1)
    front = (sa > 0) & (sb > 0) & (sa < params.max_range) & (sb < params.max_range)
    ia, ib, X = ia[front], ib[front], X[front]
    e = dist[ia, ib]
    alive = np.ones(len(X), dtype=bool)
    existing = start_X.copy()
    new_a, new_b, new_X = [], [], []
    Na, Nb = len(dets_n[a]), len(dets_n[b])
    while alive.any():
        cand = np.flatnonzero(alive)
        near = np.linalg.norm(X[cand, None] - existing[None], axis=-1).min(1)
        ok = near <= params.max_allowed_depth
        if params.max_surface_distance > 0 and ok.any():
            sd = _surface_distance(X[cand[ok]], existing)
            ok[np.flatnonzero(ok)] = sd <= params.max_surface_distance
        valid = cand[ok]
        if valid.size == 0:
            break
        # unambiguous: the best candidate of both of its detections, within the strict
        # tolerance, with every rival of either detection clearly worse. Rivals count
        # whether or not they are in reach yet: a wrong pair must not win just because
        # the right one is still out of reach.
        ev = e[cand]
        best_a = np.full(Na, np.inf)
        np.minimum.at(best_a, ia[cand], ev)
        best_b = np.full(Nb, np.inf)
        np.minimum.at(best_b, ib[cand], ev)
        is_best = (ev <= best_a[ia[cand]]) & (ev <= best_b[ib[cand]])
        sec_a = np.full(Na, np.inf)
        np.minimum.at(sec_a, ia[cand], np.where(ev <= best_a[ia[cand]], np.inf, ev))
        sec_b = np.full(Nb, np.inf)
        np.minimum.at(sec_b, ib[cand], np.where(ev <= best_b[ib[cand]], np.inf, ev))
        # two candidates tied at the best value are ambiguous
        tie_a = np.bincount(ia[cand][ev <= best_a[ia[cand]]], minlength=Na) > 1
        tie_b = np.bincount(ib[cand][ev <= best_b[ib[cand]]], minlength=Nb) > 1
        margin = np.maximum(params.ambiguity_ratio * ev, strict)
        win = (is_best & (ev <= strict) & (sec_a[ia[cand]] >= margin)
               & (sec_b[ib[cand]] >= margin) & ~tie_a[ia[cand]] & ~tie_b[ib[cand]])
        acc = cand[win & ok]
        if acc.size == 0 and params.surface_tiebreak and len(existing) >= 3:
            close = ev <= strict
            acc = _surface_tiebreak(cand[close], ok[close], ia, ib, X, existing, Na, Nb)
        if acc.size == 0:
            break
        new_a.append(ia[acc])
        new_b.append(ib[acc])
        new_X.append(X[acc])
        existing = np.concatenate([existing, X[acc]])
        taken_a = np.isin(ia, ia[acc])
        taken_b = np.isin(ib, ib[acc])
        alive &= ~(taken_a | taken_b)
    if not new_a:
        return empty
    ka, kb = np.concatenate(new_a), np.concatenate(new_b)
    tracks = np.full((len(ka), C), -1, dtype=np.intp)
    tracks[:, a], tracks[:, b] = ka, kb
    return tracks, np.concatenate(new_X)


def _surface_tiebreak(cand: NDArray, in_reach: NDArray, ia: NDArray, ib: NDArray, X: NDArray,
                      existing: NDArray, Na: int, Nb: int) -> NDArray[np.intp]:
    """Resolve candidates that the epipolar constraint cannot (markers on one epipolar
    line): the one much closer to the surface of its accepted neighbours wins.

    A candidate is taken when its distance to the local plane is at most 3 mm and every
    rival sharing one of its detections is at least 3 times (and 4 mm) further away;
    ``in_reach`` marks the candidates within Max Allowed Depth (rivals need not be)."""
    if cand.size == 0:
        return cand
    sd = _surface_distance(X[cand], existing)
    best_a = np.full(Na, np.inf)
    np.minimum.at(best_a, ia[cand], sd)
    best_b = np.full(Nb, np.inf)
    np.minimum.at(best_b, ib[cand], sd)
    is_best = (sd <= best_a[ia[cand]]) & (sd <= best_b[ib[cand]]) & (sd <= 3.0)
    other_a = np.where(is_best, np.inf, sd)
    sec_a = np.full(Na, np.inf)
    np.minimum.at(sec_a, ia[cand], other_a)
    sec_b = np.full(Nb, np.inf)
    np.minimum.at(sec_b, ib[cand], other_a)
    need = np.maximum(3.0 * sd, sd + 4.0)
    ok = is_best & in_reach & (sec_a[ia[cand]] >= need) & (sec_b[ib[cand]] >= need)
    acc = cand[ok]
    # one winner per detection
    ua, ca = np.unique(ia[acc], return_counts=True)
    ub, cb = np.unique(ib[acc], return_counts=True)
    keep = np.isin(ia[acc], ua[ca == 1]) & np.isin(ib[acc], ub[cb == 1])
    return acc[keep]


def _strict_epipolar(tracks: NDArray, dets_n: Sequence[NDArray], R: NDArray, t: NDArray,
                     focal: NDArray, caddies: Sequence[tuple[int, int]],
                     params: Init3DParameters) -> float:
    """Epipolar tolerance (px) a new match must meet: a multiple of the seeds' own
    epipolar scatter (it measures calibration and detection noise), within
    [min_strict_epipolar_px, Max Allowed Symmetric Epipolar Distance]. The scatter is
    the RMS, or 1.4826 x the median distance when that is smaller: one hand seed on a
    biased blob (0.8 px off among seeds at 0.02 px) must not loosen the tolerance for
    every match that follows (looser tolerances make more candidate pairs ambiguous)."""
    e = []
    for a, b in caddies:
        m = (tracks[:, a] >= 0) & (tracks[:, b] >= 0)
        if not m.any():
            continue
        E = essential_matrix(R[a], t[a], R[b], t[b])
        d = symmetric_epipolar_distance(dets_n[a][tracks[m, a]], dets_n[b][tracks[m, b]], E,
                                        focal[a], focal[b])
        e.append(np.diag(d))
    if not e:
        return params.max_symmetric_epipolar_distance
    e = np.concatenate(e)
    scatter = min(float(np.sqrt(np.mean(e ** 2))), 1.4826 * float(np.median(e)))
    return float(np.clip(params.epipolar_noise_factor * scatter, params.min_strict_epipolar_px,
                         params.max_symmetric_epipolar_distance))


def _extend_to_cameras(state: _State, dets_n: Sequence[NDArray], usable: list[NDArray],
                       R: NDArray, t: NDArray, focal: NDArray, params: Init3DParameters
                       ) -> int:
    """Give every point the unambiguous detections it projects onto in cameras that do
    not see it yet. Returns the number of detections attached."""
    C = len(dets_n)
    added = 0
    for c in range(C):
        free = usable[c] & ~state.used[c]
        rows = np.flatnonzero(state.tracks[:, c] < 0)
        if not free.any() or rows.size == 0:
            continue
        p = state.X[rows] @ R[c].T + t[c]
        front = p[:, 2] > 0
        proj = p[:, :2] / np.where(front, p[:, 2], 1.0)[:, None]
        d = np.linalg.norm(proj[:, None] - dets_n[c][None], axis=-1) * focal[c]
        d[:, ~free] = np.inf
        d[~front] = np.inf
        # every point's projection (with or without a view) competes for a detection, so
        # a detection that lies between two projected markers is left alone
        pall = state.X @ R[c].T + t[c]
        fall = pall[:, 2] > 0
        projall = pall[:, :2] / np.where(fall, pall[:, 2], 1.0)[:, None]
        dall = np.linalg.norm(projall[:, None] - dets_n[c][None], axis=-1) * focal[c]
        dall[~fall] = np.inf
        k = np.argmin(d, axis=1)
        dk = d[np.arange(len(rows)), k]
        ds = np.sort(d, axis=1)
        second = ds[:, 1] if d.shape[1] > 1 else np.full(len(rows), np.inf)
        col = np.sort(dall[:, k], axis=0)  # distances of all points to the chosen detection
        col_second = col[1] if len(dall) > 1 else np.full(len(rows), np.inf)
        ok = ((dk <= params.max_reprojection_px) & (second >= params.ambiguity_ratio * dk)
              & (col_second >= params.ambiguity_ratio * np.maximum(dk, 0.5)))
        # one detection, one point
        kk = k[ok]
        uniq, cnt = np.unique(kk, return_counts=True)
        ok[np.flatnonzero(ok)] = np.isin(kk, uniq[cnt == 1])
        state.tracks[rows[ok], c] = k[ok]
        state.used[c][k[ok]] = True
        added += int(ok.sum())
    return added


def _merge_caddies(tA: NDArray, XA: NDArray, tB: NDArray, XB: NDArray, distance: float
                   ) -> tuple[NDArray, NDArray]:
    """Merge mutual-nearest points of two sets closer than ``distance`` (mm)."""
    if len(tA) == 0 or len(tB) == 0:
        return np.concatenate([tA, tB]), np.concatenate([XA, XB])
    d = np.linalg.norm(XA[:, None] - XB[None], axis=-1)
    j = np.argmin(d, axis=1)
    i_back = np.argmin(d, axis=0)
    pair = (d[np.arange(len(XA)), j] <= distance) & (i_back[j] == np.arange(len(XA)))
    ia = np.flatnonzero(pair)
    jb = j[pair]
    # views must not conflict (a seed point is in both sets with the same detections)
    ta, tb = tA[ia], tB[jb]
    conflict = ((ta >= 0) & (tb >= 0) & (ta != tb)).any(1)
    ia, jb = ia[~conflict], jb[~conflict]
    merged = np.where(tA[ia] >= 0, tA[ia], tB[jb])
    keepA = np.ones(len(tA), dtype=bool)
    keepB = np.ones(len(tB), dtype=bool)
    keepA[ia] = False
    keepB[jb] = False
    tracks = np.concatenate([merged, tA[keepA], tB[keepB]])
    X = np.concatenate([0.5 * (XA[ia] + XB[jb]), XA[keepA], XB[keepB]])
    return tracks, X


def _merge_close(state: _State, distance: float) -> None:
    """Merge points of the state closer than ``distance`` whose views do not conflict
    (a marker found by one caddy in one round and by the other caddy later)."""
    while len(state.X) > 1:
        d = np.linalg.norm(state.X[:, None] - state.X[None], axis=-1)
        np.fill_diagonal(d, np.inf)
        tr = state.tracks
        both = (tr[:, None, :] >= 0) & (tr[None, :, :] >= 0)
        conflict = (both & (tr[:, None, :] != tr[None, :, :])).any(-1)
        d[conflict] = np.inf
        j = np.argmin(d, axis=1)
        i = np.arange(len(d))
        pair = (d[i, j] <= distance) & (j[j] == i) & (i < j)
        if not pair.any():
            return
        a, b = i[pair], j[pair]
        tr[a] = np.where(tr[a] >= 0, tr[a], tr[b])
        state.X[a] = 0.5 * (state.X[a] + state.X[b])
        keep = np.ones(len(tr), dtype=bool)
        keep[b] = False
        state.tracks, state.X = tr[keep], state.X[keep]


def _fail(C: int, R: NDArray, t: NDArray, message: str) -> Init3DResult:
    log.warning("%s", message)
    return Init3DResult(np.zeros((0, 3)), np.zeros((0, C), dtype=np.intp), np.zeros(0),
                        np.zeros(0), 0, R, t, False, message)


def initialize_3d(
    detections_per_camera: Sequence[ArrayLike],
    R: ArrayLike,
    t: ArrayLike,
    intr: CameraIntrinsics,
    *,
    caddies: Sequence[tuple[int, int]],
    seeds: Sequence[Sequence[int]] | None = None,
    exclude_mask: Sequence[ArrayLike] | None = None,
    params: Init3DParameters | None = None,
    brim_model: ArrayLike | None = None,
    brim_detections: ArrayLike | None = None,
) -> Init3DResult:
    """Initialise the face markers of one frame.

    Parameters
    ----------
    detections_per_camera : sequence of array_like, each shape (N_c, 2)
        Detection centres (raw px) of the frame, per camera.
    R, t : array_like, shapes (C, 3, 3), (C, 3)
        Solved cameras (brim frame, mm).
    intr : CameraIntrinsics
    caddies : sequence of (int, int)
        Camera pairs grown in step 2: neighbouring cameras of one caddy. There is no
        default (the rig decides); `carapost.model.rig.caddies` derives them from the
        take, e.g. ``((0, 1), (2, 3))`` for a four-camera rig.
    seeds : sequence of per-camera detection index tuples, optional
        Hand-matched markers: ``seeds[k][c]`` is the detection of seed ``k`` in camera
        ``c`` or -1. Each needs at least two cameras. None (or empty) with
        ``params.auto_seeds`` finds seeds automatically.
    exclude_mask : sequence of bool arrays (N_c,), optional
        Detections that are not face markers (brim dots and the brim region).
    params : Init3DParameters, optional
    brim_model : array_like, shape (B, 3), optional
        With ``brim_detections``, lets the final bundle adjustment refine the cameras
        with the brim dots fixed.
    brim_detections : array_like of int, shape (B, C), optional
        Detection index of each brim dot per camera (-1 where unmatched).

    Returns
    -------
    Init3DResult
        ``success`` False with the reason in ``message`` for degenerate seeds, cameras
        without detections or no seed found; ``ValueError`` only for wrong shapes.
    """
    params = params or Init3DParameters()
    C = intr.n_cameras
    R = np.asarray(R, dtype=np.float64).reshape(C, 3, 3).copy()
    t = np.asarray(t, dtype=np.float64).reshape(C, 3).copy()
    names = list(intr.names)
    if len(detections_per_camera) != C:
        raise ValueError(f"detections_per_camera has {len(detections_per_camera)} cameras, "
                         f"the intrinsics {C}")
    dets = [np.asarray(d, dtype=np.float64).reshape(-1, 2) for d in detections_per_camera]
    usable = [np.ones(len(d), dtype=bool) for d in dets]
    if exclude_mask is not None:
        for c in range(C):
            m = np.asarray(exclude_mask[c], dtype=bool).reshape(-1)
            if m.shape != (len(dets[c]),):
                raise ValueError(f"exclude_mask[{c}] has {m.size} entries, camera {c} has "
                                 f"{len(dets[c])} detections")
            usable[c] = ~m
    what = "Initialize 3D"
    empty = [names[c] for c in range(C) if not usable[c].any()]
    if len(empty) == C:
        return _fail(C, R, t, f"{what}: no face detections in any camera (run Detect Blobs)")
    if empty:
        log.warning("%s: no face detections in camera(s) %s", what, ", ".join(empty))
    for a, b in caddies:
        if not (0 <= a < C and 0 <= b < C and a != b):
            raise ValueError(f"caddy ({a}, {b}) is not a pair of cameras 0-{C - 1}")
    dets_n = [normalised_coordinates(dets[c], intr, c) for c in range(C)]
    focal = intr.focal
    state = _State(dets_n)

    # ---- seeds ---------------------------------------------------------------------------
    if seeds:
        st = np.full((len(seeds), C), -1, dtype=np.intp)
        for k, s in enumerate(seeds):
            s = list(s)
            if len(s) != C:
                return _fail(C, R, t, f"{what}: seed {k} has {len(s)} entries, one per camera "
                                      f"({C}) is needed")
            for c, i in enumerate(s):
                i = int(i)
                if i < -1 or i >= len(dets[c]):
                    return _fail(C, R, t, f"{what}: seed {k} refers to detection {i} of "
                                          f"camera {names[c]}, which has {len(dets[c])}")
                st[k, c] = i
            if (st[k] >= 0).sum() < 2:
                return _fail(C, R, t, f"{what}: seed {k} is attached in "
                                      f"{int((st[k] >= 0).sum())} camera(s); a seed needs "
                                      "two or more")
        for c in range(C):
            used = st[st[:, c] >= 0, c]
            if len(np.unique(used)) != len(used):
                return _fail(C, R, t, f"{what}: two seeds use the same detection of camera "
                                      f"{names[c]}")
        X, _, rep = triangulate_tracks(st, dets_n, R, t, focal)
        bad = np.flatnonzero(~np.isfinite(rep) | (rep > 3 * params.max_symmetric_epipolar_distance))
        if bad.size:
            return _fail(C, R, t, f"{what}: seed(s) {', '.join(map(str, bad))} do not match "
                                  "across their cameras (reprojection error "
                                  f"{', '.join(f'{rep[i]:.1f}' for i in bad)} px); check the "
                                  "seed detections and the calibration")
        state.add(st, X)
        n_seeds = len(st)
        seed_kind = "seeds"
    elif params.auto_seeds:
        tracks, X = multiview_tracks(dets_n, R, t, focal,
                                     min(2.0, params.max_symmetric_epipolar_distance),
                                     min_views=min(4, C), excluded=[~u for u in usable],
                                     max_range=params.max_range)
        if len(tracks) < params.min_auto_seeds:
            return _fail(C, R, t, f"{what}: found {len(tracks)} automatic seed(s) (markers "
                                  f"matched in all {min(4, C)} cameras), at least "
                                  f"{params.min_auto_seeds} are needed; add seeds by hand or "
                                  "check the calibration")
        X, _, _ = triangulate_tracks(tracks, dets_n, R, t, focal)
        state.add(tracks, X)
        n_seeds = len(tracks)
        seed_kind = "automatic seeds"
    else:
        return _fail(C, R, t, f"{what}: no seed points (match a few markers by hand)")

    strict = _strict_epipolar(state.tracks, dets_n, R, t, focal, caddies, params)

    # ---- grow per caddy, merge ---------------------------------------------------------------
    def grow_caddies() -> None:
        free = [usable[c] & ~state.used[c] for c in range(C)]
        sets = [_grow_pair(a, b, dets_n, free, R, t, focal, state.X, params, strict)
                for a, b in caddies]
        if sets:
            tr, X = sets[0]
            for tr2, X2 in sets[1:]:
                tr, X = _merge_caddies(tr, X, tr2, X2, params.max_3d_distance_to_merge)
            state.add(tr, X)
        _merge_close(state, params.max_3d_distance_to_merge)

    grow_caddies()
    if seeds and params.auto_seeds:
        # beyond the reference: markers out of reach of the hand seeds (further than Max
        # Allowed Depth from any point) start from 4-view matches, then growth resumes
        tracks, X = multiview_tracks(dets_n, R, t, focal, min(2.0 * strict, 2.0),
                                     min_views=min(4, C),
                                     excluded=[~(usable[c] & ~state.used[c]) for c in range(C)],
                                     max_range=params.max_range)
        if len(tracks):
            X, _, _ = triangulate_tracks(tracks, dets_n, R, t, focal)
            state.add(tracks, X)
            grow_caddies()

    # ---- beyond the reference: other cameras, cross-caddy pairs ------------------------------
    if params.cross_caddy:
        _extend_to_cameras(state, dets_n, usable, R, t, focal, params)
        # every camera pair that step 2 did not grow; a set of pairs, not a camera ->
        # caddy map, because neighbouring pairs of a three-camera caddy share a camera
        grown = {frozenset(pair) for pair in caddies}
        for a in range(C):
            for b in range(a + 1, C):
                if frozenset((a, b)) in grown:
                    continue
                free = [usable[c] & ~state.used[c] for c in range(C)]
                tr, X = _grow_pair(a, b, dets_n, free, R, t, focal, state.X, params, strict)
                if len(tr):
                    state.add(tr, X)
        _extend_to_cameras(state, dets_n, usable, R, t, focal, params)

    # ---- beyond the reference: widen the reach for clean, isolated clusters ------------------
    base = params
    for k in params.reach_steps:
        n_before = len(state.X)
        params = replace(base, max_allowed_depth=k * base.max_allowed_depth,
                         ambiguity_ratio=max(base.ambiguity_ratio, base.reach_ambiguity_ratio))
        grow_caddies()
        if params.cross_caddy and len(state.X) > n_before:
            _extend_to_cameras(state, dets_n, usable, R, t, focal, params)
    params = base

    _merge_close(state, params.max_3d_distance_to_merge)

    # ---- final triangulation and bundle ------------------------------------------------------
    X, res, rep = triangulate_tracks(state.tracks, dets_n, R, t, focal)
    msg_bundle = ""
    if params.bundle_adjust and brim_model is not None and brim_detections is not None:
        from carapost.algorithms.bundle import BUNDLE_OPTIONS, bundle_frame

        model = np.asarray(brim_model, dtype=np.float64).reshape(-1, 3)
        bd = np.asarray(brim_detections, dtype=np.intp).reshape(len(model), C)
        rows = np.concatenate([bd, state.tracks])
        obs = np.full(rows.shape + (2,), np.nan)
        for c in range(C):
            m = rows[:, c] >= 0
            obs[m, c] = dets[c][rows[m, c]]
        fixed = np.zeros(len(rows), dtype=bool)
        fixed[: len(model)] = True
        bres = bundle_frame(obs, np.concatenate([model, X]), R, t, intr,
                            fixed_points_mask=fixed, loss="huber", f_scale=1.0, max_nfev=50,
                            **BUNDLE_OPTIONS)
        if np.isfinite(bres.rms_after) and bres.rms_after <= bres.rms_before + 1e-9:
            R, t = bres.R, bres.t
            X, res, rep = triangulate_tracks(state.tracks, dets_n, R, t, focal)
            msg_bundle = (f"; bundle adjusted {bres.rms_before:.3f} -> {bres.rms_after:.3f} "
                          "px")
    views = (state.tracks >= 0).sum(1)
    msg = (f"{what}: {len(X)} points ({n_seeds} {seed_kind}, {len(X) - n_seeds} new), "
           f"{int((views >= 3).sum())} in 3+ cameras, median reprojection "
           f"{np.nanmedian(rep) if len(rep) else float('nan'):.2f} px{msg_bundle}")
    log.info("%s", msg)
    return Init3DResult(X, state.tracks.copy(), res, rep, n_seeds, R, t, True, msg)
