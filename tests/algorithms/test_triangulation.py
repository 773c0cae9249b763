"""Triangulation and reprojection-error outlier rejection on synthetic rigs with known truth."""

from __future__ import annotations

import importlib.util
import logging
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.algorithms.params import property_fields
from carapost.algorithms.triangulation import (
    Triangulation,
    TriangulationParameters,
    triangulate,
)

REPO = Path(__file__).resolve().parents[2]


def _bench():
    """The benchmark module: synthetic head rig and the per-point loop reference."""
    name = "_carapost_bench_triangulation"
    if name not in sys.modules:
        path = REPO / "benchmarks" / "triangulation.py"
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


def _look_at(centre, target=(0.0, 0.0, 250.0)):
    return _bench().look_at(np.asarray(centre, float), np.asarray(target, float))


def _simple_rig(centres, target=(0.0, 0.0, 250.0), focal=900.0):
    Rs, ts = zip(*(_look_at(c, target) for c in centres), strict=True)
    C = len(centres)
    intr = CameraIntrinsics(focal=[focal] * C, principal_point=[[640.0, 360.0]] * C,
                            image_size=[[1280, 720]] * C)
    return np.stack(Rs), np.stack(ts), intr


def _take(rng, F=60, P=120, outliers=0.0, missing=0.0, per_frame=False):
    return _bench().face_take(rng, F, P, outlier_fraction=outliers, missing_fraction=missing,
                              per_frame=per_frame)


def _err3d(res: Triangulation, truth):
    return np.linalg.norm(res.points - truth, axis=-1)


# --------------------------------------------------------------------------------------


def test_plain_triangulation_accuracy_and_outputs(rng):
    d = _take(rng)
    res = triangulate(d["observations"], d["R"], d["t"], d["intr"])
    e = _err3d(res, d["truth"])
    # 0.1 px noise at ~250 mm with f = 900 px: a few hundredths of a millimetre.
    assert np.median(e) < 0.05
    assert np.percentile(e, 99) < 0.15
    assert res.contribution.all()
    assert (res.n_cameras == 4).all()
    assert res.n_cameras.dtype == np.int8
    assert res.frames_done == d["observations"].shape[0]

    # Mean reprojection error in pixels agrees with exact distorted projection.
    uv, _ = project(res.points, d["R"], d["t"], d["intr"])
    exact = np.linalg.norm(uv - d["observations"], axis=-1).mean(-1)
    np.testing.assert_allclose(res.reprojection_error, exact, atol=1e-4)
    assert 0.05 < np.median(res.reprojection_error) < 0.2

    # Residual: RMS distance (mm) between the point and its rays, recomputed here.
    from carapost.algorithms.camera import pixel_rays

    o, dirs = pixel_rays(d["observations"], d["R"][None, None], d["t"][None, None], d["intr"])
    v = res.points[..., None, :] - o
    dist2 = (v**2).sum(-1) - (v * dirs).sum(-1) ** 2
    np.testing.assert_allclose(res.residual, np.sqrt(dist2.mean(-1)), rtol=1e-6, atol=1e-9)
    assert np.median(res.residual) < 0.05


def test_gauss_newton_refinement_lowers_reprojection_error(rng):
    d = _take(rng, F=20, P=60)
    obs = d["observations"] + rng.normal(0, 1.0, d["observations"].shape)
    lin = triangulate(obs, d["R"], d["t"], d["intr"])
    ref = triangulate(obs, d["R"], d["t"], d["intr"],
                      TriangulationParameters(refine_iterations=3))
    # Gauss-Newton minimises the squared pixel error the linear step only approximates.
    uv_l, _ = project(lin.points, d["R"], d["t"], d["intr"])
    uv_r, _ = project(ref.points, d["R"], d["t"], d["intr"])
    sq_l = ((uv_l - obs) ** 2).sum(-1).sum(-1)
    sq_r = ((uv_r - obs) ** 2).sum(-1).sum(-1)
    assert np.all(sq_r <= sq_l * (1 + 1e-6) + 1e-9)
    assert sq_r.sum() < sq_l.sum()


def test_outlier_rejection_fixes_single_bad_camera(rng):
    d = _take(rng, F=80, P=150, outliers=0.10)
    obs, R, t, intr, truth, bad = (d[k] for k in ("observations", "R", "t", "intr", "truth",
                                                  "bad"))
    plain = triangulate(obs, R, t, intr)
    robust = triangulate(obs, R, t, intr, TriangulationParameters(use_outlier_rejection=True))
    one_bad = bad.sum(-1) == 1
    e_p, e_r = _err3d(plain, truth), _err3d(robust, truth)
    assert np.median(e_p[one_bad]) > 3.0
    assert np.percentile(e_r[one_bad], 99) < 0.2
    # The bad camera is the one left out.
    assert not (robust.contribution & bad)[one_bad].any()
    assert (robust.n_cameras[one_bad] == 3).all()
    # Clean points are untouched.
    clean = bad.sum(-1) == 0
    np.testing.assert_allclose(robust.points[clean], plain.points[clean], atol=1e-9)
    assert robust.contribution[clean].all()


def test_outlier_rejection_p95_reduced_five_fold(rng):
    """Acceptance: with 10 % outliers, the 95th-percentile 3D error drops >= 5x."""
    d = _take(rng, F=80, P=150, outliers=0.10)
    obs, R, t, intr, truth = (d[k] for k in ("observations", "R", "t", "intr", "truth"))
    params = TriangulationParameters(use_outlier_rejection=True, minimum_cameras=2,
                                     maximum_cameras_to_drop=2)
    plain = triangulate(obs, R, t, intr, TriangulationParameters(minimum_cameras=2))
    robust = triangulate(obs, R, t, intr, params)
    p95_plain = np.percentile(_err3d(plain, truth), 95)
    p95_robust = np.percentile(_err3d(robust, truth), 95)
    assert p95_plain > 5.0
    assert p95_plain >= 5.0 * p95_robust, (p95_plain, p95_robust)
    # Defaults (minimum 3, drop 1): about 5 % of points have two bad cameras of four and
    # cannot be fixed by dropping one, so the reduction sits at the edge of 5x.
    default = triangulate(obs, R, t, intr, TriangulationParameters(use_outlier_rejection=True))
    assert np.percentile(_err3d(default, truth), 95) < p95_plain / 3.0


@pytest.mark.parametrize(
    "params",
    [
        TriangulationParameters(use_outlier_rejection=True),
        TriangulationParameters(use_outlier_rejection=True, minimum_cameras=2,
                                maximum_cameras_to_drop=2, target_reprojection_error=1.0),
        TriangulationParameters(minimum_cameras=2),
    ],
)
def test_vectorised_matches_per_point_loop(rng, params):
    d = _take(rng, F=12, P=40, outliers=0.15, missing=0.08, per_frame=True)
    args = (d["observations"], d["R"], d["t"], d["intr"], params)
    fast = triangulate(*args)
    loop = _bench().triangulate_loop(*args)
    np.testing.assert_array_equal(np.isfinite(fast.points), np.isfinite(loop.points))
    np.testing.assert_allclose(fast.points, loop.points, atol=1e-8)
    np.testing.assert_array_equal(fast.contribution, loop.contribution)
    np.testing.assert_allclose(fast.reprojection_error, loop.reprojection_error, atol=1e-8)
    np.testing.assert_allclose(fast.residual, loop.residual, atol=1e-8)


def test_subset_with_point_behind_a_camera_is_rejected():
    # Three cameras side by side; camera 2's observation is displaced outwards so that its
    # ray and camera 0's ray, as lines, cross behind the rig.
    R, t, intr = _simple_rig([[-60.0, 0, 0], [0.0, -40, 0], [60.0, 0, 0]])
    truth = np.array([[[0.0, 0.0, 250.0]]])
    uv, _ = project(truth, R, t, intr)
    uv = uv.copy()
    uv[0, 0, 2, 0] -= 560.0
    params = TriangulationParameters(use_outlier_rejection=True, minimum_cameras=2)
    res = triangulate(uv, R, t, intr, params)
    assert np.linalg.norm(res.points[0, 0] - truth[0, 0]) < 1e-4
    np.testing.assert_array_equal(res.contribution[0, 0], [True, True, False])

    # The rejected pair really fits its two rays exactly with the point behind the cameras.
    pair = triangulate(uv[:, :, [0, 2]], R[[0, 2]], t[[0, 2]], intr.subset([0, 2]),
                       TriangulationParameters(minimum_cameras=2))
    xc = np.einsum("cij,j->ci", R[[0, 2]], pair.points[0, 0]) + t[[0, 2]]
    assert (xc[:, 2] < 0).all()
    assert pair.residual[0, 0] < 1e-6


def test_subset_with_near_parallel_rays_is_rejected():
    # Cameras 0 and 1 are 4 mm apart; camera 2 is 120 mm above them.
    R, t, intr = _simple_rig([[-2.0, 0, 0], [2.0, 0, 0], [0.0, 120.0, 30]])
    truth = np.array([[[0.0, 0.0, 250.0]]])
    uv, _ = project(truth, R, t, intr)
    uv = uv.copy()
    # Along the short baseline: the pair {0, 1} still fits exactly, at 1.7 degrees, ~140 mm.
    uv[0, 0, 0, 0] -= 12.0
    robust = TriangulationParameters(use_outlier_rejection=True, minimum_cameras=2)
    res = triangulate(uv, R, t, intr, robust)
    assert np.linalg.norm(res.points[0, 0] - truth[0, 0]) < 1e-4
    np.testing.assert_array_equal(res.contribution[0, 0], [False, True, True])
    # Without the angle test the exact-fitting near-parallel pair drags the mean far away.
    loose = TriangulationParameters(use_outlier_rejection=True, minimum_cameras=2,
                                    min_ray_angle_deg=0.0)
    res0 = triangulate(uv, R, t, intr, loose)
    assert np.linalg.norm(res0.points[0, 0] - truth[0, 0]) > 20.0


def test_minimum_cameras_clamped_with_warning(rng, caplog):
    d = _take(rng, F=3, P=10)
    obs = d["observations"][:, :, :2]
    intr = d["intr"].subset([0, 1])
    with caplog.at_level(logging.WARNING, logger="carapost.triangulation"):
        res = triangulate(obs, d["R"][:2], d["t"][:2], intr)  # default minimum 3 > 2 cameras
    assert any("Minimum Cameras" in r.getMessage() and r.levelno == logging.WARNING
               for r in caplog.records)
    assert (res.n_cameras == 2).all()
    assert np.percentile(_err3d(res, d["truth"]), 95) < 0.5


def test_points_below_minimum_cameras_are_left_out(rng, caplog):
    d = _take(rng, F=4, P=20)
    obs = d["observations"].copy()
    obs[:, :5, 2:] = np.nan  # first five points seen by two cameras only
    obs[:, 5:8, 1:] = np.nan  # three points seen by one camera only
    with caplog.at_level(logging.WARNING, logger="carapost.triangulation"):
        res = triangulate(obs, d["R"], d["t"], d["intr"])
    assert not caplog.records  # 3 <= 4 cameras: no clamp
    assert np.isnan(res.points[:, :8]).all()
    assert (res.n_cameras[:, :8] == 0).all() and not res.contribution[:, :8].any()
    assert np.isnan(res.reprojection_error[:, :8]).all() and np.isnan(res.residual[:, :8]).all()
    assert np.isfinite(res.points[:, 8:]).all()
    two = triangulate(obs, d["R"], d["t"], d["intr"], TriangulationParameters(minimum_cameras=2))
    assert np.isfinite(two.points[:, :5]).all() and (two.n_cameras[:, :5] == 2).all()
    assert np.isnan(two.points[:, 5:8]).all()
    assert np.max(_err3d(two, d["truth"])[:, :5]) < 1.0


def test_flatten_single_camera_data(rng, caplog):
    d = _take(rng, F=3, P=10)
    intr = d["intr"].subset([1])
    R, t = d["R"][1:2], d["t"][1:2]
    obs = d["observations"][:, :, 1:2]
    with caplog.at_level(logging.WARNING, logger="carapost.triangulation"):
        flat = triangulate(obs, R, t, intr)  # minimum 3 clamped to the single camera
    assert caplog.records
    # Z data set to 0: the point is where the camera ray meets the world plane Z = 0.
    np.testing.assert_allclose(flat.points[..., 2], 0.0, atol=1e-9)
    uv, depth = project(flat.points, R, t, intr)
    assert (depth > 0).all()
    np.testing.assert_allclose(uv, obs, atol=1e-5)
    assert (flat.n_cameras == 1).all() and (flat.reprojection_error == 0).all()

    no_flat = TriangulationParameters(flatten_single_camera_data=False)
    est = d["truth"] + 1.0
    kept = triangulate(obs, R, t, intr, no_flat, single_camera_estimates=est)
    np.testing.assert_array_equal(kept.points, est)
    none = triangulate(obs, R, t, intr, no_flat)
    assert np.isnan(none.points).all() and (none.n_cameras == 0).all()


def test_single_camera_points_in_multicamera_rig_with_minimum_one(rng):
    d = _take(rng, F=2, P=10)
    obs = d["observations"].copy()
    obs[:, :3, 1:] = np.nan
    res = triangulate(obs, d["R"], d["t"], d["intr"], TriangulationParameters(minimum_cameras=1))
    np.testing.assert_allclose(res.points[:, :3, 2], 0.0, atol=1e-9)
    assert (res.n_cameras[:, :3] == 1).all() and (res.n_cameras[:, 3:] == 4).all()
    assert np.max(_err3d(res, d["truth"])[:, 3:]) < 0.2


def test_results_do_not_depend_on_chunking(rng):
    d = _take(rng, F=30, P=50, outliers=0.1, missing=0.05, per_frame=True)
    params = TriangulationParameters(use_outlier_rejection=True, refine_iterations=1)
    args = (d["observations"], d["R"], d["t"], d["intr"], params)
    big = triangulate(*args, chunk_size=100_000)
    one = triangulate(*args, chunk_size=1)  # one frame per chunk
    odd = triangulate(*args, chunk_size=7 * 50 + 3)
    for res in (one, odd):
        np.testing.assert_allclose(res.points, big.points, atol=1e-10)
        np.testing.assert_array_equal(res.contribution, big.contribution)
        np.testing.assert_allclose(res.reprojection_error, big.reprojection_error, atol=1e-10)


def test_per_frame_cameras_match_frame_by_frame(rng):
    d = _take(rng, F=6, P=30, outliers=0.1, per_frame=True)
    params = TriangulationParameters(use_outlier_rejection=True)
    whole = triangulate(d["observations"], d["R"], d["t"], d["intr"], params)
    for f in range(6):
        one = triangulate(d["observations"][f:f + 1], d["R"][f], d["t"][f], d["intr"], params)
        np.testing.assert_allclose(one.points[0], whole.points[f], atol=1e-10)
    # An unsolved camera-frame (NaN pose) contributes nothing.
    R = d["R"].copy()
    R[2, 3] = np.nan
    res = triangulate(d["observations"], R, d["t"], d["intr"])
    assert not res.contribution[2, :, 3].any()
    assert res.contribution[1, :, 3].all()


def test_progress_and_cancel(rng):
    d = _take(rng, F=20, P=10)
    calls = []

    def progress(done, total):
        calls.append((done, total))
        return done < 8

    res = triangulate(d["observations"], d["R"], d["t"], d["intr"], chunk_size=40,
                      progress=progress)
    assert calls == [(4, 20), (8, 20)]
    assert res.frames_done == 8
    assert np.isfinite(res.points[:8]).all() and np.isnan(res.points[8:]).all()


def test_bad_input_is_rejected_clearly(rng):
    d = _take(rng, F=2, P=5)
    with pytest.raises(ValueError, match="observations"):
        triangulate(d["observations"][..., 0], d["R"], d["t"], d["intr"])
    with pytest.raises(ValueError, match="intr"):
        triangulate(d["observations"][:, :, :3], d["R"][:3], d["t"][:3], d["intr"])
    with pytest.raises(ValueError, match="R must"):
        triangulate(d["observations"], d["R"][:, :2], d["t"], d["intr"])
    with pytest.raises(ValueError, match="minimum_cameras"):
        TriangulationParameters(minimum_cameras=0)
    with pytest.raises(ValueError, match="target_reprojection_error"):
        TriangulationParameters(target_reprojection_error=0.0)
    with pytest.raises(ValueError, match="maximum_cameras_to_drop"):
        TriangulationParameters(maximum_cameras_to_drop=-1)


def test_property_specs_match_parameter_defaults():
    defaults = TriangulationParameters()
    assert [f.name for f, _ in property_fields(TriangulationParameters)] == [
        "minimum_cameras", "flatten_single_camera_data", "use_outlier_rejection",
        "maximum_cameras_to_drop", "target_reprojection_error", "min_ray_angle_deg",
        "refine_iterations"]
    assert math.isclose(defaults.target_reprojection_error, 2.0)
    assert defaults.minimum_cameras == 3 and defaults.maximum_cameras_to_drop == 1
    assert defaults.use_outlier_rejection is False
