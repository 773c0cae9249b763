"""Camera pose smoothing over a take and the per-sample sigma: known truth, known noise."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.blob_noise import blob_noise_scale
from carapost.algorithms.camera import CameraIntrinsics, project, rodrigues_to_matrix
from carapost.algorithms.triangulation import TriangulationParameters, triangulate
from carapost.algorithms.uncertainty import (
    brim_pose_covariance,
    noise_from_residuals,
    pair_holdout_scale,
    point_noise_factor,
    sample_sigma,
    savgol_quadratic,
    smooth_camera_poses,
    width_noise_scale,
)


def caddy_rig(C: int = 4):
    """Two caddies of two cameras, 40 mm deep, 180 mm apart, looking at the face."""
    from carapost.synth.rig import look_at

    Rs, ts = [], []
    for i in range(C):
        sx = 1.0 if i < C // 2 else -1.0
        j = i % 2
        R, t = look_at(np.array([sx * 90.0, -42.0 - 40.0 * j, 232.0]),
                       np.array([-sx * 8.0, 14.0, 75.0]))
        Rs.append(R)
        ts.append(t)
    intr = CameraIntrinsics(focal=np.full(C, 576.0),
                            principal_point=np.tile([639.5, 359.5], (C, 1)),
                            image_size=np.tile([1280.0, 720.0], (C, 1)))
    return intr, np.array(Rs), np.array(ts)


def face_points(rng, n):
    return np.c_[rng.uniform(-40, 40, n), rng.uniform(-60, 30, n), rng.uniform(80, 100, n)]


@pytest.mark.parametrize(("frames", "window"), [(5, 5), (11, 11), (40, 11), (300, 31)])
def test_savgol_quadratic_is_scipys_filter(frames, window):
    """The pose filter gives scipy.signal.savgol_filter's values (order 2, ends fitted),
    without importing scipy.signal in every process that smooths poses."""
    from scipy.signal import savgol_filter

    x = np.random.default_rng(frames).normal(0.0, 50.0, (frames, 4, 3))
    want = savgol_filter(x, window, 2, axis=0, mode="interp")
    np.testing.assert_allclose(savgol_quadratic(x, window), want, rtol=0, atol=1e-10)
    # a quadratic is kept as it is, ends included; a kink is smoothed
    f = np.arange(frames, dtype=np.float64)
    np.testing.assert_allclose(savgol_quadratic(0.5 * f ** 2 - 3 * f, window),
                               0.5 * f ** 2 - 3 * f, atol=1e-8)
    with pytest.raises(ValueError, match="odd"):
        savgol_quadratic(x, window + 1)


def test_smoothing_removes_scatter_and_follows_smooth_flex():
    rng = np.random.default_rng(0)
    F, C = 90, 4
    time = np.arange(F) / 60.0
    # smooth flex: 1.5 Hz, 0.05 deg; per-frame resection scatter 0.02 deg
    flex = np.radians(0.05) * np.sin(2 * np.pi * 1.5 * time)[:, None, None] * \
        np.array([1.0, 0.5, -0.3])
    flex = np.broadcast_to(flex, (F, C, 3))
    scatter = np.radians(0.02) * rng.standard_normal((F, C, 3))
    _, R0, t0 = caddy_rig(C)
    truth_R = rodrigues_to_matrix(flex) @ R0
    noisy_R = rodrigues_to_matrix(flex + scatter) @ R0
    truth_t = np.einsum("fcij,cj->fci", rodrigues_to_matrix(flex), t0)
    noisy_t = truth_t + rng.normal(0, 0.05, (F, C, 3))
    Rs, ts = smooth_camera_poses(noisy_R, noisy_t, 11)

    def ang(A, B):
        d = np.einsum("fcij,fckj->fcik", A, B)
        return np.degrees(np.arccos(np.clip((np.trace(d, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))

    before = np.sqrt(np.mean(ang(noisy_R, truth_R) ** 2))
    after = np.sqrt(np.mean(ang(Rs, truth_R) ** 2))
    assert after < 0.6 * before
    # the fit does not lag the flex: without scatter, nothing moves
    Rc, tc = smooth_camera_poses(truth_R, truth_t, 11)
    assert np.sqrt(np.mean(ang(Rc, truth_R) ** 2)) < 0.002
    # kept frames stay exactly as they were
    keep = np.zeros(F, bool)
    keep[7] = True
    Rk, tk = smooth_camera_poses(noisy_R, noisy_t, 11, keep=keep)
    assert np.array_equal(Rk[7], noisy_R[7]) and np.array_equal(tk[7], noisy_t[7])


@pytest.mark.parametrize("cams", [(0, 1), (0, 1, 2, 3)])
def test_sigma_is_calibrated_against_known_noise(cams):
    """Monte Carlo: truth points, pixel noise of known size, least-squares triangulation;
    the fraction of errors within 1 / 2 sigma is that of a normal error."""
    rng = np.random.default_rng(1)
    intr, R, t = caddy_rig()
    N, noise = 3000, 0.15
    X = face_points(rng, N)
    uv, _ = project(X, R, t, intr)
    mask = np.zeros(4, bool)
    mask[list(cams)] = True
    uv = np.where(mask[None, :, None], uv + rng.normal(0, noise, uv.shape), np.nan)
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(uv[:, None], R, t, intr, params).points[:, 0]
    Rf, tf = np.broadcast_to(R, (N, 4, 3, 3)), np.broadcast_to(t, (N, 4, 3))
    s = sample_sigma(Y[:, None], uv[:, None], Rf, tf, intr, np.full(4, noise))[:, 0]
    e = np.linalg.norm(Y - X, axis=-1)
    assert np.isfinite(s).all()
    within1, within2 = np.mean(e <= s), np.mean(e <= 2 * s)
    assert 0.55 <= within1 <= 0.75
    assert 0.92 <= within2 <= 0.995
    if cams == (0, 1):
        # a caddy's depth error z^2 / (f b) x sqrt(2) x noise: 0.2-0.4 mm at 150-190 mm
        assert 0.2 < np.median(s) < 0.4


def test_thin_blob_noise_is_carried_by_the_width_scale():
    """Three cameras; the lone camera of the second caddy sees half of the markers as thin
    blobs (semi-minor axis 1.5 px) whose centres are twice as noisy, the rest as round
    ones. That camera alone fixes the depth along the first caddy's baseline, so its
    residuals hardly show its noise: the estimate must weigh each camera's share of the
    residual (not lend it to the other two), and one noise per camera leaves the thin
    blobs' sigmas too small where the width scale makes them right."""
    rng = np.random.default_rng(5)
    intr, R, t = caddy_rig()
    N, noise = 6000, 0.08
    X = face_points(rng, N)
    uv, _ = project(X, R, t, intr)
    thin = np.arange(N) % 2 == 0
    widths = np.tile([4.0, 3.5, 4.0, np.nan], (N, 1))  # camera 3 does not see them
    widths[thin, 2] = 1.5
    scale = width_noise_scale(widths)
    assert np.allclose(scale[0, :3], [0.75, 3.0 / 3.5, 2.0])
    uv = uv + rng.normal(0, 1, uv.shape) * (noise * scale)[..., None]
    uv[:, 3] = np.nan
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(uv[:, None], R, t, intr, params).points[:, 0]
    Rf, tf = np.broadcast_to(R, (N, 4, 3, 3)), np.broadcast_to(t, (N, 4, 3))
    e = np.linalg.norm(Y - X, axis=-1)
    sc = scale[:, None]
    est = noise_from_residuals(uv[:, None], Y[:, None], Rf, tf, intr, scale=sc)
    assert np.allclose(est[:3], noise, rtol=0.15)
    s = sample_sigma(Y[:, None], uv[:, None], Rf, tf, intr, est, scale=sc)[:, 0]
    for group in (thin, ~thin):
        assert 0.58 <= np.mean(e[group] <= s[group]) <= 0.75
        assert 0.92 <= np.mean(e[group] <= 2 * s[group]) <= 0.995
    # one noise per camera from the same residuals: the thin blobs' sigmas too small
    plain = noise_from_residuals(uv[:, None], Y[:, None], Rf, tf, intr)
    s0 = sample_sigma(Y[:, None], uv[:, None], Rf, tf, intr, plain)[:, 0]
    assert np.mean(e[thin] <= s0[thin]) < 0.5


def test_attached_widths_reads_the_blob_of_each_observation():
    from carapost.algorithms.tracking import RaggedDetections
    from carapost.algorithms.tracking.take import attached_blobs

    def attached_widths(detections, detection, first=0):
        return attached_blobs(detections, detection, first)[0]

    # 2 frames, 2 cameras: image (f, c) holds 2 blobs whose minor axis is 10 f + c + k / 10
    offsets = np.arange(0, 10, 2)
    axes = np.array([[5.0, 10 * f + c + k / 10] for f in range(2) for c in range(2)
                     for k in range(2)])
    rag = RaggedDetections(offsets, np.zeros((8, 2)), axes, 2)
    det = np.array([[[1, -1]], [[0, 1]]])  # (F=2, P=1, C=2)
    w = attached_widths(rag, det)
    assert np.allclose(w[0, 0], [0.1, np.nan], equal_nan=True)
    assert np.allclose(w[1, 0], [10.0, 11.1])
    # the same through a plain per-frame callable, and from a later first frame
    assert np.allclose(attached_widths(lambda f: rag(f), det[1:], first=1), w[1:])


def test_attached_blobs_reads_lengths_and_scores_both_ways():
    from carapost.algorithms.tracking import RaggedDetections
    from carapost.algorithms.tracking.take import attached_blobs

    offsets = np.arange(0, 10, 2)
    axes = np.array([[20 + 10 * f + c + k / 10, 1.0] for f in range(2) for c in range(2)
                     for k in range(2)])
    score = np.array([0.5 + (4 * f + 2 * c + k) / 20 for f in range(2) for c in range(2)
                      for k in range(2)])
    rag = RaggedDetections(offsets, np.zeros((8, 2)), axes, 2, score)
    det = np.array([[[1, -1]], [[0, 1]]])
    minor, major, sc = attached_blobs(rag, det)
    assert np.allclose(major[1, 0], [30.0, 31.1])
    assert np.allclose(sc[0, 0], [0.55, np.nan], equal_nan=True)
    assert np.allclose(sc[1, 0], [0.7, 0.85])
    # a per-frame callable gives scores through its ``scores`` attribute (the tracking
    # job's source does), none without it

    def source(f):
        return rag(f)

    source.scores = lambda f: [score[offsets[2 * f + c]:offsets[2 * f + c + 1]]
                               for c in range(2)]
    _, major2, sc2 = attached_blobs(source, det)
    assert np.allclose(major2, major, equal_nan=True)
    assert np.allclose(sc2, sc, equal_nan=True)
    assert np.isnan(attached_blobs(lambda f: rag(f), det)[2]).all()


def test_blob_noise_scale_follows_the_measured_errors():
    """Clean blobs keep factor 1; a low score or a blob longer than the marker's usual in
    that camera (against a lower quartile, so merged frames as many as clean ones still
    count) raises it to the factors measured on the tuning takes."""
    rng = np.random.default_rng(4)
    F = 60
    major = 5.0 * (1 + rng.normal(0, 0.01, (F, 2, 2)))
    score = np.full((F, 2, 2), 0.999)
    major[1::2, 0, 0] *= 1.25  # merged every other frame (half of them)
    score[30, 1, 1] = 0.9
    major[40, 1, 0] = np.nan  # no blob
    f = blob_noise_scale(major, score)
    assert np.allclose(f[0::2, 0, 0], 1.0)
    assert (f[1::2, 0, 0] >= 3.0).all()
    assert np.isclose(f[30, 1, 1], 4.0)
    assert np.isclose(f[40, 1, 0], 1.0)
    other = np.ones(f.shape, bool)
    other[:, 0, 0] = False
    other[30, 1, 1] = False
    assert np.allclose(f[other], 1.0)
    # the reference is the window's lower quartile, as numpy's (NaN left out)
    from carapost.algorithms.blob_noise import _lower_quartile, window_statistic

    gappy = np.where(rng.random(major.shape) < 0.3, np.nan, major)
    assert np.allclose(window_statistic(gappy, _lower_quartile, 10, 5),
                       window_statistic(gappy, lambda w: np.nanpercentile(w, 25, axis=-1),
                                        10, 5), equal_nan=True)
    # unknown scores (detections without them) leave the length alone to decide
    f2 = blob_noise_scale(major, np.full(score.shape, np.nan))
    assert np.allclose(f2[:, 1, 1], 1.0) and (f2[1::2, 0, 0] >= 3.0).all()


def test_noise_and_holdout_scale_recover_the_true_noise():
    rng = np.random.default_rng(2)
    intr, R, t = caddy_rig()
    N, noise = 2000, 0.2
    X = face_points(rng, N)
    uv, _ = project(X, R, t, intr)
    uv = uv + rng.normal(0, noise, uv.shape)
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(uv[:, None], R, t, intr, params).points[:, 0]
    Rf, tf = np.broadcast_to(R, (N, 4, 3, 3)), np.broadcast_to(t, (N, 4, 3))
    est = noise_from_residuals(uv[:, None], Y[:, None], Rf, tf, intr)
    assert np.allclose(est, noise, rtol=0.15)
    # with the right noise the hold-out test asks for no change; with half of it, for 2x
    assert pair_holdout_scale(uv[:, None], Y[:, None], Rf, tf, intr, est) < 1.15
    k = pair_holdout_scale(uv[:, None], Y[:, None], Rf, tf, intr, est / 2)
    assert 1.7 < k < 2.3


def test_track_take_fills_sigma_for_triangulated_samples():
    from carapost.algorithms.codes import KIND_BRIM, RECON_TRIANGULATED
    from carapost.algorithms.tracking import InitialState, make_spawner, track_take
    from carapost.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig(preset="speech", frames=30, seed=1, size=(1280, 720)))
    rng = np.random.default_rng(0)
    F, M, C = scene.visible.shape
    dets = []
    for f in range(F):
        per = []
        for c in range(C):
            v = scene.visible[f, :, c]
            bv = scene.brim_visible[f, :, c]
            cen = np.concatenate([scene.uv[f, v, c], scene.brim_uv[f, bv, c]])
            cen = cen + rng.normal(0, 0.1, cen.shape)
            per.append((cen, np.full((len(cen), 2), 5.0)))
        dets.append(per)
    B = len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    X0[:M][scene.visible[0].sum(-1) < 2] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    res = track_take(dets.__getitem__, InitialState(X0, kind), scene.cam_R[0], scene.cam_t[0],
                     scene.intrinsics, start=0, n_frames=F,
                     spawn=make_spawner(scene.intrinsics, ((0, 1), (2, 3)),
                                        brim_model=scene.brim3d))
    assert res.sigma is not None and res.sigma.shape == res.recon.shape
    tri = res.recon == RECON_TRIANGULATED
    tri[:, M:M + B] = False
    # the start frame holds the initial state, which came without observations here
    assert np.isfinite(res.sigma[1:][tri[1:]]).mean() > 0.99
    assert np.isnan(res.sigma[:, M:M + B]).all()
    e = np.linalg.norm(res.positions[:, :M] - scene.points3d, axis=-1)
    s = res.sigma[:, :M].astype(float)
    ok = np.isfinite(e) & np.isfinite(s)
    assert ok.sum() > 1000
    # the 2D noise is estimated from the take: most truth errors lie within 2 sigma
    assert 0.5 < np.mean(e[ok] <= s[ok]) and np.mean(e[ok] <= 2 * s[ok]) > 0.85


def brim_dots():
    """A brim arc of 17 dots above and in front of the face (mm)."""
    a = np.linspace(-1.1, 1.1, 17)
    return np.c_[110 * np.sin(a), np.full(17, -95.0), 40 + 110 * np.cos(a)]


def test_brim_pose_covariance_matches_the_scatter_of_resections():
    """Resect each camera from noisy brim dots many times: the scatter of the solved
    poses is the covariance predicted from the dots' residuals."""
    from carapost.algorithms.camera import pixels_to_normalised
    from carapost.algorithms.pose import refine_poses

    rng = np.random.default_rng(4)
    intr, R, t = caddy_rig()
    B = brim_dots()
    uv0, _ = project(B, R, t, intr)  # (N, C, 2)
    assert np.isfinite(uv0).all()
    K, noise = 300, 0.05
    uv = uv0[None] + rng.normal(0, noise, (K,) + uv0.shape)  # (K, N, C, 2)
    errs, fits = [], []
    for k in range(K):
        xn = pixels_to_normalised(uv[k], intr).transpose(1, 0, 2)  # (C, N, 2)
        fit = refine_poses(B, xn, R, t, scale=intr.focal, huber_px=None, iterations=10,
                           linearise="camera")
        dR = np.einsum("cij,ckj->cik", fit.R, R)  # fit = exp([w]x) R
        w = np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0],
                      dR[:, 1, 0] - dR[:, 0, 1]], -1) / 2
        errs.append(np.c_[w, fit.t - np.einsum("cij,cj->ci", dR, t)])
        fits.append((fit.R, fit.t))
    errs = np.array(errs)  # (K, C, 6)
    # the residuals are those of the solved poses, as in a take
    Rf, tf = np.array([f[0] for f in fits]), np.array([f[1] for f in fits])
    cov, s_b = brim_pose_covariance(np.broadcast_to(B, (K,) + B.shape), uv, Rf, tf, intr)
    # the residuals (2N - 6 degrees of freedom) give back the dots' noise
    assert np.allclose(s_b, noise, rtol=0.1)
    for c in range(4):
        emp = np.var(errs[:, c], axis=0)
        pred = np.diagonal(cov[:, c], axis1=-2, axis2=-1).mean(0)
        assert np.all((emp > 0.6 * pred) & (emp < 1.6 * pred)), (c, emp / pred)


def test_pose_error_shared_by_the_cameras_is_carried_by_sigma():
    """The rig is off against the helmet by a small rigid motion in every frame (what a
    brim error does to all cameras alike): the face points seen by all four cameras move
    with it, which their residuals cannot show. Without the pose term their sigma is far
    too small; with the pose covariance each camera sees, the errors fall within 1 / 2
    sigma about as often as a normal error's."""
    from carapost.algorithms.camera import cross_matrix

    rng = np.random.default_rng(5)
    intr, R, t = caddy_rig()
    F, P, noise = 150, 20, 0.03
    sd = np.r_[np.full(3, np.radians(0.01)), np.full(3, 0.03)]  # rad, mm
    xi = rng.normal(0, 1, (F, 6)) * sd                           # world rotation, shift
    X = face_points(rng, P)[None].repeat(F, 0)
    moved = X + np.cross(xi[:, None, :3], X) + xi[:, None, 3:]
    Rf, tf = np.broadcast_to(R, (F, 4, 3, 3)), np.broadcast_to(t, (F, 4, 3))
    uv, _ = project(moved, Rf, tf, intr)
    uv = uv + rng.normal(0, noise, uv.shape)
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(uv, Rf, tf, intr, params).points
    e = np.linalg.norm(Y - X, axis=-1)
    # the same rigid error as each camera's pose error: omega_c = R w, delta_c = R d + [t]x R w
    T = np.zeros((4, 6, 6))
    T[:, :3, :3] = R
    T[:, 3:, 3:] = R
    T[:, 3:, :3] = np.einsum("cij,cjk->cik", np.array([cross_matrix(v) for v in t]), R)
    cov = np.einsum("cij,jk,clk->cil", T, np.diag(sd ** 2), T)
    cov = np.broadcast_to(cov, (F, 4, 6, 6))
    est = noise_from_residuals(uv, Y, Rf, tf, intr)
    plain = sample_sigma(Y, uv, Rf, tf, intr, est)
    full = sample_sigma(Y, uv, Rf, tf, intr, est, pose_cov=cov)
    assert np.mean(e <= plain) < 0.3
    # an isotropic 3D error is within sqrt(trace) 61 % of the time, within twice it 99 %
    assert 0.55 <= np.mean(e <= full) <= 0.75 and 0.95 <= np.mean(e <= 2 * full)


def test_point_noise_factor_finds_the_point_with_bad_blobs():
    rng = np.random.default_rng(6)
    intr, R, t = caddy_rig()
    F, P, noise = 60, 12, 0.1
    X = face_points(rng, P)[None].repeat(F, 0)
    Rf, tf = np.broadcast_to(R, (F, 4, 3, 3)), np.broadcast_to(t, (F, 4, 3))
    uv, _ = project(X, Rf, tf, intr)
    scale = np.ones(P)
    scale[3] = 3.0  # one marker's blobs are three times as noisy (half hidden)
    uv = uv + rng.normal(0, noise, uv.shape) * scale[None, :, None, None]
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(uv, Rf, tf, intr, params).points
    est = noise_from_residuals(uv, Y, Rf, tf, intr)
    phi = point_noise_factor(uv, Y, Rf, tf, intr, est)
    assert 5.0 < phi[3] < 14.0                        # about 3^2
    assert np.all(np.delete(phi, 3) < 1.6)
    s = sample_sigma(Y, uv, Rf, tf, intr, est, point_factor=phi)
    e = np.linalg.norm(Y - X, axis=-1)
    assert 0.5 < np.mean(e[:, 3] <= s[:, 3]) < 0.85


def _perturbed(R, t, cov, rng, K):
    """K draws of every camera's pose moved by an independent error of covariance cov
    (C, 6, 6): rotation (camera frame, rad) then translation (mm), as the resection's."""
    from carapost.algorithms.camera import rodrigues_to_matrix

    C = len(R)
    L = np.linalg.cholesky(cov)
    xi = np.einsum("cij,kcj->kci", L, rng.normal(0, 1, (K, C, 6)))
    dR = rodrigues_to_matrix(xi[..., :3].reshape(-1, 3)).reshape(K, C, 3, 3)
    return dR @ R[None], np.einsum("kcij,cj->kci", dR, t) + xi[..., 3:]


@pytest.mark.parametrize("cams", [(0, 1), (0, 1, 2, 3)])
def test_independent_pose_errors_are_carried_through_the_triangulation(cams):
    """Each camera's pose is off by its own error (what each camera's brim noise does):
    triangulating the points' exact projections with those cameras scatters them as the
    independent model predicts, also along the short baseline of one caddy, where a
    shift shared by the cameras says far too little."""
    rng = np.random.default_rng(8)
    intr, R, t = caddy_rig()
    K, P = 400, 6
    X = face_points(rng, P)
    sd = np.r_[np.full(3, np.radians(0.01)), np.full(3, 0.02)]
    cov = np.broadcast_to(np.diag(sd ** 2), (4, 6, 6)).copy()
    uv, _ = project(X, R, t, intr)  # (P, C, 2) exact
    uv[:, [c for c in range(4) if c not in cams]] = np.nan
    Rk, tk = _perturbed(R, t, cov, rng, K)
    params = TriangulationParameters(minimum_cameras=2, refine_iterations=3)
    Y = triangulate(np.broadcast_to(uv, (K,) + uv.shape), Rk, tk, intr, params).points
    emp = np.mean(np.sum((Y - X) ** 2, -1), axis=0)  # (P,) mm^2
    Rf, tf = np.broadcast_to(R, (1, 4, 3, 3)), np.broadcast_to(t, (1, 4, 3))
    pc = np.broadcast_to(cov, (1, 4, 6, 6))
    tiny = np.full(4, 1e-6)  # no 2D noise: the pose term alone

    def predicted(independent):
        s = sample_sigma(X[None], uv[None], Rf, tf, intr, tiny, pose_cov=pc,
                         pose_independent=independent)[0]
        return s.astype(np.float64) ** 2

    ratio = emp / predicted(True)
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    if len(cams) == 2:
        assert np.all(emp > 3 * predicted(False))


def test_white_factor_keeps_what_each_dot_keeps():
    """Brim residuals made of white noise and of an offset each dot keeps in every frame:
    the fit over time's factor applies to the white part only."""
    rng = np.random.default_rng(9)
    intr, R, t = caddy_rig()
    B = brim_dots()
    F = 200
    Rf, tf = np.broadcast_to(R, (F, 4, 3, 3)), np.broadcast_to(t, (F, 4, 3))
    uv0 = project(B, Rf, tf, intr)[0]  # (F, N, C, 2)
    Bf = np.broadcast_to(B, (F,) + B.shape)
    white, kept, factor = 0.05, 0.03, np.full(F, 0.2)
    for sys_px, expect in ((0.0, 0.2), (kept, (0.2 * white ** 2 + kept ** 2)
                                        / (white ** 2 + kept ** 2))):
        uv = (uv0 + rng.normal(0, white, uv0.shape)
              + rng.normal(0, sys_px, uv0.shape[1:])[None])
        full, _ = brim_pose_covariance(Bf, uv, Rf, tf, intr)
        part, _ = brim_pose_covariance(Bf, uv, Rf, tf, intr, white_factor=factor)
        got = np.median(part[..., 0, 0] / full[..., 0, 0])
        assert got == pytest.approx(expect, rel=0.2), (sys_px, got, expect)
