"""Multi-view geometry of calibrated cameras: rays, epipolar geometry, triangulation.

Cameras are ``x_cam = R X + t`` (world -> camera, mm); image points are normalised
coordinates ``(x / z, y / z)`` unless a function says raw pixels. Used by the brim solve,
Initialize 3D and the processing pipeline.

Two triangulators exist on purpose and are not interchangeable:

- :func:`triangulate_tracks` (here): the linear least-squares intersection of the rays
  of detection tracks in one frame, used while tracks are being *found* (brim solve,
  Initialize 3D) where thousands of candidate tracks are scored per call;
- :func:`carapost.algorithms.triangulation.triangulate`: the robust, per-frame
  Gauss-Newton triangulation on pixel errors with outlier rejection and camera
  weighting, used on the final observations (tracking, Reconstruct).

Their results differ (a linear ray intersection is not the reprojection-error minimum),
so neither can call the other without changing every result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    cross_matrix,
    pixel_rays,
    pixels_to_normalised,
)

__all__ = [
    "camera_rays",
    "essential_matrix",
    "multiview_tracks",
    "normalised_coordinates",
    "ray_midpoints",
    "ray_residual",
    "symmetric_epipolar_distance",
    "triangulate_tracks",
]


def normalised_coordinates(det: NDArray, intr: CameraIntrinsics, c: int
                           ) -> NDArray[np.float64]:
    """Normalised image coordinates of raw pixels of one camera.

    Parameters
    ----------
    det : ndarray, shape (N, 2)
        Raw pixel positions (distorted, as detected) in camera ``c``.
    intr : CameraIntrinsics
    c : int
        Camera index.

    Returns
    -------
    ndarray, shape (N, 2)
        ``(x / z, y / z)`` of the undistorted rays in the camera frame.

    Examples
    --------
    >>> from carapost.algorithms.camera import CameraIntrinsics
    >>> intr = CameraIntrinsics(focal=[1000.0], principal_point=[[640.0, 360.0]],
    ...                         image_size=[[1280, 720]])
    >>> normalised_coordinates(np.array([[740.0, 360.0]]), intr, 0).tolist()
    [[0.1, 0.0]]
    """
    if len(det) == 0:
        return np.zeros((0, 2))
    return pixels_to_normalised(det[:, None, :], intr.subset([c]))[:, 0]


def essential_matrix(Ra: NDArray, ta: NDArray, Rb: NDArray, tb: NDArray
                     ) -> NDArray[np.float64]:
    """Essential matrix of two calibrated cameras (the fundamental matrix of normalised
    coordinates): ``xb^T E xa = 0`` for images ``xa``, ``xb`` of one point.

    Parameters
    ----------
    Ra, ta, Rb, tb : ndarray, shapes (3, 3), (3,), (3, 3), (3,)
        World -> camera poses of cameras a and b (mm).

    Returns
    -------
    ndarray, shape (3, 3)

    Examples
    --------
    >>> E = essential_matrix(np.eye(3), np.zeros(3), np.eye(3), np.array([-100.0, 0, 0]))
    >>> xa, xb = np.array([0.1, 0.2, 1.0]), np.array([-0.1, 0.2, 1.0])  # X = (50, 100, 500)
    >>> float(xb @ E @ xa)
    0.0
    """
    Rr = Rb @ Ra.T
    tr = tb - Rr @ ta
    return cross_matrix(tr) @ Rr


def symmetric_epipolar_distance(xa: NDArray, xb: NDArray, E: NDArray, fa: float, fb: float
                                ) -> NDArray[np.float64]:
    """Symmetric epipolar distance [Na, Nb] (px) between normalised points of two cameras.

    The mean of the distance of ``xb`` to the epipolar line of ``xa`` and the reverse,
    each converted to pixels with its camera's focal length.

    Parameters
    ----------
    xa : ndarray, shape (Na, 2)
    xb : ndarray, shape (Nb, 2)
        Normalised coordinates in cameras a and b.
    E : ndarray, shape (3, 3)
        :func:`essential_matrix` of the pair.
    fa, fb : float
        Focal lengths (px per normalised unit).

    Returns
    -------
    ndarray, shape (Na, Nb)

    Examples
    --------
    >>> E = essential_matrix(np.eye(3), np.zeros(3), np.eye(3), np.array([-100.0, 0, 0]))
    >>> d = symmetric_epipolar_distance(np.array([[0.1, 0.2]]),
    ...                                 np.array([[-0.1, 0.2], [-0.1, 0.21]]), E, 1000, 1000)
    >>> d.round(6).tolist()
    [[0.0, 10.0]]
    """
    ha = np.concatenate([xa, np.ones((len(xa), 1))], 1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], 1)
    la = ha @ E.T  # lines in b: l = E xa   (Na, 3)
    lb = hb @ E    # lines in a: l = E^T xb (Nb, 3)
    num = np.abs(hb @ la.T).T  # (Na, Nb) |xb^T E xa|
    da = num / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-15)[:, None] * fb
    db = num / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-15)[None, :] * fa
    return 0.5 * (da + db)


def ray_midpoints(ca: NDArray, da: NDArray, cb: NDArray, db: NDArray) -> NDArray[np.float64]:
    """Midpoints of the closest approach of ray pairs.

    Parameters
    ----------
    ca, da : ndarray, shape (N, 3)
        Origins and directions of the first rays (directions need not be unit).
    cb, db : ndarray, shape (N, 3)
        Origins and directions of the second rays.

    Returns
    -------
    ndarray, shape (N, 3)

    Examples
    --------
    >>> ray_midpoints(np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]),
    ...               np.array([[0.0, 1, 2]]), np.array([[0.0, 0, 1]])).tolist()
    [[0.0, 0.5, 0.0]]
    """
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


def camera_rays(xn: NDArray, R: NDArray, t: NDArray) -> tuple[NDArray, NDArray]:
    """World rays of normalised image points of one camera.

    Parameters
    ----------
    xn : ndarray, shape (N, 2)
        Normalised coordinates.
    R, t : ndarray, shapes (3, 3), (3,)
        World -> camera pose (mm).

    Returns
    -------
    origins : ndarray, shape (N, 3)
        The camera centre (a broadcast view).
    directions : ndarray, shape (N, 3)
        Unit directions in the world frame.

    Examples
    --------
    >>> o, d = camera_rays(np.array([[0.0, 0.0]]), np.eye(3), np.array([0.0, 0.0, 10.0]))
    >>> (o + 0.0).tolist(), d.tolist()
    ([[0.0, 0.0, -10.0]], [[0.0, 0.0, 1.0]])
    """
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
            E = essential_matrix(R[a], t[a], R[b], t[b])
            dist = symmetric_epipolar_distance(dets_n[a], dets_n[b], E, focal[a], focal[b])
            dist[~usable[a]] = np.inf
            dist[:, ~usable[b]] = np.inf
            ia, ib = np.nonzero(dist < max_px)
            if ia.size == 0:
                continue
            ca, da = camera_rays(dets_n[a][ia], R[a], t[a])
            cb, db = camera_rays(dets_n[b][ib], R[b], t[b])
            X = ray_midpoints(ca, da, cb, db)
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
        _, d = camera_rays(xn[m, c], R[c], t[c])
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
        _, d = camera_rays(xn[m, c], R[c], t[c])
        v = X[m] - centres[c]
        perp = v - (v * d).sum(1, keepdims=True) * d
        d2[m] += (perp**2).sum(1)
        p = X[m] @ R[c].T + t[c]
        proj = p[:, :2] / p[:, 2:3]
        e2[m] += (((proj - xn[m, c]) * focal[c]) ** 2).sum(1)
    res[ok] = np.sqrt(d2[ok] / n[ok])
    rep[ok] = np.sqrt(e2[ok] / n[ok])
    return X, res, rep


def ray_residual(X: ArrayLike, obs: ArrayLike, R: ArrayLike, t: ArrayLike,
                 intr: CameraIntrinsics) -> NDArray[np.float64]:
    """RMS distance of points to the rays of their raw pixel observations.

    Parameters
    ----------
    X : array_like, shape (P, 3)
        Points (mm).
    obs : array_like, shape (P, C, 2)
        Raw pixel observations; NaN where a camera does not see a point.
    R, t : array_like, shapes (C, 3, 3), (C, 3)
        Cameras (world -> camera, mm).
    intr : CameraIntrinsics

    Returns
    -------
    ndarray, shape (P,)
        RMS over the observing cameras of the perpendicular distance (mm); NaN for a
        point seen by no camera.

    Examples
    --------
    >>> intr = CameraIntrinsics(focal=[1000.0], principal_point=[[640.0, 360.0]],
    ...                         image_size=[[1280, 720]])
    >>> R, t = np.eye(3)[None], np.zeros((1, 3))
    >>> ray_residual(np.array([[0.0, 3.0, 500.0]]), np.array([[[640.0, 360.0]]]), R, t,
    ...              intr).round(9).tolist()
    [3.0]
    """
    X = np.asarray(X, dtype=np.float64)
    obs = np.asarray(obs, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    o, d = pixel_rays(obs, R[None], t[None], intr)  # (P, C, 3)
    v = X[:, None, :] - o
    perp = v - (v * d).sum(-1, keepdims=True) * d
    d2 = (perp**2).sum(-1)
    ok = np.isfinite(d2)
    n = ok.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.sqrt(np.where(ok, d2, 0.0).sum(1) / n)
    out[n < 1] = np.nan
    return out
