"""Rigid registration: weighted Kabsch, robust fit, model-to-cloud RANSAC."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.camera import rodrigues_to_matrix
from carapost.algorithms.rigid import fit_rigid, fit_rigid_robust, kabsch, register_model


def _pose(rng):
    return rodrigues_to_matrix(rng.normal(0, 0.5, 3)), rng.normal(0, 50, 3)


def test_fit_rigid_recovers_a_transform_and_matches_the_batched_kernel(rng):
    R, t = _pose(rng)
    src = rng.uniform(-50, 50, (30, 3))
    dst = src @ R.T + t
    fit = fit_rigid(src, dst)
    assert np.allclose(fit.R, R) and np.allclose(fit.t, t) and fit.rms < 1e-9
    assert np.linalg.det(fit.R) == pytest.approx(1.0)
    Rk, tk = kabsch(src, dst)
    assert np.array_equal(Rk, fit.R) and np.array_equal(tk, fit.t)


def test_fit_rigid_weights_and_nan_rows(rng):
    R, t = _pose(rng)
    src = rng.uniform(-50, 50, (20, 3))
    dst = src @ R.T + t
    dst[0] += 40.0  # one wrong correspondence, weighted out
    src[1] = np.nan  # one missing
    w = np.ones(20)
    w[0] = 0.0
    fit = fit_rigid(src, dst, w)
    assert np.allclose(fit.R, R) and np.allclose(fit.t, t)
    assert not fit.inliers[0] and not fit.inliers[1] and fit.inliers[2:].all()
    # uniform weights give the unweighted answer
    ok = np.arange(2, 20)
    a = fit_rigid(src[ok], dst[ok], np.full(ok.size, 3.0))
    b = fit_rigid(src[ok], dst[ok])
    assert np.allclose(a.R, b.R) and np.allclose(a.t, b.t)


def test_fit_rigid_refuses_bad_input():
    with pytest.raises(ValueError, match="shape"):
        fit_rigid(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="3 or more"):
        fit_rigid(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="non-negative"):
        fit_rigid(np.zeros((4, 3)), np.zeros((4, 3)), [-1, 1, 1, 1])


def test_fit_rigid_robust_ignores_outliers(rng):
    R, t = _pose(rng)
    src = rng.uniform(-50, 50, (40, 3))
    dst = src @ R.T + t + rng.normal(0, 0.05, (40, 3))
    bad = rng.choice(40, 12, replace=False)
    dst[bad] += rng.uniform(10, 30, (12, 3))
    fit = fit_rigid_robust(src, dst, threshold=0.5, seed=1)
    assert set(np.flatnonzero(~fit.inliers)) == set(bad)
    assert np.allclose(fit.R, R, atol=1e-3) and np.allclose(fit.t, t, atol=0.1)
    again = fit_rigid_robust(src, dst, threshold=0.5, seed=1)
    assert np.array_equal(again.R, fit.R)  # reproducible


def test_register_model_finds_a_brim_in_clutter(rng):
    from carapost.io.brim_svg import DEFAULT_BRIM_VERSIONS, default_brim

    model = default_brim(DEFAULT_BRIM_VERSIONS[0])[1]
    R, t = _pose(rng)
    cloud = np.concatenate([model[3:] @ R.T + t, rng.uniform(-100, 100, (30, 3)) + t])
    hyps = register_model(model, cloud, tolerance=1.0, samples=300, seed=0)
    n, Rf, tf = hyps[0]
    assert n == len(model) - 3
    assert np.allclose(Rf, R, atol=1e-6) and np.allclose(tf, t, atol=1e-4)
