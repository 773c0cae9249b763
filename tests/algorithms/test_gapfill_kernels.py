"""The compiled gap-filling kernels against plain numpy statements of the same steps."""

from __future__ import annotations

import numpy as np

from carapost.algorithms.gapfill_methods import lowrank_fill, spline_fill


def _em_reference(Y, known, energy, max_rank, outer, inner):
    """Low-rank completion as the documented iteration, whole-matrix numpy products."""
    F, P, _ = Y.shape
    D = 3 * P
    K = np.repeat(known, 3, axis=1)
    M = np.where(known[..., None], Y, 0.0).reshape(F, D)
    mean = M.sum(0) / np.maximum(K.sum(0), 1)
    Z = M - mean
    t = np.arange(F)
    for j in range(D):
        Z[~K[:, j], j] = np.interp(t[~K[:, j]], t[K[:, j]], Z[K[:, j], j])
    for _ in range(outer):
        ev, V = np.linalg.eigh(Z.T @ Z / F)
        ev, V = ev[::-1], V[:, ::-1]
        k = max(1, min(int(np.searchsorted(np.cumsum(ev) / ev.sum(), energy) + 1), max_rank,
                       D - 1))
        U = V[:, :k]
        for _ in range(inner):
            np.copyto(Z, (Z @ U) @ U.T, where=~K)
    return (Z + mean).reshape(F, P, 3)


def test_compiled_em_steps_equal_the_whole_matrix_iteration():
    rng = np.random.default_rng(3)
    F, P = 300, 9
    t = np.arange(F) / 50.0
    modes = rng.normal(size=(3, P, 3)) * 4
    Y = (rng.normal(size=(P, 3)) * 30)[None] + np.einsum(
        "fm,mpi->fpi", np.stack([np.sin(t), np.cos(1.7 * t), np.sin(0.4 * t)], 1), modes)
    Y += rng.normal(scale=0.05, size=Y.shape)
    known = rng.random((F, P)) > 0.08
    known[0] = known[-1] = True
    Yn = np.where(known[..., None], Y, np.nan)
    got = lowrank_fill(Yn, known, np.zeros((F, P), bool), energy=0.99, max_rank=20, outer=3,
                       inner=6)
    ref = _em_reference(Y, known, 0.99, 20, 3, 6)
    # float32 storage of the matrix: agreement to a few micrometres
    assert np.abs(got[~known] - ref[~known]).max() < 1e-3
    assert np.abs(got[~known] - Y[~known]).max() < 1.0


def test_spline_without_neighbours_over_the_window_is_the_plain_local_cubic():
    F = 60
    t = np.arange(F, dtype=np.float64)
    Y = np.zeros((F, 2, 3), np.float32)
    Y[:, 0] = np.stack([0.01 * t**3 - 0.2 * t**2, t, 2 * t], -1)
    Y[:, 1] = 5.0
    known = np.ones((F, 2), bool)
    known[28:33, 1] = False                     # the neighbour is missing in the window
    known[30:32, 0] = False
    nb = np.array([[1], [0]])
    nbw = np.array([[1.0], [1.0]], np.float32)   # float32 weights, as neighbour_table gives
    out = spline_fill(Y, known, np.array([0]), np.array([30]), np.array([31]),
                      np.array([True]), np.array([True]), nb, nbw)
    assert np.isfinite(out).all()
    assert np.abs(out - Y[30:32, 0]).max() < 1e-2
