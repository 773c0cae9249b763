"""Sparse least-squares machinery of bundle adjustment: Jacobian layout and LM-Schur.

A bundle-adjustment residual pair (one observation) depends on one camera block and one
3D point block. :func:`jacobian_structure` lays out the sparse Jacobian of such a problem
(for :func:`scipy.optimize.least_squares`), and :func:`lm_schur` is a Levenberg-Marquardt
solver that eliminates the points (Schur complement) and so never forms the full normal
equations. Used by :mod:`carapost.algorithms.bundle` and by the BAL benchmark.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

__all__ = ["JacobianStructure", "block_sum", "jacobian_structure", "lm_schur", "robust_loss",
           "sparse_jacobian"]


class JacobianStructure(NamedTuple):
    """Sparsity of a bundle-adjustment Jacobian (:func:`jacobian_structure`)."""

    rows: NDArray[np.intp]
    cols: NDArray[np.intp]
    select: NDArray[np.bool_]  # which of the dense per-observation entries are free
    shape: tuple[int, int]


def jacobian_structure(ci: NDArray[np.intp], pi: NDArray[np.intp], n_cam_par: int,
               cam_free: NDArray[np.bool_], pt_free: NDArray[np.bool_]) -> JacobianStructure:
    """Sparsity of a Jacobian whose residual pairs depend on one camera and one point block.

    Per observation the dense entries are laid out ``[2, n_cam_par + 3]``; entries of fixed
    cameras or points are dropped. Free cameras are numbered first, then free points.
    """
    No = ci.shape[0]
    cam_col = np.cumsum(cam_free) - 1
    pt_col = np.cumsum(pt_free) - 1
    n_cam_cols = int(cam_free.sum()) * n_cam_par
    k = n_cam_par + 3
    cols = np.empty((No, 2, k), np.intp)
    cols[:, :, :n_cam_par] = (cam_col[ci] * n_cam_par)[:, None, None] + np.arange(n_cam_par)
    cols[:, :, n_cam_par:] = (n_cam_cols + pt_col[pi] * 3)[:, None, None] + np.arange(3)
    rows = np.broadcast_to((2 * np.arange(No))[:, None, None] + np.arange(2)[:, None],
                           (No, 2, k))
    select = np.empty((No, 2, k), bool)
    select[:, :, :n_cam_par] = cam_free[ci][:, None, None]
    select[:, :, n_cam_par:] = pt_free[pi][:, None, None]
    shape = (2 * No, n_cam_cols + int(pt_free.sum()) * 3)
    return JacobianStructure(rows[select], cols[select], select, shape)


def sparse_jacobian(struct: JacobianStructure, dense: NDArray[np.float64]) -> sp.csr_matrix:
    """Sparse Jacobian from per-observation dense blocks ``[No, 2, k]``."""
    return sp.csr_matrix((dense[struct.select], (struct.rows, struct.cols)), shape=struct.shape)


def block_sum(blocks: NDArray[np.float64], index: NDArray[np.intp], n: int
               ) -> NDArray[np.float64]:
    """Sum ``blocks [N, ...]`` into ``[n, ...]`` by ``index`` (bincount per entry).

    Examples
    --------
    >>> block_sum(np.ones((3, 2, 2)), np.array([0, 2, 0]), 3)[:, 0, 0].tolist()
    [2.0, 0.0, 1.0]
    """
    shape = blocks.shape[1:]
    m = int(np.prod(shape))
    flat = (index[:, None] * m + np.arange(m)).ravel()
    return np.bincount(flat, weights=blocks.reshape(-1), minlength=n * m).reshape((n,) + shape)


def robust_loss(loss: str, s: NDArray[np.float64], delta: float
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Robust cost ``rho(s)`` and weight ``rho'(s)`` of squared observation errors ``s``.

    ``loss`` is one of scipy's names ("linear", "huber", "soft_l1", "cauchy") and
    ``delta`` its ``f_scale`` (px).

    Examples
    --------
    >>> rho, w = robust_loss("huber", np.array([1.0, 16.0]), 2.0)
    >>> rho.tolist(), w.tolist()
    ([1.0, 12.0], [1.0, 0.5])
    """
    d2 = delta * delta
    if loss == "linear":
        return s, np.ones_like(s)
    if loss == "huber":
        root = np.sqrt(s)
        inlier = root <= delta
        return (np.where(inlier, s, 2 * delta * root - d2),
                np.where(inlier, 1.0, delta / np.maximum(root, 1e-300)))
    if loss == "soft_l1":
        q = np.sqrt(1 + s / d2)
        return 2 * d2 * (q - 1), 1 / q
    if loss == "cauchy":
        return d2 * np.log1p(s / d2), 1 / (1 + s / d2)
    raise ValueError(f"loss must be 'linear', 'huber', 'soft_l1' or 'cauchy', got {loss!r}")


def lm_schur(
    fun: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
    blocks: Callable[[NDArray[np.float64], NDArray[np.float64]],
                     tuple[NDArray[np.float64], NDArray[np.float64]]],
    cams: NDArray[np.float64], pts: NDArray[np.float64], ci: NDArray[np.intp],
    pi: NDArray[np.intp], *, ftol: float, max_iter: int, loss: str = "linear",
    f_scale: float = 1.0, cam_free: NDArray[np.bool_] | None = None,
    pt_free: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], int, int, bool, str]:
    """Levenberg-Marquardt with the Schur complement on the camera parameters.

    ``fun(cams, pts)`` gives residuals ``[No, 2]``; ``blocks(cams, pts)`` the camera and
    point Jacobian blocks ``[No, 2, k]`` and ``[No, 2, 3]`` of each observation. The point
    part of ``J^T J`` is block diagonal and inverted in batch; the reduced camera system
    ``U - W V^-1 W^T`` (one sparse product) is small and dense and solved by Cholesky.
    A robust loss on each observation's squared error is handled by iteratively
    re-weighted least squares. Stops when an accepted step lowers the cost by less than
    ``ftol`` times the cost (scipy's ``ftol`` rule). Fixed cameras / points keep their
    values (their blocks are replaced by identities with zero gradient).
    """
    import scipy.linalg as sla

    Nc, k = cams.shape
    Np = pts.shape[0]
    No = ci.shape[0]
    cam_free = np.ones(Nc, bool) if cam_free is None else cam_free
    pt_free = np.ones(Np, bool) if pt_free is None else pt_free
    c_on = cam_free[ci][:, None, None]
    p_on = pt_free[pi][:, None, None]
    # Sparsity of W (camera params x point params), fixed across iterations.
    w_rows = ((ci * k)[:, None, None] + np.arange(k)[:, None]).repeat(3, 2).ravel()
    w_cols = ((pi * 3)[:, None, None] + np.arange(3)[None, :]).repeat(k, 1).ravel()
    wt_rows = w_cols.reshape(No, k, 3).transpose(0, 2, 1).ravel()
    wt_cols = w_rows.reshape(No, k, 3).transpose(0, 2, 1).ravel()
    eye_k, eye_3 = np.eye(k), np.eye(3)
    # CSR templates: the position of every dense entry in the CSR data arrays, so W and
    # W V^-1 are built without a COO conversion each time (valid when every camera sees a
    # point at most once; otherwise fall back to COO, which sums duplicates).
    unique_pairs = np.unique(ci * Np + pi).size == No

    def template(rows: NDArray[np.intp], cols: NDArray[np.intp], shape: tuple[int, int]
                 ) -> tuple[sp.csr_matrix, NDArray[np.intp]] | None:
        if not unique_pairs:
            return None
        m = sp.csr_matrix((np.arange(1, rows.size + 1, dtype=np.float64), (rows, cols)),
                          shape=shape)
        m.sort_indices()
        return m, (m.data.astype(np.intp) - 1)

    def build(tmpl: tuple[sp.csr_matrix, NDArray[np.intp]] | None, data: NDArray[np.float64],
              rows: NDArray[np.intp], cols: NDArray[np.intp], shape: tuple[int, int]
              ) -> sp.csr_matrix:
        if tmpl is None:
            return sp.csr_matrix((data, (rows, cols)), shape=shape)
        m, src = tmpl
        return sp.csr_matrix((data[src], m.indices, m.indptr), shape=shape)

    y_shape, wt_shape = (Nc * k, Np * 3), (Np * 3, Nc * k)
    y_tmpl = template(w_rows, w_cols, y_shape)
    wt_tmpl = template(wt_rows, wt_cols, wt_shape)
    # Observations sorted by camera: U is one small product per camera.
    by_cam = np.argsort(ci, kind="stable")
    cam_bounds = np.concatenate([[0], np.cumsum(np.bincount(ci, minlength=Nc))])

    def robust_cost(r: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]]:
        rho, w = robust_loss(loss, (r * r).sum(-1), f_scale)
        return 0.5 * float(rho.sum()), w

    r = fun(cams, pts)
    cost, wts = robust_cost(r)
    lam = 1e-5
    nfev = njev = 1
    message, success = "maximum number of iterations reached", False
    for _ in range(max_iter):
        Jc, Jp = blocks(cams, pts)
        njev += 1
        sw = np.sqrt(wts)[:, None]
        rw = r * sw
        Jc = np.where(c_on, Jc * sw[:, :, None], 0.0)
        Jp = np.where(p_on, Jp * sw[:, :, None], 0.0)
        JcT = Jc.transpose(0, 2, 1)
        JpT = Jp.transpose(0, 2, 1)
        Jc_sorted = Jc[by_cam].reshape(-1, k)
        U = np.stack([Jc_sorted[2 * a:2 * b].T @ Jc_sorted[2 * a:2 * b]
                      for a, b in zip(cam_bounds[:-1], cam_bounds[1:], strict=True)])
        U[~cam_free] = eye_k
        V = block_sum(JpT @ Jp, pi, Np)
        V[~pt_free] = eye_3
        W = JcT @ Jp  # [No, k, 3]
        gc = block_sum((JcT @ rw[:, :, None])[:, :, 0], ci, Nc)
        gp = block_sum((JpT @ rw[:, :, None])[:, :, 0], pi, Np)
        Wt = build(wt_tmpl, W.transpose(0, 2, 1).ravel(), wt_rows, wt_cols, wt_shape)
        while True:
            Ud = U + lam * (np.einsum("cii->ci", U)[:, :, None] * eye_k + 1e-9 * eye_k)
            Vd = V + lam * (np.einsum("pii->pi", V)[:, :, None] * eye_3 + 1e-9 * eye_3)
            Vinv = np.linalg.inv(Vd)
            Y = W @ Vinv[pi]  # [No, k, 3]
            Ys = build(y_tmpl, Y.ravel(), w_rows, w_cols, y_shape)
            S = -(Ys @ Wt).toarray()
            S.reshape(Nc, k, Nc, k)[np.arange(Nc), :, np.arange(Nc), :] += Ud
            rhs = -gc.ravel() + Ys @ gp.ravel()
            try:
                dc = sla.cho_solve(sla.cho_factor(S, check_finite=False), rhs,
                                   check_finite=False).reshape(Nc, k)
            except (np.linalg.LinAlgError, ValueError):
                lam *= 10.0
                if lam > 1e12:
                    return cams, pts, nfev, njev, False, "reduced camera system is singular"
                continue
            WTdc = block_sum((W.transpose(0, 2, 1) @ dc[ci][:, :, None])[:, :, 0], pi, Np)
            dp = np.einsum("pij,pj->pi", Vinv, -gp - WTdc)
            cams_n, pts_n = cams + dc, pts + dp
            r_n = fun(cams_n, pts_n)
            nfev += 1
            cost_n, wts_n = robust_cost(r_n)
            if np.isfinite(cost_n) and cost_n < cost:
                lam = max(lam / 5.0, 1e-12)
                break
            lam *= 5.0
            if lam > 1e12:
                return cams, pts, nfev, njev, True, "no further decrease of the cost"
        dF = cost - cost_n
        cams, pts, r, cost, wts = cams_n, pts_n, r_n, cost_n, wts_n
        if dF < ftol * cost:
            message, success = "`ftol` termination condition is satisfied.", True
            break
    return cams, pts, nfev, njev, success, message
