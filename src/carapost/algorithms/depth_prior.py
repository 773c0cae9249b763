"""A depth prior from time for points whose depth the cameras barely fix.

A marker seen by the two cameras of one caddy only (a ~40 mm baseline at 100-150 mm)
is triangulated with an error that is elongated along its depth: the 2D centroid noise
of each frame (white, frame to frame) becomes ~0.1 mm of depth noise against a few
hundredths of a millimetre across the image. The face moves smoothly at 60 fps over a
tenth of a second, so a local quadratic over a few frames predicts each sample far
better along that direction than the sample itself does, while across the image the
sample is already better than any prediction.

:func:`sample_covariance` gives each sample's 3D error covariance from its observation
geometry (as `carapost.algorithms.uncertainty.sample_sigma`, full matrix);
:func:`smooth_along_uncertainty` fits every point's track by a local quadratic over a
window of frames (gaps and ends handled by weights) and moves each sample towards the
fit along each principal direction of its covariance by the gain
``lambda_i / (lambda_i + tau^2)``: ``lambda_i`` the sample's variance along that
direction, ``tau`` the expected deviation of real motion from the local quadratic. A
well-seen direction (small ``lambda``) keeps the measurement; a poorly seen depth
follows the smooth track.

Units: mm in 3D, raw pixels in 2D. Shapes: ``F`` frames, ``P`` points, ``C`` cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.uncertainty import observation_information

__all__ = ["DEPTH_SMOOTHING_FRAMES", "MOTION_TAU_MM", "OUTLIER_SIGMAS", "sample_covariance",
           "smooth_along_uncertainty"]

#: Window (frames) of the local quadratic of the depth prior (see docs/algorithms.md).
DEPTH_SMOOTHING_FRAMES = 9

#: Least deviation (mm) of real marker motion from a local quadratic over the window
#: assumed (the measured one, across the image, is added).
MOTION_TAU_MM = 0.03

#: A sample further than this many standard deviations from the fit of its neighbours
#: in time, along its worst-seen direction (its variance there, the fit's and the
#: motion's; see `smooth_along_uncertainty`), is an outlier of the depth prior (0: none).
OUTLIER_SIGMAS = 4.0

#: ... and its square distance is this many times the largest of the others in its
#: window (an isolated outlier: the others' distances are raised only by its weight in
#: their fits, a fifth of its error or less; a track off over many frames has no right
#: neighbours to follow).
OUTLIER_RATIO = 4.0


def sample_covariance(X: ArrayLike, obs: ArrayLike, R: ArrayLike, t: ArrayLike,
                      intr: CameraIntrinsics, noise_px: ArrayLike,
                      scale: ArrayLike | None = None) -> NDArray[np.float64]:
    """Covariance (mm^2) of each triangulated sample's 3D error from its geometry.

    ``(sum_c J_c^T J_c / s_c^2)^-1`` over the cameras that observe the sample, ``J_c``
    the 2x3 Jacobian of camera ``c``'s pinhole projection in pixels at the point and
    ``s_c = noise_px[c]``.

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
    scale : array_like, shape (F, P, C), optional
        Noise factor of each observation
        (`carapost.algorithms.uncertainty.width_noise_scale`; the covariance is then
        that of the equally weighted triangulation, see
        `carapost.algorithms.uncertainty.observation_information`).

    Returns
    -------
    ndarray, shape (F, P, 3, 3)
        NaN where fewer than two cameras observe the sample or the geometry is singular.

    Examples
    --------
    Two cameras 40 mm apart, 150 mm from a point: the depth variance dominates.

    >>> import numpy as np
    >>> from carapost.algorithms.camera import CameraIntrinsics
    >>> intr = CameraIntrinsics(focal=np.array([600.0, 600.0]),
    ...                         principal_point=np.array([[640.0, 360.0], [640.0, 360.0]]))
    >>> R = np.tile(np.eye(3), (1, 2, 1, 1)); t = np.array([[[20.0, 0, 0], [-20.0, 0, 0]]])
    >>> cov = sample_covariance(np.zeros((1, 1, 3)) + [0, 0, 150.0], np.zeros((1, 1, 2, 2)),
    ...                         R, t, intr, [0.1, 0.1])
    >>> bool(cov[0, 0, 2, 2] > 50 * cov[0, 0, 0, 0])
    True
    """
    Xm = np.asarray(X, dtype=np.float64)
    o = np.asarray(obs, dtype=np.float64)
    Rm = np.asarray(R, dtype=np.float64)
    tm = np.asarray(t, dtype=np.float64)
    s = np.asarray(noise_px, dtype=np.float64)
    sc = None if scale is None else np.asarray(scale, dtype=np.float64)
    info, ok, _ = observation_information(Xm, o, Rm, tm, intr, s, sc)
    out = np.full(Xm.shape[:2] + (3, 3), np.nan)
    two = ok.sum(-1) >= 2
    if two.any():
        A = info[two]
        det = np.linalg.det(A)
        good = det > 1e-12 * np.einsum("nii->n", A) ** 3
        cov = np.full_like(A, np.nan)
        cov[good] = np.linalg.inv(A[good])
        out[two] = cov
    return out


def _local_quadratic(X: NDArray[np.float64], half: int, min_support: int,
                     centre: NDArray[np.bool_] | None = None
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Value at each frame of a least-squares quadratic over ``2 half + 1`` frames.

    Missing samples (NaN) have weight 0, so gaps and the ends of tracks shorten the
    support instead of stopping the fit. Returns the fit (NaN where fewer than
    ``min_support`` samples, or not on both sides, support it) and the variance factor
    of the fit's value for unit-variance white samples (the centre weight, ``c_0``).
    ``centre`` (F, P): samples left out (NaN in ``X``) whose frame is fitted all the
    same, from the others (``c_0`` 0 there).
    """
    from scipy.ndimage import correlate1d

    w = np.isfinite(X).all(-1).astype(np.float64)  # (F, P)
    Xz = np.where(w[..., None] > 0, X, 0.0)
    j = np.arange(-half, half + 1, dtype=np.float64)
    S = [correlate1d(w, j ** k, axis=0, mode="constant") for k in range(5)]
    T = [correlate1d(Xz, j ** k, axis=0, mode="constant") for k in range(3)]
    # normal equations of a + b j + c j^2 at every (frame, point)
    M = np.stack([np.stack([S[0], S[1], S[2]], -1), np.stack([S[1], S[2], S[3]], -1),
                  np.stack([S[2], S[3], S[4]], -1)], -2)  # (F, P, 3, 3)
    left = correlate1d(w, (j < 0).astype(np.float64), axis=0, mode="constant")
    right = correlate1d(w, (j > 0).astype(np.float64), axis=0, mode="constant")
    ok = (S[0] >= min_support) & (left >= 1) & (right >= 1) & (w > 0)
    if centre is not None:
        # frames whose own sample is left out of the fit (weight 0) are fitted as well
        ok |= (S[0] >= min_support) & (left >= 1) & (right >= 1) & centre
    fit = np.full(X.shape, np.nan)
    c0 = np.full(X.shape[:2], np.nan)
    if ok.any():
        Mi = np.linalg.inv(M[ok])  # (N, 3, 3)
        rhs = np.stack([T[0][ok], T[1][ok], T[2][ok]], -2)  # (N, 3, 3): rows = powers
        fit[ok] = np.einsum("nk,nkd->nd", Mi[:, 0], rhs)
        # the weight of the centre sample in the fit: (M^-1)_0. . (1, 0, 0), times its
        # own weight (0 where it is left out)
        c0[ok] = Mi[:, 0, 0] * w[ok]
    return fit, c0


def _window_mean(v: NDArray[np.float64], half: int) -> NDArray[np.float64]:
    """Mean of the finite values of ``v`` (F, P) over ``2 half + 1`` frames."""
    from scipy.ndimage import uniform_filter1d

    ok = np.isfinite(v)
    num = uniform_filter1d(np.where(ok, v, 0.0), 2 * half + 1, axis=0, mode="constant")
    den = uniform_filter1d(ok.astype(np.float64), 2 * half + 1, axis=0, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def smooth_along_uncertainty(X: ArrayLike, cov: ArrayLike,
                             window: int = DEPTH_SMOOTHING_FRAMES,
                             tau_mm: float = MOTION_TAU_MM, shared: float = 0.0,
                             outlier_sigmas: float = OUTLIER_SIGMAS
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Move each sample towards its track's local quadratic where it is poorly seen.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm), NaN where none.
    cov : array_like, shape (F, P, 3, 3)
        The part of each sample's error covariance that is independent from frame to
        frame (mm^2, `sample_covariance` of the 2D centroid noise); samples with a NaN
        covariance are left as they are.
    window : int
        Frames of the local quadratic (odd; below 5 nothing changes).
    tau_mm : float
        Expected deviation (mm) of the real motion from the quadratic over the window.
    shared : float
        The error that neighbouring frames share (camera pose error that changes slowly),
        as a multiple of ``cov``: no fit over time removes it, so it is added to the
        returned covariance unchanged.
    outlier_sigmas : float
        A sample whose leave-one-out distance to the fit of the others along its
        worst-seen direction is more than this many standard deviations (its variance
        there divided by ``1 - c_0``, plus ``tau^2`` and the sample's own departure
        from the fit across the image) is left out of its neighbours' fits and its
        variance along that direction is scaled up to that distance, so its depth
        follows the fit of the others; 0 turns this off.

    Returns
    -------
    X : ndarray, shape (F, P, 3)
        The positions with the prior applied.
    cov : ndarray, shape (F, P, 3, 3)
        Their covariance: along each principal direction the gain ``g`` of that
        direction leaves ``((1 - g + g c_0)^2 + g^2 (c_0 - c_0^2)) lambda + g^2 tau^2``
        (``c_0``: the weight of the sample itself in the fit, whose variance it also
        is; ``tau^2``: the motion the fit cannot follow), plus ``shared * lambda``;
        ``(1 + shared) cov`` where nothing changed.

    Examples
    --------
    A still point whose depth (z) is noisy and whose x and y are exact:

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> X = np.zeros((60, 1, 3)); X[..., 2] = rng.normal(0, 0.2, (60, 1))
    >>> cov = np.zeros((60, 1, 3, 3)); cov[...] = np.diag([1e-4, 1e-4, 0.04])
    >>> Xs, _ = smooth_along_uncertainty(X, cov)
    >>> bool(np.std(Xs[..., 2]) < 0.7 * np.std(X[..., 2])), float(np.abs(Xs[..., :2]).max())
    (True, 0.0)
    """
    Xm = np.asarray(X, dtype=np.float64)
    Cm = np.asarray(cov, dtype=np.float64)
    w = int(window)
    if w < 5 or Xm.shape[0] < 5:
        return Xm.copy(), Cm.copy()
    half = w // 2
    fit, c0 = _local_quadratic(Xm, half, min_support=5)
    use = np.isfinite(fit).all(-1) & np.isfinite(Cm).all((-1, -2))
    out_X = Xm.copy()
    out_C = Cm * (1.0 + float(shared))
    if not use.any():
        return out_X, out_C
    F, P = Xm.shape[:2]
    ok_cov = np.isfinite(Cm).all((-1, -2))
    # the refits below only take samples away, so every later `use` is within this one
    lam_all = np.full((F, P, 3), np.nan)
    U_all = np.full((F, P, 3, 3), np.nan)
    lam_all[use], U_all[use] = np.linalg.eigh(Cm[use])
    lam_all = np.maximum(lam_all, 0.0)
    tau2 = _motion_miss(Xm, fit, c0, lam_all, U_all, use, half, tau_mm)
    # outliers: a sample whose leave-one-out residual to the fit along its worst-seen
    # direction is far beyond its variance there, the fit's and the motion's (a wrong
    # match along a one-caddy depth) is left out of the fit of its neighbours in time
    # and its variance along that direction is inflated to what it departs by (so its
    # depth follows the fit, and its sigma says so)
    out_s = float(outlier_sigmas)
    flagged = np.zeros((F, P), bool)
    m2_flag = np.ones((F, P))
    c_orig = c0.copy()
    if out_s > 0:
        for _ in range(3):
            test = use & ~flagged & (c0 < 1.0)
            if not test.any():
                break
            # along the sample's worst-seen direction only (a wrong match's error lies
            # along it); the local departure across the image, where the sample is
            # well seen, is the motion the fit misses at that very frame (the onset of
            # a fast expression), allowed for as well
            cz = c0[test]
            loo = np.einsum("nji,nj->ni", U_all[test],
                            fit[test] - Xm[test]) / (1.0 - cz)[:, None]
            across = np.mean(loo[:, :2] ** 2, axis=1)
            m2 = loo[:, 2] ** 2 / (lam_all[test][:, 2] / (1.0 - cz) + tau2[test] + across)
            # an isolated outlier, not a noisy track: the others in the window must
            # agree with their fits (a run of biased blobs, one camera then the other,
            # leaves no right neighbours to follow)
            m2_all = np.full((F, P), np.nan)
            m2_all[test] = m2
            others = _others_max(m2_all, half)
            new = np.zeros((F, P), bool)
            new[test] = (m2 > out_s ** 2) & (m2 > OUTLIER_RATIO * others[test])
            if not new.any():
                break
            m2_flag[new] = m2[new[test]] / out_s ** 2
            flagged |= new
            Xf = np.where(flagged[..., None], np.nan, Xm)
            fit, c0 = _local_quadratic(Xf, half, min_support=5, centre=flagged)
            use = np.isfinite(fit).all(-1) & ok_cov
            tau2 = _motion_miss(Xm, fit, c0, lam_all, U_all, use & ~flagged, half, tau_mm)
    lam0 = lam_all[use]  # before the inflation
    lam = lam0.copy()
    lam[:, 2] *= np.where(flagged[use], m2_flag[use], 1.0)
    U = U_all[use]
    d = fit[use] - Xm[use]
    along = np.einsum("nji,nj->ni", U, d)  # components of the step along each direction
    c = c0[use][:, None]
    t2 = tau2[use][:, None]
    g = lam / (lam + t2)
    out_X[use] = Xm[use] + np.einsum("nij,nj->ni", U, g * along)
    # X' = (1 - g) X + g fit, and the fit weighs X itself by c_0 (the rest of its
    # variance, c_0 - c_0^2, comes from the other frames); a sample left out of its fit
    # (c_0 0) keeps the other frames' part, c_0 / (1 - c_0) of its own variance before
    # the fit left it out
    lam_new = ((1 - g + g * c) ** 2 + g ** 2 * (c - c ** 2)) * lam + g ** 2 * t2
    fl = flagged[use]
    if fl.any():
        co = c_orig[use][fl][:, None]
        lam_new[fl] = (1 - g[fl]) ** 2 * lam[fl] + g[fl] ** 2 * (co / (1 - co) * lam0[fl]
                                                                 + t2[fl])
    lam_new += float(shared) * lam0
    out_C[use] = np.einsum("nij,nj,nkj->nik", U, lam_new, U)
    return out_X, out_C


def _others_max(v: NDArray[np.float64], half: int) -> NDArray[np.float64]:
    """Largest finite value of ``v`` (F, P) over ``2 half + 1`` frames, each frame's own
    left out (0 where there is no other)."""
    from scipy.ndimage import maximum_filter

    foot = np.ones((2 * half + 1, 1), bool)
    foot[half, 0] = False
    return maximum_filter(np.where(np.isfinite(v), v, 0.0), footprint=foot,
                          mode="constant", cval=0.0)


def _motion_miss(X: NDArray[np.float64], fit: NDArray[np.float64], c0: NDArray[np.float64],
                 lam: NDArray[np.float64], U: NDArray[np.float64], use: NDArray[np.bool_],
                 half: int, tau_mm: float) -> NDArray[np.float64]:
    """(F, P) variance (mm^2) of the real motion about the local quadratic.

    How far the motion departs from the quadratic, measured where the sample is well
    seen: across the image the step to the fit is the motion the fit misses plus noise
    of variance (1 - c_0) lambda. Averaged over the window and taken as the same in
    every direction (fast lips and jaw get a small gain, a still face a large one);
    at least ``tau_mm`` squared.
    """
    miss = np.full(X.shape[:2], np.nan)
    if use.any():
        along = np.einsum("nji,nj->ni", U[use], fit[use] - X[use])
        c = c0[use][:, None]
        miss[use] = np.mean(along[:, :2] ** 2 - (1 - c) * lam[use][:, :2], axis=1)
    return float(tau_mm) ** 2 + np.maximum(np.nan_to_num(_window_mean(miss, half)), 0.0)
