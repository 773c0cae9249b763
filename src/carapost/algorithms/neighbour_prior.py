"""A depth prior from the face's neighbours for points whose depth the cameras barely fix.

Skin moves with the skin around it: over a take, a marker keeps nearly the same offset
from each of its neighbours, changed only by how the face deforms between them. A point
whose depth its cameras fix poorly (a marker seen by the two cameras of one caddy at a
grazing angle, or with noisy blobs: a millimetre of depth error from a pixel) is
predicted by its neighbours (:func:`patch_prediction`: each neighbour's position plus
the point's median offset from it over the take) to a few tenths of a millimetre in
every direction. :func:`fuse` combines each sample with that prediction by their
covariances: the sample's own (its observation geometry, after the depth prior from
time) and the prediction's, isotropic with the deformation measured for the point
(:func:`deformation_sigma`, from the directions its cameras do fix). A well-seen sample
barely moves; a poorly seen depth moves most of the way to the neighbours'.

Units: mm. Shapes: ``F`` frames, ``P`` points.

Examples
--------
A point 5 mm above four neighbours, all moving together; its depth (z) is noisy:

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> F = 50
>>> base = np.array([[0., 0, 5], [10, 0, 0], [-10, 0, 0], [0, 10, 0], [0, -10, 0]])
>>> truth = base[None] + np.linspace(0, 3, F)[:, None, None]
>>> X = truth + rng.normal(0, 0.01, truth.shape)
>>> X[:, 0, 2] += rng.normal(0, 1.0, F)
>>> tri = np.ones((F, 5), bool)
>>> nb = np.array([[1, 2, 3, 4], [0, 3, 4, -1], [0, 3, 4, -1], [0, 1, 2, -1],
...                [0, 1, 2, -1]])
>>> cov = np.zeros((F, 5, 3, 3)); cov[...] = np.diag([1e-4, 1e-4, 1e-4])
>>> cov[:, 0] = np.diag([1e-4, 1e-4, 1.0])
>>> pred = patch_prediction(X, tri, nb)
>>> tau = deformation_sigma(X, pred, cov, tri)
>>> Xf, _ = fuse(X, cov, pred, tau, tri)
>>> e0 = np.abs(X[:, 0, 2] - truth[:, 0, 2]).mean()
>>> e1 = np.abs(Xf[:, 0, 2] - truth[:, 0, 2]).mean()
>>> bool(e1 < 0.3 * e0)
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["deformation_sigma", "fuse", "patch_prediction"]

#: Least deformation (mm) assumed between a point and its neighbours over a take.
MIN_DEFORMATION_MM = 0.1


def patch_prediction(X: ArrayLike, tri: ArrayLike, nb: NDArray[np.intp]
                     ) -> NDArray[np.float64]:
    """Each point predicted from its neighbours: their positions plus its median offset
    from each over the take, averaged over the neighbours present.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
        Positions (mm).
    tri : array_like, shape (F, P)
        Samples to use (triangulated).
    nb : ndarray of int, shape (P, k)
        Each point's neighbours (-1 for none).

    Returns
    -------
    ndarray, shape (F, P, 3)
        Predictions (NaN where no neighbour is present, or the point was never seen).
    """
    X = np.asarray(X, np.float64)
    tri = np.asarray(tri, bool) & np.isfinite(X).all(-1)
    Xt = np.where(tri[..., None], X, np.nan)
    F, P = tri.shape
    pred = np.full((F, P, 3), np.nan)
    for p in range(P):
        n = nb[p][nb[p] >= 0]
        if n.size == 0 or not tri[:, p].any():
            continue
        both = tri[:, p:p + 1] & tri[:, n]
        ok = both.sum(0) >= 3
        if not ok.any():
            continue
        n = n[ok]
        with np.errstate(all="ignore"):
            off = np.nanmedian(Xt[:, p:p + 1] - Xt[:, n], axis=0)  # (n, 3)
            cand = Xt[:, n] + off[None]
            have = np.isfinite(cand).all(-1)
            s = np.where(have[..., None], cand, 0.0).sum(1)
            c = have.sum(1)
        pred[:, p] = np.where((c > 0)[:, None], s / np.maximum(c, 1)[:, None], np.nan)
    return pred


def _worst_direction(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """(..., 3) unit eigenvector of the largest eigenvalue of each 3x3 covariance."""
    c = np.nan_to_num(cov)
    _, v = np.linalg.eigh(c)
    return v[..., :, -1]


def deformation_sigma(X: ArrayLike, pred: ArrayLike, cov: ArrayLike, tri: ArrayLike
                      ) -> NDArray[np.float64]:
    """Per point, the deviation (mm per axis) of real positions from the neighbours'
    prediction, measured across each sample's worst direction (where the cameras fix
    the point, so the measurement's own error does not count).

    Parameters
    ----------
    X, pred : array_like, shape (F, P, 3)
    cov : array_like, shape (F, P, 3, 3)
        Each sample's covariance (mm^2).
    tri : array_like, shape (F, P)

    Returns
    -------
    ndarray, shape (P,)
        RMS per axis, at least `MIN_DEFORMATION_MM`; NaN for points never predicted.
    """
    X = np.asarray(X, np.float64)
    pred = np.asarray(pred, np.float64)
    d = pred - X
    ok = np.asarray(tri, bool) & np.isfinite(d).all(-1) & np.isfinite(cov).all((-1, -2))
    v = _worst_direction(np.asarray(cov, np.float64))
    perp = d - np.einsum("fpi,fpi->fp", d, v)[..., None] * v
    sq = np.where(ok, np.sum(perp ** 2, -1) / 2.0, np.nan)
    tau = np.full(sq.shape[1], np.nan)
    seen = ok.any(0)
    # per axis: |perp|^2 / 2 of a 2-D normal has its median at s^2 ln 2
    tau[seen] = np.sqrt(np.nanmedian(sq[:, seen], axis=0) / np.log(2.0))
    return np.where(np.isfinite(tau), np.maximum(tau, MIN_DEFORMATION_MM), np.nan)


def fuse(X: ArrayLike, cov: ArrayLike, pred: ArrayLike, tau: ArrayLike, mask: ArrayLike,
         *, gate: float = 3.0, gate_along: float = 6.0
         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Combine each masked sample with the neighbours' prediction by their covariances.

    ``X + K (pred - X)`` with ``K = cov (cov + tau^2 I)^-1``; the covariance becomes
    ``(I - K) cov``. A sample further than ``gate`` standard deviations from its
    prediction across its worst direction (Mahalanobis over ``cov + tau^2 I`` in the
    plane of the two other principal directions of ``cov``), or further than
    ``gate_along`` along it, is left alone: a disagreement where the cameras fix the
    sample is the prediction's failure (a deformation its neighbours do not share).
    Along the worst direction (a one-caddy depth) the gate is wider: a large
    disagreement there is what a poorly seen sample shows (the errors of its blobs,
    thin or low-contrast ones above all, have heavier tails than the covariance), and
    it is where the prediction is trusted most; only a deformation far beyond that
    (a lip corner moving millimetres in depth on its own) is left as measured.

    Parameters
    ----------
    X : array_like, shape (F, P, 3)
    cov : array_like, shape (F, P, 3, 3)
    pred : array_like, shape (F, P, 3)
    tau : array_like, shape (P,)
        The prediction's per-axis deviation (mm).
    mask : array_like, shape (F, P)
    gate, gate_along : float
        Standard deviations across and along each sample's worst direction.

    Returns
    -------
    X : ndarray, shape (F, P, 3)
    cov : ndarray, shape (F, P, 3, 3)
        Unchanged where not masked or no prediction exists.
    """
    X = np.array(X, np.float64)
    cov = np.array(cov, np.float64)
    pred = np.asarray(pred, np.float64)
    tau = np.asarray(tau, np.float64)
    m = np.asarray(mask, bool) & np.isfinite(pred).all(-1) & np.isfinite(X).all(-1) & \
        np.isfinite(cov).all((-1, -2)) & np.isfinite(tau)[None, :]
    fi, pi = np.nonzero(m)
    if fi.size == 0:
        return X, cov
    C = cov[fi, pi]
    t2 = tau[pi] ** 2
    S = C + t2[:, None, None] * np.eye(3)
    # where the two disagree beyond their covariances the prediction has failed: the
    # sample is left as it is. Along the worst direction the gate is wider: on the
    # tuning takes of other renderers one gate of 3 over all directions kept the worst
    # one-caddy samples (3-4 mm, 3-3.5 sigma off along their depth) from their
    # neighbours' prediction (docs/benchmarks.md, eleventh session, t22d)
    lam, V = np.linalg.eigh(C)  # ascending: V[..., 2] is the worst direction
    d = pred[fi, pi] - X[fi, pi]
    a = np.einsum("nij,ni->nj", V, d)  # (n, 3) along the principal directions
    s2 = lam + t2[:, None]
    across = np.sum(a[:, :2] ** 2 / s2[:, :2], axis=-1)
    along = a[:, 2] ** 2 / s2[:, 2]
    keep = (across <= gate ** 2) & (along <= gate_along ** 2)
    fi, pi, C, S = fi[keep], pi[keep], C[keep], S[keep]
    K = np.linalg.solve(S.transpose(0, 2, 1), C.transpose(0, 2, 1)).transpose(0, 2, 1)
    X[fi, pi] += np.einsum("nij,nj->ni", K, pred[fi, pi] - X[fi, pi])
    cov[fi, pi] = C - np.einsum("nij,njk->nik", K, C)
    return X, cov
