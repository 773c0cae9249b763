"""The depth prior from the face's neighbours: a poorly seen depth follows the patch,
a deformation the neighbours do not share is left alone."""

import numpy as np

from carapost.algorithms.neighbour_prior import deformation_sigma, fuse, patch_prediction
from carapost.algorithms.single_sensor import neighbours


def _face(F, rng):
    """(F, P, 3) a 7 x 7 grid of markers 10 mm apart on a bulging surface, moving
    smoothly together with a small deformation of their own."""
    g = np.stack(np.meshgrid(np.arange(7) * 10.0, np.arange(7) * 10.0), -1).reshape(-1, 2)
    z = 130.0 - 0.01 * ((g - 30) ** 2).sum(-1)
    base = np.c_[g, z]
    tt = np.arange(F)[:, None, None] / 60.0
    X = base[None] + 3.0 * np.sin(2 * np.pi * 1.5 * tt) * np.array([1.0, 0.5, 0.2])
    X = X + 0.05 * np.sin(2 * np.pi * rng.uniform(0.5, 2, (1, len(base), 3)) * tt
                          + rng.uniform(0, 6, (1, len(base), 3)))
    return X


def test_poor_depth_follows_the_neighbours_good_samples_stay():
    rng = np.random.default_rng(4)
    F = 90
    truth = _face(F, rng)
    P = truth.shape[1]
    cov = np.zeros((F, P, 3, 3))
    cov[...] = np.diag([0.02, 0.02, 0.05]) ** 2
    poor = np.array([10, 24, 31])
    cov[:, poor] = np.diag([0.02, 0.02, 0.8]) ** 2  # 0.8 mm of depth noise
    X = truth + rng.normal(0, 1, truth.shape) * np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    tri = np.ones((F, P), bool)
    pred = patch_prediction(X, tri, neighbours(X, tri))
    tau = deformation_sigma(X, pred, cov, tri)
    assert np.all(tau < 0.2)  # the deformation is small and measured so
    Xf, cov_f = fuse(X, cov, pred, tau, tri)
    e0 = np.linalg.norm(X - truth, axis=-1)
    e1 = np.linalg.norm(Xf - truth, axis=-1)
    assert np.sqrt(np.mean(e1[:, poor] ** 2)) < 0.35 * np.sqrt(np.mean(e0[:, poor] ** 2))
    others = np.setdiff1d(np.arange(P), poor)
    # the well-seen samples barely move, and do not get worse
    assert np.abs(Xf[:, others] - X[:, others]).max() < 0.1
    assert np.sqrt(np.mean(e1[:, others] ** 2)) <= 1.02 * np.sqrt(np.mean(e0[:, others] ** 2))
    assert (np.einsum("fpii->fp", cov_f) <= np.einsum("fpii->fp", cov) + 1e-12).all()


def test_a_deformation_its_neighbours_do_not_share_is_kept():
    rng = np.random.default_rng(5)
    F = 90
    truth = _face(F, rng)
    P = truth.shape[1]
    # one marker (a lip corner) moves 4 mm in depth on its own over frames 40-60
    bump = np.zeros(F)
    bump[40:61] = 4.0 * np.sin(np.linspace(0, np.pi, 21))
    truth[:, 24, 2] += bump
    cov = np.zeros((F, P, 3, 3))
    cov[...] = np.diag([0.02, 0.02, 0.3]) ** 2
    X = truth + rng.normal(0, 1, truth.shape) * [0.02, 0.02, 0.3]
    tri = np.ones((F, P), bool)
    pred = patch_prediction(X, tri, neighbours(X, tri))
    tau = deformation_sigma(X, pred, cov, tri)
    Xf, _ = fuse(X, cov, pred, tau, tri)
    peak = slice(45, 56)
    # where the prediction misses by millimetres the sample is left as measured
    assert np.abs(Xf[peak, 24] - X[peak, 24]).max() < 1e-9
    assert np.abs(Xf[peak, 24, 2] - truth[peak, 24, 2]).max() < 1.5


def test_a_poor_depth_far_along_its_worst_direction_still_follows_the_neighbours():
    # a marker seen by the two cameras of one caddy, with blobs whose errors have a
    # heavier tail than its covariance: some samples 3-5 sigma off along the depth,
    # while across it (where the cameras fix it) they agree with the neighbours
    rng = np.random.default_rng(6)
    F = 90
    truth = _face(F, rng)
    P = truth.shape[1]
    cov = np.zeros((F, P, 3, 3))
    cov[...] = np.diag([0.02, 0.02, 0.05]) ** 2
    cov[:, 24] = np.diag([0.02, 0.02, 1.0]) ** 2
    X = truth + rng.normal(0, 1, truth.shape) * np.sqrt(np.diagonal(cov, axis1=-2, axis2=-1))
    tails = np.arange(5, F, 9)
    X[tails, 24, 2] = truth[tails, 24, 2] + rng.choice([-1, 1], tails.size) * \
        rng.uniform(3.2, 5.0, tails.size)
    tri = np.ones((F, P), bool)
    pred = patch_prediction(X, tri, neighbours(X, tri))
    tau = deformation_sigma(X, pred, cov, tri)
    Xf, _ = fuse(X, cov, pred, tau, tri)
    e1 = np.abs(Xf[tails, 24, 2] - truth[tails, 24, 2])
    assert e1.max() < 1.0
    # a gate of 3 sigma along the depth too leaves them where they are
    Xg, _ = fuse(X, cov, pred, tau, tri, gate_along=3.0)
    assert np.abs(Xg[tails, 24, 2] - truth[tails, 24, 2]).max() > 3.0
