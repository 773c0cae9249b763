"""Rigid registration: weighted Kabsch, its robust variant, and model-to-cloud RANSAC.

All transforms map ``src`` onto ``dst`` as ``dst ~ src @ R.T + t`` (row vectors; R a
proper rotation, t in the units of the points, mm in carapost).

- :func:`fit_rigid`: least-squares fit with known correspondences (optionally weighted),
  the SVD solution of Kabsch/Umeyama without scale.
- :func:`fit_rigid_robust`: the same with outliers among the correspondences (RANSAC
  over minimal samples, then refitted on the inliers); returns the inlier mask.
- :func:`kabsch`: the batched unweighted kernel (stacks of point sets at once).
- :func:`register_model`: correspondences unknown (the brim model in a triangulated
  cloud), by RANSAC over triplets with equal side lengths.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = ["RigidTransform", "fit_rigid", "fit_rigid_robust", "kabsch", "register_model"]


class RigidTransform(NamedTuple):
    """A fitted rigid transform ``dst ~ src @ R.T + t``.

    Attributes
    ----------
    R : ndarray, shape (3, 3)
        Rotation.
    t : ndarray, shape (3,)
        Translation (units of the points).
    rms : float
        Weighted RMS distance between ``src @ R.T + t`` and ``dst`` over the inliers.
    inliers : ndarray of bool, shape (N,)
        Correspondences used (all with a positive weight for :func:`fit_rigid`).
    """

    R: NDArray[np.float64]
    t: NDArray[np.float64]
    rms: float
    inliers: NDArray[np.bool_]


def kabsch(A: NDArray, B: NDArray) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares rotation and translation with ``B ~ A @ R.T + t``, batched.

    Parameters
    ----------
    A, B : ndarray, shape (..., N, 3)
        Corresponding point sets (N >= 3, not collinear for a unique answer).

    Returns
    -------
    R : ndarray, shape (..., 3, 3)
        Proper rotations (a reflection is never returned).
    t : ndarray, shape (..., 3)

    Examples
    --------
    >>> A = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> R, t = kabsch(A, A + [1.0, 2.0, 3.0])
    >>> bool(np.allclose(R, np.eye(3))), t.round(9).tolist()
    (True, [1.0, 2.0, 3.0])
    """
    ca = A.mean(-2, keepdims=True)
    cb = B.mean(-2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = cb[..., 0, :] - np.einsum("...ij,...j->...i", R, ca[..., 0, :])
    return R, t


def _as_pairs(src: ArrayLike, dst: ArrayLike) -> tuple[NDArray, NDArray]:
    A = np.asarray(src, dtype=np.float64)
    B = np.asarray(dst, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] != 3 or A.shape != B.shape:
        raise ValueError(f"src and dst must both have shape (N, 3), got {A.shape} and "
                         f"{B.shape}")
    return A, B


def fit_rigid(src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None
              ) -> RigidTransform:
    """Weighted least-squares rigid fit ``dst ~ src @ R.T + t`` (Kabsch, SVD).

    Parameters
    ----------
    src, dst : array_like, shape (N, 3)
        Corresponding points; rows with NaN are left out.
    weights : array_like, shape (N,), optional
        Non-negative weight per correspondence (default 1).

    Returns
    -------
    RigidTransform
        ``inliers`` marks the rows used (finite, positive weight).

    Raises
    ------
    ValueError
        For mismatched shapes, negative weights, or fewer than 3 usable rows.

    Examples
    --------
    >>> src = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    >>> R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])  # 90 deg about z
    >>> fit = fit_rigid(src, src @ R.T + [1.0, 2.0, 3.0])
    >>> bool(np.allclose(fit.R, R)), fit.t.round(9).tolist(), round(fit.rms, 9)
    (True, [1.0, 2.0, 3.0], 0.0)
    """
    A, B = _as_pairs(src, dst)
    w = np.ones(len(A)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
    if w.shape != (len(A),) or (w < 0).any():
        raise ValueError("weights must be one non-negative number per correspondence")
    use = np.isfinite(A).all(1) & np.isfinite(B).all(1) & (w > 0)
    if use.sum() < 3:
        raise ValueError(f"fit_rigid needs 3 or more usable correspondences, got "
                         f"{int(use.sum())}")
    a, b, ww = A[use], B[use], w[use]
    if weights is None:
        R, t = kabsch(a, b)
    else:
        s = ww / ww.sum()
        ca, cb = s @ a, s @ b
        H = (a - ca).T @ ((b - cb) * s[:, None])
        U, _, Vt = np.linalg.svd(H)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ D @ U.T
        t = cb - R @ ca
    d2 = ((a @ R.T + t - b) ** 2).sum(1)
    rms = float(np.sqrt((ww * d2).sum() / ww.sum()))
    return RigidTransform(R, t, rms, use)


def fit_rigid_robust(src: ArrayLike, dst: ArrayLike, *, threshold: float,
                     weights: ArrayLike | None = None, iterations: int = 200,
                     seed: int = 0) -> RigidTransform:
    """Rigid fit with outliers among the correspondences (RANSAC, then refit).

    Minimal samples of 3 correspondences are fitted by :func:`kabsch`; the hypothesis
    with the most correspondences within ``threshold`` (ties: smallest summed distance)
    is refitted by :func:`fit_rigid` on its inliers, and the refit repeated until the
    inlier set no longer changes (at most 10 times).

    Parameters
    ----------
    src, dst : array_like, shape (N, 3)
        Corresponding points; rows with NaN never count as inliers.
    threshold : float
        Largest distance of an inlier after the transform (units of the points).
    weights : array_like, shape (N,), optional
        Weights of the final fits (:func:`fit_rigid`).
    iterations : int
        Minimal samples tried.
    seed : int
        Seed of the sampling (results are reproducible).

    Returns
    -------
    RigidTransform
        With ``inliers`` the correspondences within ``threshold`` of the final fit.

    Raises
    ------
    ValueError
        For mismatched shapes or fewer than 3 usable rows.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(-50, 50, (20, 3))
    >>> dst = src + [0.0, 0.0, 100.0]
    >>> dst[:4] += 30.0  # four wrong correspondences
    >>> fit = fit_rigid_robust(src, dst, threshold=1.0)
    >>> int(fit.inliers.sum()), bool(np.allclose(fit.t, [0.0, 0.0, 100.0]))
    (16, True)
    """
    A, B = _as_pairs(src, dst)
    finite = np.flatnonzero(np.isfinite(A).all(1) & np.isfinite(B).all(1))
    if finite.size < 3:
        raise ValueError(f"fit_rigid_robust needs 3 or more usable correspondences, got "
                         f"{finite.size}")
    rng = np.random.default_rng(seed)
    picks = np.array([rng.choice(finite, 3, replace=False) for _ in range(int(iterations))])
    Rh, th = kabsch(A[picks], B[picks])  # (H, 3, 3), (H, 3)
    moved = np.einsum("hij,nj->hni", Rh, np.nan_to_num(A[finite])) + th[:, None, :]
    dist = np.linalg.norm(moved - B[finite][None], axis=-1)
    inl = dist < threshold
    score = np.where(inl, dist, 0.0).sum(1)
    best = np.lexsort((score, -inl.sum(1)))[0]
    keep = np.zeros(len(A), dtype=bool)
    keep[finite[inl[best]]] = True
    if keep.sum() < 3:
        keep[finite] = True
    w = None if weights is None else np.asarray(weights, np.float64).reshape(-1)
    fit = None
    for _ in range(10):
        fit = fit_rigid(A[keep], B[keep], None if w is None else w[keep])
        with np.errstate(invalid="ignore"):
            d = np.linalg.norm(A @ fit.R.T + fit.t - B, axis=1)
        new = np.isfinite(d) & (d < threshold)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
    assert fit is not None
    return RigidTransform(fit.R, fit.t, fit.rms, keep)


def register_model(
    model: NDArray, cloud: NDArray, *, tolerance: float, samples: int, seed: int,
    keep: int = 5,
) -> list[tuple[int, NDArray, NDArray]]:
    """Rigid registrations of a model to a cloud with unknown correspondences.

    RANSAC over model triplets: each sampled triplet (sides of at least 10 mm) is matched
    to every cloud triplet with the same side lengths (within ``tolerance``), fitted by
    :func:`kabsch`, and scored by the model points landing within ``tolerance`` of a
    cloud point; the best hypothesis of each sample is refitted on its inliers.

    Parameters
    ----------
    model : ndarray, shape (B, 3)
        Model points (mm).
    cloud : ndarray, shape (N, 3)
        Measured points (mm), possibly with clutter.
    tolerance : float
        Inlier distance and side-length tolerance (mm).
    samples : int
        Most model triplets tried (stops after 60 once 60 % of the model is explained).
    seed : int
        Seed of the triplet sampling (results are reproducible).
    keep : int
        Most distinct hypotheses returned.

    Returns
    -------
    list of (n_inliers, R, t)
        Up to ``keep`` distinct hypotheses with ``cloud ~ model @ R.T + t``, best first
        (most inliers, then smallest RMS).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> model = rng.uniform(-50, 50, (12, 3))
    >>> from carapost.algorithms.camera import rodrigues_to_matrix
    >>> R = rodrigues_to_matrix([0.1, -0.2, 0.3])
    >>> cloud = np.concatenate([model @ R.T + [5.0, 0.0, 200.0], rng.uniform(-80, 80, (5, 3))])
    >>> n, R_fit, t_fit = register_model(model, cloud, tolerance=1.0, samples=100, seed=0)[0]
    >>> n, bool(np.allclose(R_fit, R)), bool(np.allclose(t_fit, [5.0, 0.0, 200.0]))
    (12, True, True)
    """
    B, N = len(model), len(cloud)
    if B < 3 or N < 3:
        return []
    rng = np.random.default_rng(seed)
    Dm = np.linalg.norm(model[:, None] - model[None], axis=-1)
    Dq = np.linalg.norm(cloud[:, None] - cloud[None], axis=-1)
    hyps: list[tuple[int, float, NDArray, NDArray]] = []
    tol = tolerance
    tree = cKDTree(cloud)
    for n_sample in range(int(samples)):
        # enough tries once most of the brim is explained
        if n_sample >= 60 and hyps and max(h[0] for h in hyps) >= 0.6 * min(B, N):
            break
        i, j, k = rng.choice(B, 3, replace=False)
        # wide, non-degenerate triangles pin the pose best
        if min(Dm[i, j], Dm[i, k], Dm[j, k]) < 10.0:
            continue
        P, Q = np.nonzero(np.abs(Dq - Dm[i, j]) < tol)
        if P.size == 0:
            continue
        okr = (np.abs(Dq[P][:, :] - Dm[i, k]) < tol) & (np.abs(Dq[Q][:, :] - Dm[j, k]) < tol)
        pi, r = np.nonzero(okr)
        if pi.size == 0:
            continue
        tri_q = np.stack([cloud[P[pi]], cloud[Q[pi]], cloud[r]], 1)  # (H, 3, 3)
        tri_m = np.broadcast_to(model[[i, j, k]], tri_q.shape)
        Rh, th = kabsch(tri_m, tri_q)
        moved = np.einsum("hij,bj->hbi", Rh, model) + th[:, None, :]
        dist, _ = tree.query(moved.reshape(-1, 3), distance_upper_bound=tol)
        inl = (dist < tol).reshape(moved.shape[:2])
        n_in = inl.sum(1)
        best = int(np.argmax(n_in))
        if n_in[best] < 4:
            continue
        # refit on the inliers of the best hypothesis of this sample
        m = inl[best]
        _, nn = tree.query(moved[best][m])
        R2, t2 = kabsch(model[m], cloud[nn])
        d2, _ = tree.query(model @ R2.T + t2)
        n2 = int((d2 < tol).sum())
        rms = float(np.sqrt(np.mean(d2[d2 < tol] ** 2))) if n2 else np.inf
        hyps.append((n2, rms, R2, t2))
    hyps.sort(key=lambda h: (-h[0], h[1]))
    out: list[tuple[int, NDArray, NDArray]] = []
    for n, _, Rh, th in hyps:
        if any(np.abs(Rh - R0).max() < 1e-3 and np.abs(th - t0).max() < 0.5
               for _, R0, t0 in out):
            continue
        out.append((n, Rh, th))
        if len(out) >= keep:
            break
    return out
