"""Bundle adjustment on synthetic head rigs with known truth and on the BAL fixture."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from carapost.algorithms.bundle import bundle_frame, bundle_sequence, left_jacobian
from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    project,
    rodrigues_to_matrix,
)


def _bal():
    """The BAL harness (benchmarks/bal.py, not part of the product), loaded by path."""
    name = "_carapost_bench_bal"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[2] / "benchmarks" / "bal.py"
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]



def _rig() -> tuple[np.ndarray, np.ndarray, CameraIntrinsics]:
    def look_at(c):
        z = -c / np.linalg.norm(c)
        x = np.cross([0.0, -1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        return R, -R @ c

    centres = np.array([[-110.0, -60, 220], [-95, 50, 235], [110, -60, 220], [95, 50, 235]])
    Rs, ts = zip(*(look_at(c) for c in centres), strict=True)
    intr = CameraIntrinsics(
        focal=[900.0, 910.0, 905.0, 895.0],
        principal_point=[[640.5, 360.2], [639.0, 359.0], [641.0, 361.5], [638.2, 358.7]],
        radial=[[5.6e-8, -3.4e-15, -7.9e-21], [-2.0e-8, 1.0e-14, 1.0e-21],
                [4.0e-8, -2e-15, 0.0], [3e-8, 0.0, 0.0]],
        distortion_centre=[[641.3, 358.2], [637.7, 362.9], [640.0, 360.0], [642.0, 357.0]],
        image_size=[[1280, 720]] * 4,
    )
    return np.stack(Rs), np.stack(ts), intr


def _cloud(rng, P=120):
    x = rng.uniform(-70, 70, P)
    y = rng.uniform(-90, 90, P)
    return np.stack([x, y, 40 * (1 - (x / 80) ** 2 - (y / 100) ** 2)], -1)


def _perturb(rng, R, t, X, brim, rot=0.01, trans=2.0, pts=1.0):
    Rp = rodrigues_to_matrix(rng.normal(0, rot, (len(R), 3))) @ R
    tp = t + rng.normal(0, trans, t.shape)
    Xp = X + rng.normal(0, pts, X.shape)
    Xp[brim] = X[brim]
    return Rp, tp, Xp


def test_left_jacobian_matches_finite_differences(rng):
    for w in (rng.normal(0, 1.0, 3), np.array([1e-6, -2e-6, 0.0]), np.array([0.0, 3.0, 0.1])):
        X = rng.normal(0, 1, 3)
        # d(R(w) X)/dw = -[R(w) X]x J_l(w)
        analytic = -_skew(rodrigues_to_matrix(w) @ X) @ left_jacobian(w)
        eps = 1e-6
        numeric = np.stack([(rodrigues_to_matrix(w + eps * e) @ X
                             - rodrigues_to_matrix(w - eps * e) @ X) / (2 * eps)
                            for e in np.eye(3)], -1)
        np.testing.assert_allclose(analytic, numeric, atol=1e-7)


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def test_bundle_frame_recovers_cameras_with_brim_fixed(rng):
    R, t, intr = _rig()
    X = _cloud(rng)
    uv, _ = project(X, R, t, intr)
    uv += rng.normal(0, 0.1, uv.shape)
    brim = np.zeros(len(X), bool)
    brim[:20] = True
    Rp, tp, Xp = _perturb(rng, R, t, X, brim)
    res = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim)
    assert res.success
    assert res.rms_before > 5.0 and res.rms_after < 0.2
    # Gauge fixed by the brim: cameras come back to the truth, brim points do not move.
    err_c = np.linalg.norm(camera_centres(res.R, res.t) - camera_centres(R, t), axis=-1)
    assert err_c.max() < 0.2
    np.testing.assert_array_equal(res.points[brim], Xp[brim])
    assert np.median(np.linalg.norm(res.points[~brim] - X[~brim], axis=-1)) < 0.05
    # The rotation stays a rotation.
    np.testing.assert_allclose(res.R @ res.R.transpose(0, 2, 1), np.broadcast_to(np.eye(3),
                               res.R.shape), atol=1e-12)


def test_bundle_frame_gauge_by_one_camera_without_brim(rng):
    R, t, intr = _rig()
    X = _cloud(rng)
    uv, _ = project(X, R, t, intr)
    uv += rng.normal(0, 0.1, uv.shape)
    Rp, tp, Xp = _perturb(rng, R, t, X, np.zeros(len(X), bool))
    res = bundle_frame(uv, Xp, Rp, tp, intr)
    assert res.rms_after < 0.2 < 5.0 < res.rms_before
    # Camera 0 holds the gauge and the first baseline keeps its length (the scale).
    np.testing.assert_allclose(res.R[0], Rp[0], atol=1e-12)
    np.testing.assert_allclose(res.t[0], tp[0], atol=1e-9)
    c0, c1 = camera_centres(Rp, tp), camera_centres(res.R, res.t)
    assert np.linalg.norm(c1[1] - c1[0]) == pytest.approx(np.linalg.norm(c0[1] - c0[0]),
                                                            rel=1e-9)
    # The refined points reproject onto the observations.
    uv1, _ = project(res.points, res.R, res.t, intr)
    assert np.sqrt(np.mean(np.sum((uv1 - uv) ** 2, -1))) < 0.2


def test_robust_loss_resists_mismatched_detections(rng):
    R, t, intr = _rig()
    X = _cloud(rng)
    uv, _ = project(X, R, t, intr)
    uv += rng.normal(0, 0.1, uv.shape)
    bad = rng.random(uv.shape[:2]) < 0.03
    uv[bad] += 40.0
    brim = np.zeros(len(X), bool)
    brim[:20] = True
    brim &= ~bad.any(1)
    Rp, tp, Xp = _perturb(rng, R, t, X, brim)
    robust = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim, loss="huber")
    plain = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim, loss="linear")
    err = [np.linalg.norm(camera_centres(r.R, r.t) - camera_centres(R, t), axis=-1).max()
           for r in (robust, plain)]
    assert err[0] < 0.3
    assert err[1] > 3 * err[0]


def test_schur_and_least_squares_solvers_agree(rng):
    R, t, intr = _rig()
    X = _cloud(rng, 60)
    uv, _ = project(X, R, t, intr)
    uv += rng.normal(0, 0.1, uv.shape)
    brim = np.arange(len(X)) < 15
    Rp, tp, Xp = _perturb(rng, R, t, X, brim)
    a = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim, loss="linear")
    b = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim, loss="linear",
                     solver="least_squares")
    assert a.rms_after == pytest.approx(b.rms_after, rel=1e-4)
    np.testing.assert_allclose(camera_centres(a.R, a.t), camera_centres(b.R, b.t), atol=1e-3)


def test_refine_intrinsics_recovers_focal_length(rng):
    R, t, intr = _rig()
    X = _cloud(rng, 200)
    uv, _ = project(X, R, t, intr)
    uv += rng.normal(0, 0.05, uv.shape)
    brim = np.ones(len(X), bool)  # all structure known: a calibration
    wrong = intr.copy()
    wrong.focal = intr.focal + np.array([6.0, -4.0, 5.0, -3.0])
    res = bundle_frame(uv, X, R, t, wrong, fixed_points_mask=brim, refine_intrinsics=True,
                       loss="linear")
    assert res.intrinsics is not None
    assert np.abs(res.intrinsics.focal - intr.focal).max() < 1.0
    assert res.rms_after < 0.1


def test_bundle_sequence_per_frame_cameras_with_brim_model(rng):
    R, t, intr = _rig()
    F, P = 4, 80
    base = _cloud(rng, P)
    brim = np.arange(P) < 16
    X = base[None].repeat(F, 0)
    X[:, ~brim] += rng.normal(0, 2.0, (F, int((~brim).sum()), 3))  # the face moves
    Rf = rodrigues_to_matrix(rng.normal(0, 0.002, (F, 4, 3))) @ R[None]  # the rig flexes
    tf = t[None] + rng.normal(0, 0.3, (F, 4, 3))
    uv, _ = project(X, Rf, tf, intr)
    uv += rng.normal(0, 0.1, uv.shape)
    Rp = rodrigues_to_matrix(rng.normal(0, 0.01, (F, 4, 3))) @ Rf
    tp = tf + rng.normal(0, 2.0, tf.shape)
    tp[2, 1] = np.nan  # an unsolved camera-frame starts from the previous frame's result
    Rp[2, 1] = np.nan
    Xp = X + rng.normal(0, 1.0, X.shape)
    res = bundle_sequence(uv, Xp, Rp, tp, intr, brim_points_mask=brim, brim_model=base[brim])
    assert res.frames_done == F and res.success.all()
    assert (res.rms_after < 0.2).all()
    err = np.linalg.norm(camera_centres(res.R, res.t) - camera_centres(Rf, tf), axis=-1)
    assert err.max() < 0.3
    np.testing.assert_array_equal(res.points[:, brim], np.broadcast_to(base[brim],
                                                                      (F, 16, 3)))
    calls = []
    part = bundle_sequence(uv, Xp, Rp, tp, intr, brim_points_mask=brim, brim_model=base[brim],
                           progress=lambda d, n: calls.append(d) or d < 2)
    assert part.frames_done == 2 and calls == [1, 2]
    assert np.isnan(part.R[2:]).all()


def test_bundle_input_errors(rng):
    R, t, intr = _rig()
    X = _cloud(rng, 10)
    uv, _ = project(X, R, t, intr)
    with pytest.raises(ValueError, match="points"):
        bundle_frame(uv, X[:5], R, t, intr)
    with pytest.raises(ValueError, match="fixed_points_mask"):
        bundle_frame(uv, X, R, t, intr, fixed_points_mask=np.ones(3, bool))
    with pytest.raises(ValueError, match="brim_model"):
        bundle_sequence(uv[None], X[None], R[None], t[None], intr,
                        brim_points_mask=np.arange(10) < 4, brim_model=np.zeros((3, 3)))


def test_bal_subset_converges(fixtures_dir):
    path = fixtures_dir / "bal" / "bal-ladybug-problem-49-7776-pre-shrink-1800.txt"
    if not path.exists():
        pytest.skip(f"{path} not found")
    prob = _bal().read_bal(path)
    assert prob.cameras.shape == (49, 9) and prob.points.shape == (1800, 3)
    assert prob.observations.shape == (10863, 2)
    res = _bal().bundle_adjust_bal(prob, max_nfev=20)
    assert res.cost_final < 0.02 * res.cost_initial
    assert res.rms_final < 1.0
    r = _bal().bal_residuals(res.cameras, res.points, prob.camera_index, prob.point_index,
                      prob.observations)
    assert 0.5 * np.sum(r**2) == pytest.approx(res.cost_final)


def test_read_bal_rejects_truncated_file(tmp_path):
    bad = tmp_path / "short.txt"
    bad.write_text("1 1 1\n0 0 1.0 2.0\n" + "0 " * 9 + "\n1 2\n")
    with pytest.raises(ValueError, match="short.txt"):
        _bal().read_bal(bad)
