"""The image of a brim dot is not centred on the image of the dot's centre.

A brim dot is a flat disc. Seen at an angle, its image is an ellipse whose centre (where
the blob detector puts the blob's centroid) lies off the projection of the disc's centre,
towards the nearer half of the disc: the nearer half is magnified more. The offset grows
with the square of the disc's radius over its distance and with the tilt; for dots of
2.5 mm radius at 100-150 mm it is 0.03-0.09 px, the same for a dot in every frame, while
the blob centroid's noise is ~0.03 px. Solving the cameras from the uncorrected centroids
puts that systematic error into every frame's poses: on rendered takes of other rigs it
moved the points seen by all four cameras by ~0.05 mm as a whole (docs/benchmarks.md,
"Brim dots seen at an angle").

:func:`disc_image_offsets` gives the offset in closed form: with the disc's centre
``X``, unit normal ``n`` and radius ``r`` in the camera frame, the image conic's centre is
the homogeneous point ``r^2 (e_z - n n_z) - X X_z`` (the pole of the line at infinity of
the conic ``H^-T diag(1, 1, -1) H^-1``, ``H = [r u, r v, X]`` with ``u, v`` spanning the
disc's plane), and the projection of the centre is ``X / X_z``; lens distortion is
applied to both. What it needs beyond the brim model (the dots' centres) is estimated
from the take: the dots' normals from the model's shape (:func:`brim_dot_normals`, a
smooth surface through the dots) and their radius from the detected blobs' semi-major
axes (:func:`estimate_dot_radius`). :func:`unbias_brim_cameras` re-solves every frame's
cameras with the corrected centroids.

Units: mm in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``B`` brim dots, ``C`` cameras.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    distort_pixels,
    pixels_to_normalised,
)
from carapost.algorithms.pose import refine_poses

__all__ = [
    "BrimDiscCorrection",
    "brim_dot_normals",
    "disc_image_offsets",
    "disc_semi_axes",
    "estimate_dot_radius",
    "unbias_brim_cameras",
]

#: Fewest blobs of a dot for a radius of its own (fewer: the brim's median radius).
MIN_RADIUS_SAMPLES = 5
#: Frames of a long take whose blobs are used to estimate the radii (evenly spread).
RADIUS_FRAMES = 200
#: Frames re-solved together (bounds the solver's memory: ~1.4 KB per camera-frame and
#: dot).
CHUNK_FRAMES = 1024


class BrimDiscCorrection(NamedTuple):
    """Result of :func:`unbias_brim_cameras`.

    Attributes
    ----------
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
        Poses re-solved from the corrected centroids (frames kept or with too few dots
        unchanged).
    obs : ndarray, shape (F, B, C, 2)
        The brim observations less their offsets (raw px): where the centroid of an
        unbiased dot would be.
    normals : ndarray, shape (B, 3)
        The dots' unit normals used (towards the cameras).
    radius : ndarray, shape (B,)
        The dots' radii used (mm).
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    obs: NDArray[np.float64]
    normals: NDArray[np.float64]
    radius: NDArray[np.float64]


def _camera_frame(X: NDArray, normals: NDArray, R: NDArray, t: NDArray
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Disc centres and normals in every camera frame, (F, B, C, 3) each."""
    Xc = np.einsum("fcij,bj->fbci", R, X) + t[:, None, :, :]
    nc = np.einsum("fcij,bj->fbci", R, normals)
    return Xc, nc


def disc_image_offsets(X: ArrayLike, normals: ArrayLike, radius: ArrayLike, R: ArrayLike,
                       t: ArrayLike, intr: CameraIntrinsics) -> NDArray[np.float64]:
    """Offset of each disc's image centroid from the image of its centre.

    Parameters
    ----------
    X : array_like, shape (B, 3)
        Disc centres (mm, world frame).
    normals : array_like, shape (B, 3)
        Unit normals of the discs (world frame; either sign).
    radius : array_like, shape (B,) or scalar
        Disc radii (mm).
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
        World->camera poses.
    intr : CameraIntrinsics
        Intrinsics of the ``C`` cameras.

    Returns
    -------
    ndarray, shape (F, B, C, 2)
        Centroid minus projected centre (raw px); NaN behind a camera or where a pose is
        NaN.

    Examples
    --------
    A disc of radius 2.5 mm facing the camera has no offset; tilted by 45 deg about the
    image x axis, 120 mm away on the optical axis (focal length 1000 px), its image
    centre moves 0.22 px (towards its nearer half):

    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics
    >>> intr = CameraIntrinsics(focal=np.array([1000.0]),
    ...                         principal_point=np.array([[640.0, 360.0]]))
    >>> R, t = np.eye(3)[None, None], np.zeros((1, 1, 3))
    >>> X = np.array([[0.0, 0.0, 120.0], [0.0, 0.0, 120.0]])
    >>> s = np.sqrt(0.5)
    >>> n = np.array([[0.0, 0.0, -1.0], [0.0, s, -s]])
    >>> np.round(disc_image_offsets(X, n, 2.5, R, t, intr)[0, :, 0], 3)
    array([[ 0.   ,  0.   ],
           [ 0.   , -0.217]])
    """
    X = np.asarray(X, np.float64)
    n = np.asarray(normals, np.float64)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    r2 = np.broadcast_to(np.asarray(radius, np.float64), X.shape[:1])[None, :, None] ** 2
    Xc, nc = _camera_frame(X, n, R, t)
    ez = np.array([0.0, 0.0, 1.0])
    h = r2[..., None] * (ez - nc * nc[..., 2:3]) - Xc * Xc[..., 2:3]
    K = intr.K()  # (C, 3, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        front = Xc[..., 2] > 0
        centre = Xc[..., :2] / Xc[..., 2:3]
        conic = h[..., :2] / h[..., 2:3]

        def pixels(xn: NDArray) -> NDArray:
            x = (K[:, 0, 0] * xn[..., 0] + K[:, 0, 1] * xn[..., 1] + K[:, 0, 2])
            y = K[:, 1, 1] * xn[..., 1] + K[:, 1, 2]
            return distort_pixels(np.stack([x, y], axis=-1), intr)

        out = pixels(conic) - pixels(centre)
    out[~front] = np.nan
    return out


def disc_semi_axes(X: ArrayLike, normals: ArrayLike, R: ArrayLike, t: ArrayLike,
                   intr: CameraIntrinsics, radius: ArrayLike = 1.0) -> NDArray[np.float64]:
    """Semi-axes (px) of each disc's image ellipse (pinhole; distortion left out).

    Parameters
    ----------
    X, normals : array_like, shape (B, 3)
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    radius : array_like, shape (B,) or scalar
        Disc radii (mm); the axes grow in proportion to it.

    Returns
    -------
    ndarray, shape (F, B, C, 2)
        Semi-major and semi-minor axis (px, in units of the focal length); NaN where the
        disc is behind the camera or seen edge-on.
    """
    X = np.asarray(X, np.float64)
    n = np.asarray(normals, np.float64)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    r = np.broadcast_to(np.asarray(radius, np.float64), X.shape[:1])
    Xc, nc = _camera_frame(X, n, np.asarray(R, np.float64), np.asarray(t, np.float64))
    # an orthonormal basis u, v of each disc's plane
    a = np.where((np.abs(nc[..., :1]) < 0.9), [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u = np.cross(a, nc)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    v = np.cross(nc, u)
    rr = r[None, :, None, None]
    H = np.stack([rr * u, rr * v, Xc], axis=-1)  # columns (F, B, C, 3, 3)
    with np.errstate(invalid="ignore", divide="ignore"):
        Hi = np.linalg.inv(np.where(np.isfinite(H), H, np.eye(3)))
        Q = np.swapaxes(Hi, -1, -2) @ (np.array([1.0, 1.0, -1.0])[:, None] * Hi)
        A = Q[..., :2, :2]
        b = Q[..., :2, 2]
        c = Q[..., 2, 2]
        Ab = np.linalg.solve(A, b[..., None])[..., 0]
        k = (b * Ab).sum(-1) - c
        lam = np.linalg.eigvalsh(A)  # ascending: the smaller gives the major axis
        axes = np.sqrt(k[..., None] / lam) * intr.focal[None, None, :, None]
    bad = ~np.isfinite(H).all((-1, -2)) | (Xc[..., 2] <= 0) | ~np.isfinite(axes).all(-1)
    axes[bad] = np.nan
    return axes


def brim_dot_normals(X: ArrayLike, toward: ArrayLike) -> NDArray[np.float64]:
    """Unit normals of the brim dots from the model's shape.

    A brim is a smooth sheet (a flat printed label or a curved visor); the dots' normals
    are those of a quadric height surface fitted through all of them, in the frame of
    their principal axes (a plane with fewer than six dots). On the rendered takes'
    curved brims this is within 1-2 deg of the truth.

    Parameters
    ----------
    X : array_like, shape (B, 3)
        The brim model's dot centres (mm); NaN rows are left out (their normal is NaN).
    toward : array_like, shape (3,)
        A point on the side the dots face (the cameras' mean centre): the normals point
        towards it.

    Returns
    -------
    ndarray, shape (B, 3)
        NaN for every dot when fewer than three dots are known or they are collinear.

    Examples
    --------
    Dots on the plane z = 0 seen from z > 0:

    >>> import numpy as np
    >>> X = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0], [5, 3, 0]])
    >>> brim_dot_normals(X, [0.0, 0.0, 100.0])[0]
    array([0., 0., 1.])
    """
    X = np.asarray(X, np.float64)
    out = np.full(X.shape, np.nan)
    ok = np.isfinite(X).all(-1)
    P = X[ok]
    if len(P) < 3:
        return out
    mid = P.mean(0)
    w, V = np.linalg.eigh((P - mid).T @ (P - mid))
    if w[1] <= 1e-9 * max(w[2], 1e-12):
        return out  # collinear: no plane
    e1, e2, e3 = V[:, 2], V[:, 1], V[:, 0]
    a, b, h = (P - mid) @ e1, (P - mid) @ e2, (P - mid) @ e3
    one = np.ones_like(a)
    if len(P) >= 6:
        M = np.stack([one, a, b, a * a, a * b, b * b], axis=1)
        co = np.linalg.lstsq(M, h, rcond=None)[0]
        dh_da = co[1] + 2.0 * co[3] * a + co[4] * b
        dh_db = co[2] + co[4] * a + 2.0 * co[5] * b
    else:
        co = np.linalg.lstsq(np.stack([one, a, b], axis=1), h, rcond=None)[0]
        dh_da, dh_db = np.full_like(a, co[1]), np.full_like(a, co[2])
    n = e3[None, :] - dh_da[:, None] * e1[None, :] - dh_db[:, None] * e2[None, :]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    side = ((np.asarray(toward, np.float64)[None, :] - P) * n).sum(1)
    n[side < 0] *= -1.0
    out[ok] = n
    return out


def estimate_dot_radius(X: ArrayLike, normals: ArrayLike, major_px: ArrayLike, R: ArrayLike,
                        t: ArrayLike, intr: CameraIntrinsics) -> NDArray[np.float64]:
    """Each brim dot's radius (mm) from its blobs' semi-major axes.

    The semi-major axis of a disc's image is hardly changed by the disc's tilt, so the
    ratio of the detected semi-major axis to that of a disc of 1 mm at the same place
    is the radius. The median over a dot's blobs is its radius; a dot with fewer than
    `MIN_RADIUS_SAMPLES` blobs takes the median of all.

    Parameters
    ----------
    X, normals : array_like, shape (B, 3)
    major_px : array_like, shape (F, B, C)
        Detected semi-major axis (px) of each observation's blob, NaN where none.
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics

    Returns
    -------
    ndarray, shape (B,)
        NaN for every dot when no blob has an axis.
    """
    major = np.asarray(major_px, np.float64)
    F = major.shape[0]
    rows = np.unique(np.linspace(0, F - 1, min(F, RADIUS_FRAMES)).astype(np.intp))
    unit = disc_semi_axes(X, normals, np.asarray(R)[rows], np.asarray(t)[rows], intr)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = major[rows] / unit  # (F', B, C)
    ratio = np.where(np.isfinite(ratio) & (ratio > 0), ratio, np.nan)
    B = ratio.shape[1]
    flat = np.moveaxis(ratio, 1, 0).reshape(B, -1)
    count = np.isfinite(flat).sum(1)
    if not count.any():
        return np.full(B, np.nan)
    everyone = float(np.nanmedian(flat))
    own = np.full(B, everyone)
    enough = count >= MIN_RADIUS_SAMPLES
    if enough.any():
        own[enough] = np.nanmedian(flat[enough], axis=1)
    return own


def unbias_brim_cameras(X: ArrayLike, obs: ArrayLike, major_px: ArrayLike, R: ArrayLike,
                        t: ArrayLike, intr: CameraIntrinsics, *,
                        keep: ArrayLike | None = None, iterations: int = 1,
                        resect_iterations: int = 2, min_points: int = 6
                        ) -> BrimDiscCorrection | None:
    """Re-solve every frame's cameras from the brim with the dots' offsets removed.

    Parameters
    ----------
    X : array_like, shape (B, 3)
        The brim model (mm).
    obs : array_like, shape (F, B, C, 2)
        The brim dots' blob centroids (raw px), NaN where none.
    major_px : array_like, shape (F, B, C)
        Their blobs' semi-major axes (px), NaN where unknown.
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
        The poses solved from the uncorrected centroids (the starting point).
    intr : CameraIntrinsics
    keep : array_like of bool, shape (F,), optional
        Frames whose poses are left as they are (their observations are still
        corrected).
    iterations : int
        Rounds of offsets from the current poses and re-solve. The offsets hardly change
        with the poses: against three rounds of eight Gauss-Newton steps, one round of
        two moves the cameras by 5e-5 mm at most (the default, 0.12 ms per frame of four
        cameras).
    resect_iterations : int
        Gauss-Newton steps per round (from poses already near the solution).
    min_points : int
        As in tracking's per-frame resection (:func:`carapost.algorithms.tracking.
        matching.resect_cameras`): cameras seeing fewer dots keep their pose.

    Returns
    -------
    BrimDiscCorrection or None
        None when the brim's normals or radii cannot be estimated (fewer than three
        dots, no blob axes): nothing to correct with.
    """
    X = np.asarray(X, np.float64)
    obs = np.asarray(obs, np.float64)
    R = np.array(R, np.float64)
    t = np.array(t, np.float64)
    F, B, C = obs.shape[:3]
    posed = np.isfinite(R).all((-1, -2)) & np.isfinite(t).all(-1)  # (F, C)
    if not posed.any():
        return None
    centres = camera_centres(R[posed], t[posed])
    normals = brim_dot_normals(X, centres.reshape(-1, 3).mean(0))
    if not np.isfinite(normals).any():
        return None
    Rs = np.where(posed[..., None, None], R, np.eye(3))
    ts = np.where(posed[..., None], t, 0.0)
    radius = estimate_dot_radius(X, np.nan_to_num(normals), major_px, Rs, ts, intr)
    if not np.isfinite(radius).any():
        return None
    radius = np.where(np.isfinite(radius) & np.isfinite(normals).all(-1), radius, 0.0)
    nrm = np.nan_to_num(normals)
    solve = posed & ~(np.zeros(F, bool) if keep is None else np.asarray(keep, bool))[:, None]
    corrected = obs
    for _ in range(max(1, int(iterations))):
        off = disc_image_offsets(X, nrm, radius, Rs, ts, intr)
        corrected = obs - np.nan_to_num(off)
        for lo in range(0, F, CHUNK_FRAMES):
            sl = slice(lo, min(F, lo + CHUNK_FRAMES))
            m = solve[sl]
            if not m.any():
                continue
            xn = pixels_to_normalised(corrected[sl], intr)  # (f, B, C, 2)
            xn = np.moveaxis(xn, 1, 2)[m]  # (n, B, 2), n solved camera-frames
            focal = np.broadcast_to(intr.focal, m.shape)[m]
            res = refine_poses(X, xn, Rs[sl][m], ts[sl][m], scale=focal,
                               iterations=resect_iterations, huber_px=None,
                               min_points=min_points, linearise="camera")
            Rc, tc = Rs[sl], ts[sl]
            Rc[m], tc[m] = res.R, res.t
            Rs[sl], ts[sl] = Rc, tc
    Rs = np.where(posed[..., None, None], Rs, R)
    ts = np.where(posed[..., None], ts, t)
    return BrimDiscCorrection(Rs, ts, corrected, normals, radius)
