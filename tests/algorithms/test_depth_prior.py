"""The depth prior from time: poorly seen depth follows the track, fast motion is kept."""

import numpy as np
import pytest

from carapost.algorithms.depth_prior import sample_covariance, smooth_along_uncertainty


def _tracks(F: int, rng: np.random.Generator, speed: float) -> np.ndarray:
    """(F, P, 3) smooth marker paths (mm) with a jaw-like fast component of ``speed``."""
    tt = np.arange(F)[:, None] / 60.0
    P = 20
    phase = rng.uniform(0, 2 * np.pi, (P, 3))
    freq = rng.uniform(0.5, 4.0, (P, 3))
    X = np.zeros((F, P, 3)) + rng.uniform(-20, 20, (1, P, 3))
    X[..., 2] += 130.0
    X += speed * np.sin(2 * np.pi * freq[None] * tt[..., None] + phase[None])
    return X


def _depth_noise(F: int, P: int, rng: np.random.Generator):
    """Covariance elongated along z (0.15 mm) with 0.02 mm across, and a draw of it."""
    cov = np.zeros((F, P, 3, 3))
    cov[...] = np.diag([0.02 ** 2, 0.02 ** 2, 0.15 ** 2])
    noise = rng.normal(0, 1, (F, P, 3)) * [0.02, 0.02, 0.15]
    return cov, noise


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(a - b, axis=-1)
    return float(np.sqrt(np.nanmean(d ** 2)))


def test_depth_noise_is_reduced_and_lateral_detail_kept():
    rng = np.random.default_rng(1)
    truth = _tracks(120, rng, speed=2.0)
    cov, noise = _depth_noise(*truth.shape[:2], rng)
    X = truth + noise
    Xs, cov_s = smooth_along_uncertainty(X, cov)
    assert _rmse(Xs, truth) < 0.7 * _rmse(X, truth)
    # across the image the samples were better than any fit: they barely move
    assert np.abs(Xs[..., :2] - X[..., :2]).max() < 0.02
    # the returned covariance follows the error it leaves (within 25 %)
    pred = np.sqrt(np.nanmean(cov_s[1:-1, :, 2, 2]))
    got = float(np.sqrt(np.mean((Xs[1:-1, :, 2] - truth[1:-1, :, 2]) ** 2)))
    assert 0.75 < got / pred < 1.25


def test_fast_motion_is_not_smoothed_away():
    # 10 mm at up to 4 Hz (lips in a fast expression), each axis at its own frequency:
    # far from a quadratic over 9 frames
    rng = np.random.default_rng(2)
    truth = _tracks(120, rng, speed=10.0)
    cov, noise = _depth_noise(*truth.shape[:2], rng)
    X = truth + noise
    Xs, _ = smooth_along_uncertainty(X, cov)
    assert _rmse(Xs, truth) < 0.9 * _rmse(X, truth)
    # the allowance measured across the image is what keeps the corners of these paths:
    # a fixed one, as small as for a still face, cuts them
    import carapost.algorithms.depth_prior as dp

    saved = dp._window_mean
    try:
        dp._window_mean = lambda v, half: np.zeros_like(v)
        Xf, _ = smooth_along_uncertainty(X, cov)
    finally:
        dp._window_mean = saved
    assert _rmse(Xf, truth) > 1.05 * _rmse(Xs, truth)


def test_gaps_and_shared_error():
    rng = np.random.default_rng(3)
    truth = _tracks(60, rng, speed=1.0)
    cov, noise = _depth_noise(*truth.shape[:2], rng)
    X = truth + noise
    X[20:24, 0] = np.nan  # a gap: the samples beside it are still fitted
    X[:, 1] = np.nan  # a point never seen stays NaN
    X[30, 2] = np.nan
    X[:29, 2] = np.nan  # a two-sample island: too short to fit, left alone
    X[33:, 2] = np.nan
    Xs, cov_s = smooth_along_uncertainty(X, cov, shared=1.0)
    assert np.isnan(Xs[20:24, 0]).all() and np.isnan(Xs[:, 1]).all()
    assert np.isfinite(Xs[:20, 0]).all() and np.isfinite(Xs[24:, 0]).all()
    assert np.array_equal(Xs[29:33, 2], X[29:33, 2], equal_nan=True)
    # what neighbouring frames share is never smoothed away: at least `shared` times cov
    assert (cov_s[29, 2] >= 2 * cov[29, 2] - 1e-12).all()
    assert (cov_s[10, 0, 2, 2] >= cov[10, 0, 2, 2])
    # too short a window changes nothing
    X2, _ = smooth_along_uncertainty(X, cov, window=3)
    assert np.array_equal(X2, X, equal_nan=True)


def test_a_wrong_depth_follows_the_others_and_says_so():
    # one-caddy depth noise (0.15 mm) and, in 12 samples, a wrong match's depth error of
    # 1.5-2.5 mm (a blob of a neighbour along the caddy's epipolar line): before, the fit
    # that includes the sample is pulled towards it and the gain leaves most of it
    rng = np.random.default_rng(4)
    truth = _tracks(120, rng, speed=2.0)
    cov, noise = _depth_noise(*truth.shape[:2], rng)
    X = truth + noise
    frames = rng.choice(np.arange(10, 110), 12, replace=False)
    points = rng.integers(0, truth.shape[1], 12)
    X[frames, points, 2] += rng.uniform(1.5, 2.5, 12) * rng.choice([-1, 1], 12)
    Xs, cov_s = smooth_along_uncertainty(X, cov)
    Xo, _ = smooth_along_uncertainty(X, cov, outlier_sigmas=0)
    err = np.linalg.norm(Xs - truth, axis=-1)
    before = np.linalg.norm(Xo - truth, axis=-1)[frames, points]
    # (one may be missed: the isolation test needs it well above every other sample of
    # its window, and noise or a second outlier nearby can deny it)
    assert np.median(err[frames, points]) < 0.2 and (err[frames, points] < 0.35).sum() >= 11
    assert np.median(before) > 0.4
    # their sigma grows to cover what is left; the rest is as without the check
    sig = np.sqrt(np.einsum("...ii->...", cov_s))
    assert (err[frames, points] < 3 * sig[frames, points]).sum() >= 11
    assert _rmse(Xs, truth) < 0.8 * _rmse(Xo, truth)
    ok = np.ones(err.shape, bool)
    for f, p in zip(frames, points, strict=True):
        ok[max(f - 8, 0):f + 9, p] = False  # the fits and the motion allowance it spoilt
    changed = np.abs(Xs - Xo).max(-1)[ok] > 1e-9
    assert changed.mean() < 0.01
    # right samples are seldom taken for outliers
    Xc, _ = smooth_along_uncertainty(truth + noise, cov)
    Xc0, _ = smooth_along_uncertainty(truth + noise, cov, outlier_sigmas=0)
    assert (np.abs(Xc - Xc0).max(-1) > 1e-9).mean() < 0.01


def test_a_track_noisy_over_many_frames_is_not_cut_into_outliers():
    # a blob biased for a run of frames, one camera then the other: the depth is off by
    # 1-1.5 mm on 14 frames of one point, alternating in sign. No right neighbours are
    # left to follow, so the test leaves that run to the plain prior
    rng = np.random.default_rng(5)
    truth = _tracks(120, rng, speed=2.0)
    cov, noise = _depth_noise(*truth.shape[:2], rng)
    X = truth + noise
    X[40:54, 3, 2] += rng.uniform(1.0, 1.5, 14) * np.where(np.arange(14) % 3, 1, -1)
    Xs, _ = smooth_along_uncertainty(X, cov)
    Xo, _ = smooth_along_uncertainty(X, cov, outlier_sigmas=0)
    run = slice(36, 58)
    assert _rmse(Xs[run, 3:4], truth[run, 3:4]) < 1.05 * _rmse(Xo[run, 3:4], truth[run, 3:4])


def test_sample_covariance_matches_a_monte_carlo():
    from carapost.algorithms.camera import CameraIntrinsics
    from carapost.algorithms.triangulation import TriangulationParameters, triangulate

    intr = CameraIntrinsics(focal=np.array([600.0, 600.0]),
                            principal_point=np.array([[640.0, 360.0], [640.0, 360.0]]))
    R = np.tile(np.eye(3), (1, 2, 1, 1))
    t = np.array([[[20.0, 0, 0], [-20.0, 0, 0]]])
    X = np.array([[[5.0, -8.0, 140.0]]])
    uv = 600.0 * (X[0, 0, :2] + t[0, :, :2]) / (X[0, 0, 2] + t[0, :, 2:]) + 0.0
    uv = uv + np.array([[640.0, 360.0]])
    cov = sample_covariance(X, uv[None, None], R, t, intr, [0.1, 0.1])[0, 0]
    rng = np.random.default_rng(0)
    N = 4000
    obs = uv[None, None] + rng.normal(0, 0.1, (N, 1, 2, 2))
    Y = triangulate(obs, np.broadcast_to(R, (N, 2, 3, 3)), np.broadcast_to(t, (N, 2, 3)),
                    intr, TriangulationParameters(minimum_cameras=2,
                                                  use_outlier_rejection=False)).points[:, 0]
    emp = np.cov((Y - X[0, 0]).T)
    assert np.allclose(np.diag(emp), np.diag(cov), rtol=0.15)


@pytest.mark.slow
def test_track_take_drops_a_wrong_match_and_smooths_one_caddy_depth():
    """Track Take end to end on truth detections with 0.1 px noise: a detection
    in one of three or more cameras (3.5 px) is left out of its sample, and the depth prior makes
    the take more accurate than the same tracking without it."""
    from carapost.algorithms.codes import KIND_BRIM
    from carapost.algorithms.tracking import (
        InitialState,
        TrackingParameters,
        make_spawner,
        track_take,
    )
    from carapost.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig(preset="speech", frames=30, seed=1, size=(1280, 720)))
    rng = np.random.default_rng(0)
    F, M, C = scene.visible.shape
    many = np.flatnonzero((scene.visible.sum(-1) >= 3).all(0))
    m = int(many[0])
    cam = int(np.flatnonzero(scene.visible[:, m].all(0))[0])
    bad = range(10, 16)
    dets = []
    for f in range(F):
        per = []
        for c in range(C):
            v = scene.visible[f, :, c]
            bv = scene.brim_visible[f, :, c]
            cen = np.concatenate([scene.uv[f, v, c], scene.brim_uv[f, bv, c]])
            cen = cen + rng.normal(0, 0.1, cen.shape)
            if c == cam and f in bad:
                cen[int(np.flatnonzero(np.flatnonzero(v) == m)[0])] += [2.5, 2.5]
            per.append((cen, np.full((len(cen), 2), 5.0)))
        dets.append(per)
    B = len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    X0[:M][scene.visible[0].sum(-1) < 2] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]

    def run(depth_frames: int):
        return track_take(dets.__getitem__, InitialState(X0, kind), scene.cam_R[0],
                          scene.cam_t[0], scene.intrinsics,
                          TrackingParameters(depth_smoothing_frames=depth_frames),
                          start=0, n_frames=F,
                          spawn=make_spawner(scene.intrinsics, ((0, 1), (2, 3)),
                                             brim_model=scene.brim3d))

    res, plain = run(9), run(0)
    assert np.isnan(res.obs[list(bad), m, cam]).all()
    assert (res.detection[list(bad), m, cam] == -1).all()
    err = np.linalg.norm(res.positions[:, m] - scene.points3d[:, m], axis=-1)
    assert np.nanmax(err[list(bad)]) < 0.5
    e = np.linalg.norm(res.positions[1:, :M] - scene.points3d[1:], axis=-1)
    e0 = np.linalg.norm(plain.positions[1:, :M] - scene.points3d[1:], axis=-1)
    ok = np.isfinite(e) & np.isfinite(e0)
    assert np.sqrt(np.mean(e[ok] ** 2)) < 0.85 * np.sqrt(np.mean(e0[ok] ** 2))
