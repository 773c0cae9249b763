"""Per-frame camera poses over a take, and the uncertainty of each 3D sample.

Tracking resects every camera in every frame from the brim dots alone. The brim is
small and far above the jaw, so a few hundredths of a pixel of centroid error on its
dots tilt a camera by ~0.02 deg, and that tilt moves the far end of the face: a point
seen by the two cameras of one caddy (a 40 mm baseline at 100-150 mm) gets most of it
as depth error. The frame-to-frame part of that error is white (sensor noise on each
frame's brim dots) while real rig flex is smooth (it follows the head's motion), so
:func:`smooth_camera_poses` fits every camera's pose over a short window of frames, and
:func:`retriangulate` solves the points again from the same observations with the
smoothed cameras.

:func:`sample_sigma` gives each triangulated sample the standard deviation of its 3D
error expected from three sources, each measured on the take itself:

- the 2D noise of each camera (:func:`noise_from_residuals`: the reprojection residuals
  of points seen by three or more cameras), through the sample's observation geometry
  (which cameras, at what angles and depths). The noise of one observation scales with
  the width of its blob (:func:`width_noise_scale`): a disc seen edge-on is a thin
  ellipse whose centre is 3-5 times less precise than a round one's, and the camera
  that sees a marker its caddy partner cannot is the one that sees it most obliquely;
- how much worse than that a point's own observations are (:func:`point_noise_factor`:
  a marker half hidden by a fold or seen at a grazing angle keeps larger residuals over
  the whole take);
- the error of the cameras' poses, solved from the brim (:func:`brim_pose_covariance`:
  the covariance of each camera's resection from its brim dots and their residuals).
  The brim is seen alike by every camera, so what its centroid errors do to one camera
  they do to the others: the error moves the rig as a whole against the helmet and
  every point with it, which no residual of the face points can reveal. It is carried
  as the shift it gives the point (the mean over the cameras that see it).

Units: mm in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``P`` points, ``C`` cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.algorithms.pose_error import (  # re-exported: sigma's pose term
    brim_pose_covariance,
    pose_noise_variance,
    pose_shift_variance,
)
from carapost.algorithms.pose_smoothing import (  # re-exported: the pose fit's home
    POSE_SMOOTHING_FRAMES,
    savgol_quadratic,
    smooth_camera_poses,
)
from carapost.algorithms.triangulation import TriangulationParameters, triangulate

__all__ = [
    "POSE_SMOOTHING_FRAMES",
    "brim_pose_covariance",
    "noise_from_residuals",
    "observation_information",
    "pair_holdout_scale",
    "point_misfit",
    "point_noise_factor",
    "retriangulate",
    "sample_sigma",
    "savgol_quadratic",
    "smooth_camera_poses",
    "width_noise_scale",
]

#: Floor (px) of the per-camera 2D noise: no blob centre is trusted more than this,
#: whatever its residuals say. Below what is measured on any rendered take (0.03-0.07
#: px per camera on the takes of other renderers): at 0.05 the floor clipped the
#: measurement of clean takes and their sigmas were 1.3-1.6 times too large (held-out
#: 301-304: 82 % of errors within 1 sigma; docs/benchmarks.md, twenty-first session).
MIN_NOISE_PX = 0.02

#: Semi-minor axis (px) of the blob at which a camera's noise (`noise_from_residuals`)
#: is stated; the noise of an observation is that times ``BLOB_WIDTH_REF_PX / b``
#: (`width_noise_scale`). On the tuning takes of other renderers (51,000 observations,
#: error against the truth projection) the RMS error per axis times the blob's
#: semi-minor axis stayed between 0.17 and 0.26 px^2 over b = 1.5-8 px, while the error
#: itself went from 0.20 px (b < 1.6) to 0.04 px (b > 3.5) (docs/benchmarks.md).
BLOB_WIDTH_REF_PX = 3.0
#: Semi-minor axes (px) outside this range count as its ends: narrower blobs are rare and
#: their measured axis is itself noisy; a wide blob's centre is not better than this.
BLOB_WIDTH_RANGE_PX = (1.0, 6.0)


def width_noise_scale(minor_px: ArrayLike) -> NDArray[np.float64]:
    """Factor of each observation's 2D noise from the width of its blob.

    The centre of a blob is found from the pixels across its edge; a thin ellipse (a
    disc seen obliquely, semi-minor axis ``b``) has fewer of them and a blur tail that
    its support cuts, so its centre error grows as ``1 / b``. The factor is
    ``BLOB_WIDTH_REF_PX / b`` with ``b`` clipped to `BLOB_WIDTH_RANGE_PX`.

    Parameters
    ----------
    minor_px : array_like
        Semi-minor axis (px) of the blob of each observation; NaN or <= 0 where the
        observation has no blob (patch or target tracked): factor 1.

    Returns
    -------
    ndarray
        Same shape, >= ``BLOB_WIDTH_REF_PX / BLOB_WIDTH_RANGE_PX[1]``.

    Examples
    --------
    >>> width_noise_scale([1.5, 3.0, 12.0, float("nan")]).tolist()
    [2.0, 1.0, 0.5, 1.0]
    """
    b = np.asarray(minor_px, dtype=np.float64)
    lo, hi = BLOB_WIDTH_RANGE_PX
    with np.errstate(invalid="ignore"):
        known = np.isfinite(b) & (b > 0)
    return np.where(known, BLOB_WIDTH_REF_PX / np.clip(np.where(known, b, 1.0), lo, hi), 1.0)


def retriangulate(obs: ArrayLike, R: ArrayLike, t: ArrayLike, intr: CameraIntrinsics,
                  mask: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Triangulate the masked samples again from their observations (same cameras).

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
        Raw pixel observations (NaN where none).
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    mask : array_like of bool, shape (F, P)
        Samples to solve (those with >= 2 observations are solved).

    Returns
    -------
    X : ndarray, shape (F, P, 3)
        New positions (mm); NaN outside ``mask`` or where fewer than two cameras see it.
    residual : ndarray, shape (F, P)
        RMS distance of each new position to its rays (mm).
    """
    o = np.asarray(obs, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    sel = np.where(m[..., None, None], o, np.nan)
    params = TriangulationParameters(minimum_cameras=2, use_outlier_rejection=False,
                                     refine_iterations=1)
    res = triangulate(sel, R, t, intr, params)
    return res.points, res.residual


def noise_from_residuals(obs: ArrayLike, X: ArrayLike, R: ArrayLike, t: ArrayLike,
                         intr: CameraIntrinsics, scale: ArrayLike | None = None,
                         max_samples: int = 8_000) -> NDArray[np.float64]:
    """Per-camera 2D noise (px) from the reprojection residuals of over-determined points.

    A point seen by ``n >= 3`` cameras and solved by least squares (every ray alike)
    leaves the residual ``r = (I - H) e`` of its observation errors ``e``, ``H`` the hat
    matrix of the solve (``J (J^T J)^-1 J^T``, ``J`` the 2n x 3 pixel Jacobian), so a
    camera's expected squared residual is its 2x2 block of ``(I - H) V (I - H)^T``
    (``V``: each observation's noise variance). The cameras do not share the residual
    alike: the lone camera of its caddy in a three-camera sample fixes the depth along
    the other caddy's baseline by itself and keeps almost none of its error, so equal
    shares (``2n / (2n - 3)`` each) would lend its noise to the other two. Each camera's
    variance is the median (robust to a few wrong blobs) of ``|r|^2`` over its expected
    value, divided by that ratio's median for a normal error (``ln 2`` when the residual
    keeps both axes alike, 0.455 when it keeps one: Satterthwaite's chi-square of the
    block's eigenvalues), starting from equal noise and repeated with the new variances
    (three times).

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
    X : array_like, shape (F, P, 3)
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    scale : array_like, shape (F, P, C), optional
        Noise factor of each observation (`width_noise_scale`): its noise is the
        camera's times it, so the result is the noise of an observation of factor 1.
    max_samples : int
        Over-determined samples used at most (spread evenly over the take; a median
        needs no more).

    Returns
    -------
    ndarray, shape (C,)
        Per-axis standard deviation (px) of each camera's observations (of factor 1 with
        ``scale``), at least `MIN_NOISE_PX`; cameras without enough data get the median
        of the others.
    """
    o = np.asarray(obs, dtype=np.float64)
    Xm = np.asarray(X, dtype=np.float64)
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    F, P, C, _ = o.shape
    has = np.isfinite(o).all(-1)
    use = (has.sum(-1) >= 3) & np.isfinite(Xm).all(-1)
    out = np.full(C, np.nan)
    fi, pi = np.nonzero(use)
    if fi.size > max_samples:
        pick = np.unique(np.linspace(0, fi.size - 1, max_samples).astype(np.intp))
        fi, pi = fi[pick], pi[pick]
    if fi.size:
        hs = has[fi, pi]  # (N, C)
        uv = _project_per_frame(Xm[fi, pi], Rm[fi], tm[fi], intr)
        r2 = np.where(hs, np.sum((uv - o[fi, pi]) ** 2, axis=-1), 0.0)  # (N, C)
        k2 = (np.ones(hs.shape) if scale is None
              else np.asarray(scale, dtype=np.float64)[fi, pi] ** 2)
        M = _residual_maps(Xm[fi, pi], hs, Rm[fi], tm[fi], intr)  # (N, 2C, 2C)
        # equal to start with (the update does not depend on their common size)
        var = np.ones(C)
        for _ in range(3):
            v = np.repeat(np.where(hs, var[None, :] * k2, 0.0), 2, axis=1)  # (N, 2C)
            new = np.full(C, np.nan)
            for c in range(C):
                Mc = M[:, 2 * c:2 * c + 2]  # (N, 2, 2C): camera c's rows
                block = (Mc * v[:, None, :]) @ np.swapaxes(Mc, 1, 2)  # (N, 2, 2)
                expect = block[:, 0, 0] + block[:, 1, 1]
                m = hs[:, c] & (expect > 1e-12 * var[c])
                if m.sum() >= 20:
                    ratio = r2[m, c] / expect[m] / _ratio_median(block[m])
                    new[c] = var[c] * np.median(ratio)
            if not np.isfinite(new).any():
                break
            # a camera with too few samples of its own is taken as the others' median
            var = np.where(np.isfinite(new), new, np.nanmedian(new))
        for c in range(C):
            if hs[:, c].sum() >= 20:
                out[c] = np.sqrt(var[c])
    if np.isfinite(out).any():
        out[~np.isfinite(out)] = np.nanmedian(out)
    else:
        out[:] = 0.15
    return np.maximum(out, MIN_NOISE_PX)


def _ratio_median(block: NDArray[np.float64]) -> NDArray[np.float64]:
    """Median of ``|r|^2 / E|r|^2`` for a normal 2D residual of covariance ``block``
    (N, 2, 2): that of ``chi2(nu) / nu`` with ``nu = tr^2 / (l_1^2 + l_2^2)`` (1-2)."""
    # chi2(nu).median() is 2 * gammaincinv(nu / 2, 0.5) (scipy.stats computes it so);
    # scipy.special alone spares a take the import of scipy.stats (~0.3 s of CPU)
    from scipy.special import gammaincinv

    tr = block[:, 0, 0] + block[:, 1, 1]
    sq = tr ** 2 - 2.0 * (block[:, 0, 0] * block[:, 1, 1] - block[:, 0, 1] * block[:, 1, 0])
    nu = np.clip(tr ** 2 / np.maximum(sq, 1e-300), 1.0, 2.0)
    return 2.0 * gammaincinv(nu / 2.0, 0.5) / nu


def _residual_maps(X: NDArray[np.float64], has: NDArray[np.bool_], R: NDArray[np.float64],
                   t: NDArray[np.float64], intr: CameraIntrinsics) -> NDArray[np.float64]:
    """``I - H`` (N, 2C, 2C) of the equally weighted triangulation of N samples (each
    with its own frame's cameras, ``has`` (N, C) the observing ones): the map from the
    observation errors to the residuals (rows and columns of the others are zero)."""
    N, C = has.shape
    Xc = np.einsum("ncij,nj->nci", R, X) + t  # (N, C, 3)
    z = np.where(has & (Xc[..., 2] > 1e-6), Xc[..., 2], 1.0)
    f = intr.focal[None, :]
    Jc = np.zeros((N, C, 2, 3))
    Jc[..., 0, 0] = Jc[..., 1, 1] = f / z
    Jc[..., 0, 2] = -f * Xc[..., 0] / z ** 2
    Jc[..., 1, 2] = -f * Xc[..., 1] / z ** 2
    J = np.where(has[..., None, None], np.einsum("ncak,nckj->ncaj", Jc, R), 0.0)
    J = J.reshape(N, 2 * C, 3)
    A = np.einsum("nai,naj->nij", J, J)
    good = np.linalg.det(A) > 1e-12 * np.einsum("nii->n", A) ** 3
    H = np.zeros((N, 2 * C, 2 * C))
    H[good] = J[good] @ np.linalg.solve(A[good], np.swapaxes(J[good], 1, 2))
    eye = np.repeat(has, 2, axis=1).astype(np.float64)
    return np.where(good[:, None, None], eye[:, :, None] * np.eye(2 * C)[None] - H, 0.0)


def pair_holdout_scale(obs: ArrayLike, X: ArrayLike, R: ArrayLike, t: ArrayLike,
                       intr: CameraIntrinsics, noise_px: ArrayLike,
                       max_samples: int = 4000) -> float:
    """Scale of `sample_sigma` that the take's own camera pairs bear out (>= 1).

    A diagnostic (Track Take no longer applies it): it sees what makes a take's cameras
    disagree, not the pose error they share (`brim_pose_covariance` carries that), and
    its mean of ratios follows a few wrong blobs.

    The 2D residuals see the centroid noise but only part of the camera pose error
    (a pose error along a caddy's baseline leaves a two-camera point on both rays, only
    at another depth). A hold-out test measures it: a sample seen by three or more
    cameras is triangulated again from each pair of them alone; for a correct model the
    difference ``X_pair - X_all`` has covariance ``Cov_pair - Cov_all`` (nested least
    squares), so the mean of ``|X_pair - X_all|^2 / trace(Cov_pair - Cov_all)`` is the
    square of the factor by which the sigmas must grow (1 when the model is right).
    Pairs that see a point at less than 2 degrees are left out; the top 1 % of the
    ratios (wrong blobs) is trimmed.

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
        Observations of the triangulated samples (NaN elsewhere).
    X : array_like, shape (F, P, 3)
        Their positions (mm).
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    noise_px : array_like, shape (C,)
    max_samples : int
        Samples used at most (spread evenly), to bound the cost.

    Returns
    -------
    float
        The factor (1.0 when there are too few redundant samples to tell).
    """
    o = np.asarray(obs, dtype=np.float64)
    Xm = np.asarray(X, dtype=np.float64)
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    has = np.isfinite(o).all(-1)
    fi, pi = np.nonzero((has.sum(-1) >= 3) & np.isfinite(Xm).all(-1))
    if fi.size < 50:
        return 1.0
    pick = np.unique(np.linspace(0, fi.size - 1, min(fi.size, max_samples)).astype(int))
    fi, pi = fi[pick], pi[pick]
    # sample_sigma and triangulate take per-frame cameras; one "frame" per sample
    Rn, tn = Rm[fi], tm[fi]
    ob, Xa = o[fi, pi][:, None], Xm[fi, pi][:, None]   # (N, 1, C, 2), (N, 1, 3)
    s_all = sample_sigma(Xa, ob, Rn, tn, intr, noise_px).astype(np.float64)[:, 0]
    C = o.shape[2]
    params = TriangulationParameters(minimum_cameras=2, use_outlier_rejection=False,
                                     refine_iterations=1, min_ray_angle_deg=2.0)
    ratios = []
    for a in range(C):
        for b in range(a + 1, C):
            sel = has[fi, pi][:, a] & has[fi, pi][:, b]
            if sel.sum() < 20:
                continue
            keep = np.zeros(C, bool)
            keep[[a, b]] = True
            ob2 = np.where(keep[None, None, :, None], ob[sel], np.nan)
            Xp = triangulate(ob2, Rn[sel], tn[sel], intr, params).points
            s_pair = sample_sigma(Xp, ob2, Rn[sel], tn[sel], intr, noise_px)[:, 0]
            den = s_pair.astype(np.float64) ** 2 - s_all[sel] ** 2
            d2 = np.sum((Xp[:, 0] - Xa[sel, 0]) ** 2, axis=-1)
            ok = np.isfinite(d2) & np.isfinite(den) & (den > 0)
            ratios.append(d2[ok] / den[ok])
    r = np.concatenate(ratios) if ratios else np.zeros(0)
    if r.size < 50:
        return 1.0
    r = np.sort(r)[: max(1, int(0.99 * r.size))]
    return float(max(1.0, np.sqrt(np.mean(r))))


def _project_per_frame(X: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64],
                       intr: CameraIntrinsics) -> NDArray[np.float64]:
    """Raw pixels (N, C, 2) of N points (N, 3), each with its own frame's cameras."""
    return project(X[:, None, :], R, t, intr)[0][:, 0]


def sample_sigma(X: ArrayLike, obs: ArrayLike, R: ArrayLike, t: ArrayLike,
                 intr: CameraIntrinsics, noise_px: ArrayLike,
                 pose_cov: ArrayLike | None = None, point_factor: ArrayLike | None = None,
                 scale: ArrayLike | None = None, chunk: int = 256,
                 pose_independent: bool = False) -> NDArray[np.float32]:
    """Standard deviation (mm) of each triangulated sample's 3D error.

    First-order propagation: with ``J_c`` the 2x3 Jacobian of camera ``c``'s pixel
    projection at the point, the covariance of the 2D noise's effect is
    ``phi_p (sum_c J_c^T J_c / s_c^2)^-1`` over the cameras that observe it (``s_c`` =
    ``noise_px[c]``, ``phi_p`` = ``point_factor[p]``, 1 without it). With ``pose_cov``,
    the shift of the point by each observing camera's pose error is added (the mean
    over those cameras of ``M_c Cov_c M_c^T``, ``M_c`` = ``R_c^T [-[X_c]x, I]`` the
    point's displacement per pose parameter, ``X_c`` the point in camera coordinates;
    see the module docstring for why the shift is shared); with ``pose_independent`` the
    cameras' pose errors are taken as independent instead, each an extra 2D noise of its
    observation carried through the triangulation
    (`carapost.algorithms.pose_error.pose_noise_variance`): what is left once the brim
    dots' offsets are removed (:mod:`carapost.algorithms.brim_discs`) is each camera's
    own centroid noise. The
    value stored is the root
    of the trace: the RMS length of the error vector, which is the standard deviation
    along the worst direction when one direction dominates (depth along a short caddy
    baseline) and never less than it.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm).
    obs : array_like, shape (F, P, C, 2)
        The observations the positions were solved from (NaN where none).
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    noise_px : array_like, shape (C,)
        Per-axis 2D noise of each camera (px).
    pose_cov : array_like, shape (F, C, 6, 6), optional
        Covariance of each camera's pose per frame (`brim_pose_covariance`: rotation
        (rad) then translation (mm), camera coordinates); NaN or zero where unknown.
    point_factor : array_like, shape (P,), optional
        Variance factor of each point's 2D noise (`point_noise_factor`).
    scale : array_like, shape (F, P, C), optional
        Noise factor of each observation (`width_noise_scale`); see
        `observation_information`.
    chunk : int
        Frames per block (bounds the memory of long takes).
    pose_independent : bool
        How ``pose_cov`` enters: a shift shared by the cameras (False) or independent
        errors of each camera (True).

    Returns
    -------
    ndarray, shape (F, P), float32
        NaN where fewer than two cameras observe the sample or the geometry is singular.

    Examples
    --------
    Two cameras 40 mm apart, 150 mm from a point: the depth error dominates.

    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics
    >>> intr = CameraIntrinsics(focal=np.array([600.0, 600.0]),
    ...                         principal_point=np.array([[640.0, 360.0], [640.0, 360.0]]))
    >>> R = np.tile(np.eye(3), (1, 2, 1, 1)); t = np.array([[[20.0, 0, 0], [-20.0, 0, 0]]])
    >>> s = sample_sigma(np.zeros((1, 1, 3)) + [0, 0, 150.0], np.zeros((1, 1, 2, 2)),
    ...                  R, t, intr, [0.1, 0.1])
    >>> round(float(s[0, 0]), 2)
    0.13
    """
    Xm = np.asarray(X, dtype=np.float64)
    o = np.asarray(obs)
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    s = np.asarray(noise_px, dtype=np.float64)
    pc = None if pose_cov is None else np.asarray(pose_cov, dtype=np.float64)
    phi = (np.ones(Xm.shape[1]) if point_factor is None
           else np.asarray(point_factor, dtype=np.float64))
    sc = None if scale is None else np.asarray(scale, dtype=np.float64)
    out = np.full(Xm.shape[:2], np.nan, dtype=np.float32)
    for a in range(0, Xm.shape[0], max(1, int(chunk))):
        b = slice(a, a + max(1, int(chunk)))
        out[b] = _sigma_block(Xm[b], o[b].astype(np.float64), Rm[b], tm[b], intr, s,
                              None if pc is None else pc[b], phi,
                              None if sc is None else sc[b], pose_independent)
    return out


def observation_information(X: NDArray[np.float64], obs: NDArray[np.float64],
                            R: NDArray[np.float64], t: NDArray[np.float64],
                            intr: CameraIntrinsics, noise_px: NDArray[np.float64],
                            scale: NDArray[np.float64] | None = None
                            ) -> tuple[NDArray[np.float64], NDArray[np.bool_],
                                       NDArray[np.float64]]:
    """Information matrix of each sample's position from its observations.

    ``sum_c J_c^T J_c / s_c^2`` over the cameras that observe the sample in front of
    them, ``J_c`` the 2x3 Jacobian of camera ``c``'s pinhole projection in pixels at the
    point, ``s_c = noise_px[c]`` (px); its inverse is the covariance of the 2D noise's
    effect (mm^2). Shared by `sample_sigma` and
    `carapost.algorithms.depth_prior.sample_covariance`.

    With ``scale`` each observation's noise is ``s_c k_c`` (``k_c`` its factor,
    `width_noise_scale`). The triangulation weighs every ray alike, so the covariance
    of its result is the sandwich ``A^-1 B A^-1`` (``A = sum_c J_c^T J_c``,
    ``B = sum_c (s_c k_c)^2 J_c^T J_c``), not the inverse of the weighted sum, which
    would credit the solve with down-weighting a thin blob it does not down-weight; the
    information returned is ``A B^-1 A``, whose inverse is that covariance.

    Parameters
    ----------
    X : ndarray, shape (F, P, 3)
        Positions (mm), NaN where none.
    obs : ndarray, shape (F, P, C, 2)
        Observations (px), NaN where none.
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    noise_px : ndarray, shape (C,)
    scale : ndarray, shape (F, P, C), optional
        Noise factor of each observation.

    Returns
    -------
    info : ndarray, shape (F, P, 3, 3)
        1/mm^2; zero where no camera counts.
    ok : ndarray, shape (F, P, C), bool
        The cameras that count (observed, point in front).
    Xc : ndarray, shape (F, P, C, 3)
        The point in each camera's coordinates (mm).
    """
    has = np.isfinite(obs).all(-1) & np.isfinite(X).all(-1)[..., None]  # (F, P, C)
    Xc = np.einsum("fcij,fpj->fpci", R, np.nan_to_num(X)) + t[:, None]  # (F, P, C, 3)
    z = Xc[..., 2]
    ok = has & (z > 1e-6)
    zs = np.where(ok, z, 1.0)
    x, y = Xc[..., 0] / zs, Xc[..., 1] / zs
    # d(normalised)/d(camera coords), then through R: (F, P, C, 2, 3)
    Jn = np.zeros(Xc.shape[:-1] + (2, 3))
    Jn[..., 0, 0] = 1.0 / zs
    Jn[..., 0, 2] = -x / zs
    Jn[..., 1, 1] = 1.0 / zs
    Jn[..., 1, 2] = -y / zs
    J = np.einsum("fpcak,fckj->fpcaj", Jn, R)
    if scale is None:
        wgt = np.where(ok, (intr.focal[None, None, :] / noise_px[None, None, :]) ** 2, 0.0)
        return np.einsum("fpc,fpcai,fpcaj->fpij", wgt, J, J), ok, Xc
    f2 = np.where(ok, intr.focal[None, None, :] ** 2, 0.0)
    A = np.einsum("fpc,fpcai,fpcaj->fpij", f2, J, J)
    var = (noise_px[None, None, :] * np.where(ok, scale, 1.0)) ** 2
    B = np.einsum("fpc,fpcai,fpcaj->fpij", f2 * var, J, J)
    info = np.zeros_like(A)
    tr = np.einsum("fpii->fp", B)
    # two cameras or more and a geometry that fixes the point (else no information)
    solvable = (ok.sum(-1) >= 2) & (np.linalg.det(B) > 1e-12 * tr ** 3)
    if solvable.any():
        As = A[solvable]
        info[solvable] = As @ np.linalg.solve(B[solvable], As)
    return info, ok, Xc


def _sigma_block(Xm: NDArray[np.float64], o: NDArray[np.float64], Rm: NDArray[np.float64],
                 tm: NDArray[np.float64], intr: CameraIntrinsics, s: NDArray[np.float64],
                 pc: NDArray[np.float64] | None, phi: NDArray[np.float64],
                 scale: NDArray[np.float64] | None = None,
                 pose_independent: bool = False) -> NDArray[np.float32]:
    """`sample_sigma` of a block of frames."""
    info, ok, Xc = observation_information(Xm, o, Rm, tm, intr, s, scale)
    out = np.full(Xm.shape[:2], np.nan, dtype=np.float32)
    two = ok.sum(-1) >= 2
    if not two.any():
        return out
    A = info[two]
    det = np.linalg.det(A)
    good = det > 1e-12 * np.einsum("nii->n", A) ** 3
    var = np.full(A.shape[0], np.nan)
    var[good] = np.einsum("nii->n", np.linalg.inv(A[good]))
    var *= np.broadcast_to(phi[None, :], two.shape)[two]
    if pc is not None:
        if pose_independent:
            var += pose_noise_variance(Xc[two], ok[two], Rm, np.nonzero(two)[0], pc,
                                        intr.focal)
        else:
            var += pose_shift_variance(Xc[two], ok[two], Rm, np.nonzero(two)[0], pc)
    out[two] = np.sqrt(var).astype(np.float32)
    return out


def point_noise_factor(obs: ArrayLike, X: ArrayLike, R: ArrayLike, t: ArrayLike,
                       intr: CameraIntrinsics, noise_px: ArrayLike,
                       min_samples: int = 5, scale: ArrayLike | None = None
                       ) -> NDArray[np.float64]:
    """Variance factor (>= 1) of each point's 2D noise, from its own residuals.

    A sample seen by ``n >= 3`` cameras leaves ``chi2 = sum_c |r_c|^2 / s_c^2`` with
    ``2n - 3`` degrees of freedom; divided by the median of that chi-square it is about
    1 for a point whose observations are as good as the camera's typical ones. The
    factor is the median of this ratio over the point's samples (robust to a few
    frames with a wrong blob), at least 1: a marker whose blobs are consistently off
    (half hidden by a fold, seen edge-on, merged with a neighbour) is trusted less in
    every frame, including those where only two cameras see it.

    Parameters
    ----------
    obs : array_like, shape (F, P, C, 2)
    X : array_like, shape (F, P, 3)
    R, t : array_like, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    noise_px : array_like, shape (C,)
    min_samples : int
        A point with fewer over-determined samples keeps 1.
    scale : array_like, shape (F, P, C), optional
        Noise factor of each observation (`width_noise_scale`): what the blob's width
        explains is not counted as the point's excess.

    Returns
    -------
    ndarray, shape (P,)
    """
    # at most ~600 frames spread over the take (a median needs no more)
    step = max(1, np.shape(X)[0] // 600)
    o = np.asarray(obs)[::step].astype(np.float64)
    Xm = np.asarray(X)[::step].astype(np.float64)
    q = point_misfit(o, Xm, np.asarray(R, dtype=np.float64)[::step],
                     np.asarray(t, dtype=np.float64)[::step], intr,
                     np.asarray(noise_px, dtype=np.float64), min_cameras=3,
                     min_samples=min_samples,
                     scale=None if scale is None else np.asarray(scale)[::step])
    return np.where(np.isfinite(q), np.maximum(q, 1.0), 1.0)


def point_misfit(obs: NDArray[np.float64], X: NDArray[np.float64], R: NDArray[np.float64],
                 t: NDArray[np.float64], intr: CameraIntrinsics,
                 noise_px: NDArray[np.float64], *, min_cameras: int,
                 min_samples: int, scale: NDArray[np.float64] | None = None
                 ) -> NDArray[np.float64]:
    """Median over each point's samples of its reprojection chi-square against the
    cameras' noise, divided by the chi-square's median (about 1 for typical blobs).

    A sample seen by ``n >= min_cameras`` cameras leaves ``sum_c |r_c|^2 / s_c^2`` with
    ``2n - 3`` degrees of freedom. Shared by `point_noise_factor` and the spurious-point
    test (`carapost.algorithms.spurious`).

    Parameters
    ----------
    obs : ndarray, shape (F, P, C, 2)
        Observations (px), NaN where none.
    X : ndarray, shape (F, P, 3)
        Positions (mm), NaN where none.
    R, t : ndarray, shapes (F, C, 3, 3) and (F, C, 3)
    intr : CameraIntrinsics
    noise_px : ndarray, shape (C,)
    min_cameras, min_samples : int
        Samples with fewer cameras do not count; a point with fewer samples gets NaN.
    scale : ndarray, shape (F, P, C), optional
        Noise factor of each observation (the camera's noise times it is its own).

    Returns
    -------
    ndarray, shape (P,)
    """
    # the median of chi2(k) as scipy.stats.chi2.median computes it (bit for bit), without
    # importing scipy.stats (~0.3 s of CPU per process)
    from scipy.special import gammaincinv

    has = np.isfinite(obs).all(-1)
    n = has.sum(-1)
    use = (n >= min_cameras) & np.isfinite(X).all(-1)
    out = np.full(X.shape[1], np.nan)
    if not use.any():
        return out
    fi, pi = np.nonzero(use)
    uv = _project_per_frame(X[fi, pi], R[fi], t[fi], intr)
    r2 = (np.where(has[fi, pi], np.sum((uv - obs[fi, pi]) ** 2, -1), 0.0)
          / noise_px[None, :] ** 2)
    if scale is not None:
        r2 = r2 / np.asarray(scale, dtype=np.float64)[fi, pi] ** 2
    q = r2.sum(-1) / (2 * gammaincinv((2 * n[fi, pi] - 3) / 2, 0.5))
    order = np.argsort(pi, kind="stable")
    pi_s, q_s = pi[order], q[order]
    starts = np.flatnonzero(np.r_[True, pi_s[1:] != pi_s[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], pi_s.size], strict=True):
        if b - a >= min_samples:
            out[pi_s[a]] = float(np.median(q_s[a:b]))
    return out
