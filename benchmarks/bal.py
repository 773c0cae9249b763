"""Bundle Adjustment in the Large (BAL): problem reader, Snavely camera, solver comparison.

A benchmark harness, not product code: it checks the product's Levenberg-Marquardt /
Schur machinery (:mod:`carapost.algorithms.lm`) against :func:`scipy.optimize.least_squares`
on public BAL problems (Snavely's camera: rotation vector, translation, f, k1, k2, camera
looking down -z). Used by ``benchmarks/bundle.py`` and ``tests/algorithms/test_bundle.py``
(which load this file by path).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.optimize import least_squares

from carapost.algorithms.bundle import left_jacobian
from carapost.algorithms.camera import cross_matrix, rodrigues_to_matrix
from carapost.algorithms.lm import jacobian_structure, lm_schur, sparse_jacobian


def _rms(r: NDArray[np.float64]) -> float:
    """RMS reprojection error (px) of a residual vector (pairs of x, y)."""
    r = r.reshape(-1, 2)
    return float(np.sqrt((r**2).sum(-1).mean())) if r.size else float("nan")


class BALProblem(NamedTuple):
    """A BAL problem: ``cameras [Nc, 9]`` (rotation vector, t, f, k1, k2), ``points [Np, 3]``,
    and per observation the camera index, point index and pixel position ``[No, 2]``."""

    cameras: NDArray[np.float64]
    points: NDArray[np.float64]
    camera_index: NDArray[np.intp]
    point_index: NDArray[np.intp]
    observations: NDArray[np.float64]


def read_bal(path: str | Path) -> BALProblem:
    """Read a BAL text problem file.

    Raises
    ------
    ValueError
        When the file does not hold the number of values its header announces.
    """
    path = Path(path)
    with open(path, encoding="ascii") as fh:
        header = fh.readline().split()
        if len(header) != 3:
            raise ValueError(f"{path}: first line must be '<cameras> <points> <observations>'")
        nc, npt, no = (int(v) for v in header)
        data = np.array(fh.read().split(), dtype=np.float64)
    expected = 4 * no + 9 * nc + 3 * npt
    if data.size != expected:
        raise ValueError(f"{path}: expected {expected} values after the header, found {data.size}")
    obs = data[: 4 * no].reshape(no, 4)
    cams = data[4 * no: 4 * no + 9 * nc].reshape(nc, 9)
    pts = data[4 * no + 9 * nc:].reshape(npt, 3)
    return BALProblem(cams, pts, obs[:, 0].astype(np.intp), obs[:, 1].astype(np.intp), obs[:, 2:])


def bal_residuals(cameras: NDArray[np.float64], points: NDArray[np.float64],
                  camera_index: NDArray[np.intp], point_index: NDArray[np.intp],
                  observations: NDArray[np.float64]) -> NDArray[np.float64]:
    """Snavely-model reprojection residuals ``[No, 2]`` (px)."""
    cam = cameras[camera_index]
    P = np.einsum("nij,nj->ni", rodrigues_to_matrix(cam[:, :3]), points[point_index]) + cam[:, 3:6]
    p = -P[:, :2] / P[:, 2:3]
    s = (p * p).sum(-1)
    rho = 1 + s * (cam[:, 7] + s * cam[:, 8])
    return cam[:, 6:7] * rho[:, None] * p - observations


def _bal_jacobian(cameras: NDArray[np.float64], points: NDArray[np.float64],
                  ci: NDArray[np.intp], pi: NDArray[np.intp]) -> NDArray[np.float64]:
    """Dense per-observation Jacobian blocks ``[No, 2, 12]`` (camera 9, point 3)."""
    cam = cameras[ci]
    Rn = rodrigues_to_matrix(cam[:, :3])
    RX = np.einsum("nij,nj->ni", Rn, points[pi])
    P = RX + cam[:, 3:6]
    iz = 1.0 / P[:, 2]
    p = -P[:, :2] * iz[:, None]
    s = (p * p).sum(-1)
    f, k1, k2 = cam[:, 6], cam[:, 7], cam[:, 8]
    rho = 1 + s * (k1 + s * k2)
    drho = k1 + 2 * k2 * s
    No = P.shape[0]
    dp_dP = np.zeros((No, 2, 3))
    dp_dP[:, 0, 0] = -iz
    dp_dP[:, 1, 1] = -iz
    dp_dP[:, 0, 2] = -p[:, 0] * iz
    dp_dP[:, 1, 2] = -p[:, 1] * iz
    dproj_dp = f[:, None, None] * (rho[:, None, None] * np.eye(2)
                                   + 2 * drho[:, None, None] * p[:, :, None] * p[:, None, :])
    A = dproj_dp @ dp_dP
    J = np.empty((No, 2, 12))
    J[:, :, 0:3] = -A @ cross_matrix(RX) @ left_jacobian(cam[:, :3])
    J[:, :, 3:6] = A
    J[:, :, 6] = rho[:, None] * p
    J[:, :, 7] = (f * s)[:, None] * p
    J[:, :, 8] = (f * s * s)[:, None] * p
    J[:, :, 9:12] = A @ Rn
    return J


class BALResult(NamedTuple):
    """Result of :func:`bundle_adjust_bal`: refined arrays, costs (0.5 sum r^2), RMS (px)."""

    cameras: NDArray[np.float64]
    points: NDArray[np.float64]
    cost_initial: float
    cost_final: float
    rms_initial: float
    rms_final: float
    nfev: int
    njev: int
    seconds: float
    success: bool
    message: str


def bal_sparsity(problem: BALProblem) -> sp.csr_matrix:
    """0/1 sparsity of the BAL Jacobian (for a finite-difference ``jac_sparsity``)."""
    nc, npt = problem.cameras.shape[0], problem.points.shape[0]
    struct = jacobian_structure(problem.camera_index, problem.point_index, 9, np.ones(nc, bool),
                        np.ones(npt, bool))
    return sp.csr_matrix((np.ones(struct.rows.size, np.int8), (struct.rows, struct.cols)),
                         shape=struct.shape)


def bundle_adjust_bal(
    problem: BALProblem,
    *,
    solver: str = "schur",
    jacobian: str = "analytic",
    loss: str = "linear",
    f_scale: float = 1.0,
    max_nfev: int | None = None,
    ftol: float = 1e-4,
    x_scale: str = "jac",
) -> BALResult:
    """Bundle-adjust a BAL problem.

    Parameters
    ----------
    problem : BALProblem
    solver : {"schur", "least_squares"}
        ``"schur"``: Levenberg-Marquardt on the analytic Jacobian with the points
        eliminated (Schur complement; linear loss only). ``"least_squares"``:
        :func:`scipy.optimize.least_squares` (TRF, LSMR).
    jacobian : {"analytic", "fd"}
        For ``least_squares``: the analytic sparse Jacobian, or scipy's finite differences
        with ``jac_sparsity`` (the reference).
    loss, f_scale, max_nfev, ftol, x_scale
        As in :func:`scipy.optimize.least_squares` (``max_nfev`` bounds the number of
        iterations of the Schur solver).

    Returns
    -------
    BALResult
    """
    if jacobian not in ("analytic", "fd"):
        raise ValueError(f"jacobian must be 'analytic' or 'fd', got {jacobian!r}")
    if solver not in ("schur", "least_squares"):
        raise ValueError(f"solver must be 'schur' or 'least_squares', got {solver!r}")
    if solver == "schur" and (loss != "linear" or jacobian != "analytic"):
        raise ValueError("solver 'schur' supports loss='linear' with the analytic Jacobian")
    nc, npt = problem.cameras.shape[0], problem.points.shape[0]
    ci, pi, obs = problem.camera_index, problem.point_index, problem.observations

    def split(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return x[: 9 * nc].reshape(nc, 9), x[9 * nc:].reshape(npt, 3)

    def fun(x: NDArray[np.float64]) -> NDArray[np.float64]:
        cams, pts = split(x)
        return bal_residuals(cams, pts, ci, pi, obs).ravel()

    struct = jacobian_structure(ci, pi, 9, np.ones(nc, bool), np.ones(npt, bool))

    def jac(x: NDArray[np.float64]) -> sp.csr_matrix:
        cams, pts = split(x)
        return sparse_jacobian(struct, _bal_jacobian(cams, pts, ci, pi))

    x0 = np.concatenate([problem.cameras.ravel(), problem.points.ravel()])
    r0 = fun(x0)
    t0 = time.perf_counter()
    if solver == "schur":
        def blocks(cams: NDArray[np.float64], pts: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
            J = _bal_jacobian(cams, pts, ci, pi)
            return J[:, :, :9], J[:, :, 9:]

        cams, pts, nfev, njev, ok, msg = lm_schur(
            lambda c, p: bal_residuals(c, p, ci, pi, obs), blocks, problem.cameras.copy(),
            problem.points.copy(), ci, pi, ftol=ftol,
            max_iter=100 if max_nfev is None else max_nfev)
        seconds = time.perf_counter() - t0
        r1 = bal_residuals(cams, pts, ci, pi, obs).ravel()
        return BALResult(cams, pts, 0.5 * float(r0 @ r0), 0.5 * float(r1 @ r1), _rms(r0),
                         _rms(r1), nfev, njev, seconds, ok, msg)
    if jacobian == "analytic":
        sol = least_squares(fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale,
                            x_scale=x_scale, tr_solver="lsmr", ftol=ftol, max_nfev=max_nfev)
    else:
        sol = least_squares(fun, x0, jac_sparsity=bal_sparsity(problem), method="trf",
                            loss=loss, f_scale=f_scale, x_scale=x_scale, tr_solver="lsmr",
                            ftol=ftol, max_nfev=max_nfev)
    seconds = time.perf_counter() - t0
    cams, pts = split(sol.x)
    r1 = fun(sol.x)
    return BALResult(cams, pts, 0.5 * float(r0 @ r0), 0.5 * float(r1 @ r1), _rms(r0), _rms(r1),
                     int(sol.nfev), int(sol.njev or 0), seconds, bool(sol.success),
                     str(sol.message))
