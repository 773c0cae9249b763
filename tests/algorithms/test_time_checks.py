"""Wrong observations found by the motion; single-sensor samples placed from both sides.

On a synthetic take with truth cameras and 0.1 px detection noise: a blob 3 px off in
the one camera of the other caddy (which fixes a one-caddy point's depth) moves the
point in depth while every residual stays small; the motion finds it. A marker that one
camera of its caddy misses for a run of frames is put back on its ray at the depth its
neighbours' motion gives from both sides, with a sigma measured on the take. A sample
whose observations are all on a wrong blob, consistently in both cameras of a caddy
(small residual), is removed by its neighbours in time; a single-sensor sample whose
ray misses its prediction by more than the Single Sensor Tracking Threshold is not
kept. An observation on a blob twice as wide as the marker's blob in the frames around
it (merged with a neighbour, its centre pixels off in every camera alike) is removed,
and so is one on a blob twice as long as the marker's over the take (merged along its
length with a crease for longer than the width's window, its width unchanged).
A two-camera sample whose rays miss each other loses the observation of the camera that
does not usually see the point; a single-sensor sample that no other camera ever
checked becomes a gap.
"""

import numpy as np
import pytest

from carapost.algorithms.camera import project
from carapost.algorithms.codes import (
    POINT_FILLS,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    blank_point_array,
)
from carapost.algorithms.single_sensor import neighbour_prediction
from carapost.algorithms.temporal_check import inconsistent_observations, loo_prediction
from carapost.algorithms.tracking.time_checks import (
    PAIR_TARGET_FACTOR,
    lengthened_blobs,
    merged_blobs,
    place_single_sensor,
    reject_by_motion,
    reject_inconsistent_pairs,
    reject_merged_blobs,
    reject_unanchored_single_sensor,
    reject_wrong_samples,
    unanchored_single_sensor,
)
from carapost.algorithms.uncertainty import retriangulate
from carapost.synth import SynthConfig, build_scene


@pytest.fixture(scope="module")
def scene():
    return build_scene(SynthConfig(preset="speech", frames=40, seed=3, size=(1280, 720)))


def _arrays(scene, rng, noise=0.1):
    """Track-result arrays from the truth: observations with noise, triangulated."""
    F, M, C = scene.visible.shape
    o = {k: blank_point_array(k, F, M, C) for k in POINT_FILLS}
    uv = scene.uv + rng.normal(0, noise, scene.uv.shape)
    obs = np.where(scene.visible[..., None], uv, np.nan)
    o["obs"][:] = obs
    o["source"][scene.visible] = 1
    tri = scene.visible.sum(-1) >= 2
    X, res = retriangulate(obs, scene.cam_R, scene.cam_t, scene.intrinsics, tri)
    ok = tri & np.isfinite(X).all(-1)
    o["positions"][ok] = X[ok]
    o["residual"][ok] = res[ok]
    o["recon"][ok] = RECON_TRIANGULATED
    return o


def _error(o, scene):
    return np.linalg.norm(o["positions"].astype(float) - scene.points3d, axis=-1)


def test_wrong_blob_in_the_other_caddys_camera_is_removed(scene):
    rng = np.random.default_rng(0)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    # samples seen by both cameras of caddy (0, 1) and by camera 2 alone of the other
    three = scene.visible[..., 0] & scene.visible[..., 1] & scene.visible[..., 2]
    three[:, :] &= ~scene.visible[..., 3]
    o["obs"][..., 3, :][three] = np.nan  # make sure camera 3 is not there
    cand = np.argwhere(three[2:-2]) + [2, 0]
    assert len(cand) > 40
    pick = cand[rng.choice(len(cand), 25, replace=False)]
    # 3 px off in camera 2, across its image (the direction that moves caddy 0-1's depth)
    o["obs"][pick[:, 0], pick[:, 1], 2] += np.array([3.0, 0.0])
    obs = o["obs"].astype(float)
    redo = np.zeros((F, M), bool)
    redo[pick[:, 0], pick[:, 1]] = True
    X, _ = retriangulate(obs, scene.cam_R, scene.cam_t, scene.intrinsics, redo)
    o["positions"][redo] = X[redo]
    before = _error(o, scene)[redo]
    injected = np.zeros((F, M, C), bool)
    injected[pick[:, 0], pick[:, 1], 2] = True
    n = reject_by_motion(o, scene.cam_R, scene.cam_t, np.ones(M, bool), scene.intrinsics,
                         np.zeros(F, bool))
    removed = ~np.isfinite(o["obs"][..., 0]) & np.isfinite(obs[..., 0])
    assert n == removed.sum()
    assert (removed & injected).sum() >= 23  # nearly all found
    assert (removed & ~injected).sum() <= 1  # and next to no right blob removed
    after = _error(o, scene)[redo]
    assert np.nanmax(before) > 0.3
    # each cleared sample is now what its two right cameras give
    clean = obs.copy()
    clean[injected] = np.nan
    Xc, _ = retriangulate(clean, scene.cam_R, scene.cam_t, scene.intrinsics, redo)
    fixed_ = removed[redo].any(-1)
    ec = np.linalg.norm(Xc - scene.points3d, axis=-1)[redo]
    assert np.allclose(after[fixed_], ec[fixed_], atol=1e-4)
    assert np.sqrt(np.mean(after ** 2)) < 0.5 * np.sqrt(np.mean(before ** 2))
    assert (o["recon"][redo] == RECON_TRIANGULATED).all()


def test_clean_take_loses_no_observation(scene):
    o = _arrays(scene, np.random.default_rng(1))
    F, M, C = scene.visible.shape
    X = np.where((o["recon"] == RECON_TRIANGULATED)[..., None], o["positions"], np.nan)
    tri = o["recon"] == RECON_TRIANGULATED
    from carapost.algorithms.single_sensor import neighbours

    pred = loo_prediction(X, tri, neighbours(X, tri))
    flag = inconsistent_observations(o["obs"], pred, scene.cam_R, scene.cam_t,
                                     scene.intrinsics, tri)
    assert flag.sum() <= 0.0005 * tri.sum()


def _caddy_23_only(scene) -> np.ndarray:
    """Up to six markers seen by cameras 2 and 3 only, on every frame."""
    one = scene.visible[..., 2] & scene.visible[..., 3] & ~scene.visible[..., 0] & \
        ~scene.visible[..., 1]
    pts = np.flatnonzero(one.all(0))[:6]
    assert pts.size >= 3
    return pts


def _camera_3_misses(o, pts, run) -> None:
    """Camera 3 misses ``pts`` over ``run``: their samples there are single-sensor."""
    o["obs"][run, pts, 3] = np.nan
    rec = o["recon"][run]
    rec[:, pts] = RECON_SINGLE_SENSOR
    o["recon"][run] = rec


def test_single_sensor_samples_from_both_sides(scene):
    rng = np.random.default_rng(2)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    # markers of caddy (2, 3) only; camera 3 misses them on frames 12-21
    pts = _caddy_23_only(scene)
    run = slice(12, 22)
    o["obs"][run, pts, 3] = np.nan
    block = o["positions"][run]
    # the per-frame tracker's placement, here 1 mm off along camera 2's ray
    cen = -np.einsum("fji,fj->fi", scene.cam_R[run, 2], scene.cam_t[run, 2])
    d = scene.points3d[run][:, pts] - cen[:, None]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    block[:, pts] = scene.points3d[run][:, pts] + 1.0 * d
    o["positions"][run] = block
    rec = o["recon"][run]
    rec[:, pts] = RECON_SINGLE_SENSOR
    o["recon"][run] = rec
    kept = {k: v.copy() for k, v in o.items()}
    # with max_gap 2 only the frames next to the triangulated ones are predicted from
    # both sides; further in, the tracker's placement is kept (moved onto the ray)
    place_single_sensor(kept, scene.cam_R, scene.cam_t, np.ones(M, bool),
                        scene.intrinsics, max_gap=2)
    ek = _error(kept, scene)[run][:, pts]
    assert np.median(ek[[0, 1, -2, -1]]) < 0.3
    assert np.median(ek[3:7]) > 0.7
    # by default (MAX_GAP, 32 frames) the whole 10-frame run is
    sigma = place_single_sensor(o, scene.cam_R, scene.cam_t, np.ones(M, bool),
                                scene.intrinsics)
    e = _error(o, scene)[run][:, pts]
    # the 1 mm placement is replaced; lips whose neighbours move otherwise stay worst
    assert np.sqrt(np.mean(e ** 2)) < 0.4
    assert np.median(e) < 0.2
    s = sigma[run][:, pts]
    assert np.isfinite(s).all()
    # sigma grows with the distance in time to the triangulated samples
    assert (s[4:6] > s[[0, -1]]).all()
    # and is the right size: most errors within 2 sigma, not absurdly loose
    assert np.mean(e <= 2 * s) >= 0.75
    assert np.median(s) < 0.5
    assert np.isnan(sigma[o["recon"] != RECON_SINGLE_SENSOR]).all()


def test_single_sensor_sigma_carries_a_bad_references_sigma(scene):
    """A single-sensor sample predicted from a triangulated sample that is itself off
    (the frame where the caddy's second camera starts to lose the marker) inherits that
    error; the reference's sigma says so, and the sample's sigma must too."""
    rng = np.random.default_rng(4)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    pts = _caddy_23_only(scene)
    run = slice(12, 22)
    _camera_3_misses(o, pts, run)
    # the reference before the run: 0.8 mm off along camera 2's ray, and its sigma
    # says so; every other triangulated sample has the take's typical sigma
    cen = -np.einsum("ji,j->i", scene.cam_R[11, 2], scene.cam_t[11, 2])
    d = scene.points3d[11, pts] - cen
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o["positions"][11, pts] = scene.points3d[11, pts] + 0.8 * d
    tri = o["recon"] == RECON_TRIANGULATED
    ref = np.where(tri, 0.05, np.nan).astype(np.float32)
    ref[11, pts] = 0.8
    args = (scene.cam_R, scene.cam_t, np.ones(M, bool), scene.intrinsics)
    plain = {k: v.copy() for k, v in o.items()}
    s0 = place_single_sensor(plain, *args)[run][:, pts]
    s1 = place_single_sensor(o, *args, ref_sigma=ref)[run][:, pts]
    e = _error(o, scene)[run][:, pts]
    assert np.allclose(e, _error(plain, scene)[run][:, pts])  # the placement is the same
    assert np.median(e[0]) > 0.5  # next to the bad reference the sample inherits its error
    assert np.mean(e[0] <= 2 * s0[0]) < 0.5  # the take's curve alone does not cover it
    assert np.mean(e[0] <= 2 * s1[0]) == 1.0
    # the weight follows the distance in time: at the run's far end the good reference
    # dominates and the sigma hardly moves
    assert (s1 >= s0 - 1e-6).all()
    assert np.median(s1[-1] / s0[-1]) < 1.5 < np.median(s1[0] / s0[0])
    # a reference no worse than the point's typical sample adds nothing
    flat = {k: v.copy() for k, v in plain.items()}
    same = place_single_sensor(flat, *args, ref_sigma=np.where(tri, 0.05, np.nan))
    assert np.allclose(same[run][:, pts], s0, rtol=1e-5)


def test_single_sensor_samples_of_the_first_frame_are_placed_and_get_a_sigma(scene):
    """The initialised (fixed) frame is placed like any other: what it holds of a point
    found later is the per-frame tracker's placement, which had no sigma."""
    rng = np.random.default_rng(3)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    pts = _caddy_23_only(scene)
    run = slice(0, 4)  # camera 3 misses them on the first four frames
    o["obs"][run, pts, 3] = np.nan
    cen = -np.einsum("fji,fj->fi", scene.cam_R[run, 2], scene.cam_t[run, 2])
    d = scene.points3d[run][:, pts] - cen[:, None]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    block = o["positions"][run]
    block[:, pts] = scene.points3d[run][:, pts] + 1.0 * d
    o["positions"][run] = block
    rec = o["recon"][run]
    rec[:, pts] = RECON_SINGLE_SENSOR
    o["recon"][run] = rec
    sigma = place_single_sensor(o, scene.cam_R, scene.cam_t, np.ones(M, bool),
                                scene.intrinsics)
    e = _error(o, scene)[run][:, pts]
    assert np.median(e[0]) < 0.3 and np.median(e) < 0.3  # the 1 mm placement replaced
    assert np.isfinite(sigma[run][:, pts]).all()


def test_neighbour_prediction_blends_both_sides():
    # the point moves with its neighbours, plus a drift of its own that the neighbours
    # do not share: both sides' references give the interpolation of that drift
    F = 21
    base = np.array([[0., 0, 100], [10, 0, 100], [-10, 0, 100], [0, 10, 100],
                     [0, -10, 100]])
    X = np.repeat(base[None], F, 0)
    X[:, :, 0] += np.linspace(0, 5, F)[:, None]
    X[:, 0, 1] += np.linspace(0, 2, F)  # the point's own drift
    tri = np.ones((F, 5), bool)
    tri[5:16, 0] = False
    pred, gap = neighbour_prediction(np.where(tri[..., None], X, np.nan), tri)
    assert np.allclose(pred[5:16, 0], X[5:16, 0], atol=1e-9)
    assert gap[10, 0] == 6 and gap[5, 0] == 1 and gap[0, 0] == 0
    # a point with no reference at all has no prediction
    tri[:, 4] = False
    pred, gap = neighbour_prediction(np.where(tri[..., None], X, np.nan), tri)
    assert np.isnan(pred[:, 4]).all() and (gap[:, 4] == -1).all()


@pytest.mark.parametrize("single_sensor", [True, False])
def test_a_two_camera_sample_left_with_one_camera(scene, single_sensor):
    # seen by cameras 0 and 2 only; a blob 4 px off in camera 2: after its removal the
    # sample is single-sensor, or a gap when single sensor tracking is off
    rng = np.random.default_rng(6)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    two = scene.visible[..., 0] & scene.visible[..., 2]
    cand = np.argwhere(two[2:-2]) + [2, 0]
    pick = cand[rng.choice(len(cand), 12, replace=False)]
    f, p = pick[:, 0], pick[:, 1]
    block = o["obs"][f, p]
    block[:, [1, 3]] = np.nan
    block[:, 2] += [4.0, 0.0]
    o["obs"][f, p] = block
    obs = o["obs"].astype(float)
    redo = np.zeros((F, M), bool)
    redo[f, p] = True
    X, _ = retriangulate(obs, scene.cam_R, scene.cam_t, scene.intrinsics, redo)
    o["positions"][redo] = X[redo]
    reject_by_motion(o, scene.cam_R, scene.cam_t, np.ones(M, bool), scene.intrinsics,
                     np.zeros(F, bool), single_sensor=single_sensor)
    gone = ~np.isfinite(o["obs"][f, p, 2, 0])
    assert gone.sum() >= 10
    if single_sensor:
        assert (o["recon"][f, p][gone] == RECON_SINGLE_SENSOR).all()
    else:
        assert (o["recon"][f, p][gone] == RECON_NONE).all()
        assert np.isnan(o["positions"][f, p][gone]).all()


def _one_caddy(o, scene, cams=(0, 1)):
    """Keep only cameras ``cams`` of every sample they both see; re-triangulate."""
    F, M, C = scene.visible.shape
    both = scene.visible[..., cams[0]] & scene.visible[..., cams[1]]
    other = [c for c in range(C) if c not in cams]
    block = o["obs"][both]
    block[:, other] = np.nan
    o["obs"][both] = block
    X, res = retriangulate(o["obs"].astype(float), scene.cam_R, scene.cam_t,
                           scene.intrinsics, both)
    ok = both & np.isfinite(X).all(-1)
    o["positions"][ok] = X[ok]
    o["residual"][ok] = res[ok]
    return ok


def test_consistent_wrong_match_in_both_cameras_of_a_caddy_is_removed(scene):
    rng = np.random.default_rng(7)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    ok = _one_caddy(o, scene)
    cand = np.argwhere(ok[2:-2]) + [2, 0]
    # isolated samples of different points: each wrong sample has right neighbours
    pts = rng.choice(np.unique(cand[:, 1]), 12, replace=False)
    f = rng.integers(3, F - 3, pts.size)
    keep = ok[f, pts]
    f, p = f[keep], pts[keep]
    assert p.size >= 8
    # a blob 2 mm off on the face, seen consistently by both cameras of the caddy
    off = scene.points3d[f, p] + rng.normal(0, 1, (p.size, 3)) * [1, 1, 0.2]
    off = scene.points3d[f, p] + 2.0 * (off - scene.points3d[f, p]) / np.linalg.norm(
        off - scene.points3d[f, p], axis=-1, keepdims=True)
    for k in range(p.size):
        uv, _ = project(off[k][None], scene.cam_R[f[k]], scene.cam_t[f[k]],
                        scene.intrinsics)
        row = o["obs"][f[k], p[k]]
        row[:2] = uv[0, :2]
        o["obs"][f[k], p[k]] = row
        o["positions"][f[k], p[k]] = off[k]
    o["residual"][f, p] = 0.0
    tri_before = (o["recon"] == RECON_TRIANGULATED).sum()
    n = reject_wrong_samples(o, np.ones(M, bool), np.zeros(F, bool)).sum()
    gone = o["recon"] == RECON_NONE
    # nearly every wrong sample found (one whose two sides disagree by as much, a lip
    # moving fast against its neighbours, is not judged)
    hit = gone[f, p]
    assert hit.mean() >= 0.8
    assert np.isnan(o["positions"][f, p][hit]).all()
    assert (o["detection"][f, p][hit] == POINT_FILLS["detection"]).all()
    assert not np.isfinite(o["obs"][f, p][hit]).any()
    assert n - hit.sum() <= 0.0005 * tri_before  # and next to no right one


def test_clean_take_loses_no_sample(scene):
    o = _arrays(scene, np.random.default_rng(8))
    _one_caddy(o, scene, (2, 3))
    F, M, C = scene.visible.shape
    tri = (o["recon"] == RECON_TRIANGULATED).sum()
    n = reject_wrong_samples(o, np.ones(M, bool), np.zeros(F, bool)).sum()
    assert n <= 0.0005 * tri


def test_single_sensor_threshold(scene):
    # markers of caddy (2, 3) only; camera 3 misses them on frames 12-14; on frame 13
    # camera 2's blob is a wrong one 6 px away
    rng = np.random.default_rng(9)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    pts = _caddy_23_only(scene)
    run = slice(12, 15)
    _camera_3_misses(o, pts, run)
    blk = o["obs"][13]
    blk[pts, 2] += [6.0, 0.0]
    o["obs"][13] = blk
    args = (scene.cam_R, scene.cam_t, np.ones(M, bool), scene.intrinsics)
    free = {k: v.copy() for k, v in o.items()}
    place_single_sensor(free, *args)
    assert (free["recon"][13, pts] == RECON_SINGLE_SENSOR).all()
    assert np.median(free["residual"][13, pts]) > 0.5  # the ray misses the prediction
    sigma = place_single_sensor(o, *args, threshold_mm=0.5)
    # the wrong ones are gaps, the right ones on frames 12 and 14 kept
    assert (o["recon"][13, pts] == RECON_NONE).all()
    assert np.isnan(o["positions"][13, pts]).all() and np.isnan(sigma[13, pts]).all()
    assert not np.isfinite(o["obs"][13, pts]).any()
    right = o["recon"][[12, 14]][:, pts] == RECON_SINGLE_SENSOR
    assert right.mean() >= 0.8
    assert (o["residual"][[12, 14]][:, pts][right] <= 0.5).all()
    assert (sigma[[12, 14]][:, pts][right] <= 0.5).all()



def _axes(scene, rng, lo, hi, drift):
    """(F, M, C) blob axes (px) changing slowly, as a face turning or moving would change
    them: ``lo``-``hi`` px per marker-camera, up to ``drift`` over the take, 3 % noise."""
    F, M, C = scene.visible.shape
    base = rng.uniform(lo, hi, (1, M, C))
    d = 1.0 + drift * np.sin(np.linspace(0, np.pi, F))[:, None, None] * \
        rng.uniform(-1, 1, (1, M, C))
    a = base * d * (1.0 + rng.normal(0, 0.03, (F, M, C)))
    return np.where(scene.visible, a, np.nan)


def _widths(scene, rng):
    """Semi-minor axes: 1.5-4 px, up to 40 % over the take (the angle changes them)."""
    return _axes(scene, rng, 1.5, 4.0, 0.4)


def _lengths(scene, rng, drift=0.1):
    """Semi-major axes: a disc's radius magnified, 3-5 px, changing with the distance
    only (up to ``drift`` over the take)."""
    return _axes(scene, rng, 3.0, 5.0, drift)


def test_observations_on_merged_blobs_are_removed(scene):
    rng = np.random.default_rng(11)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    ok = _one_caddy(o, scene)
    widths = _widths(scene, rng)
    # three points merge with a neighbour's blob in both cameras of caddy (0, 1) for
    # 1-4 frames: the blob is 2.2 times as wide, its centre 8 px off in each camera
    cand = np.unique(np.argwhere(ok[5:-8].all(0)).ravel())
    pts = rng.choice(cand, 3, replace=False)
    runs = [(8, 9), (15, 18), (25, 29)]
    for p, (a, b) in zip(pts, runs, strict=True):
        blk = o["obs"][a:b, p]
        blk[:, :2] += [6.0, 5.3]
        o["obs"][a:b, p] = blk
        widths[a:b, p, :2] *= 2.2
        X, _ = retriangulate(o["obs"][a:b, p][:, None].astype(float), scene.cam_R[a:b],
                             scene.cam_t[a:b], scene.intrinsics, np.ones((b - a, 1), bool))
        o["positions"][a:b, p] = X[:, 0]
    wrong = np.zeros((F, M), bool)
    for p, (a, b) in zip(pts, runs, strict=True):
        wrong[a:b, p] = True
    assert _error(o, scene)[wrong].min() > 1.0
    tri = o["recon"] == RECON_TRIANGULATED
    n_obs = np.isfinite(o["obs"][..., 0]).sum()
    drop = reject_merged_blobs(o, widths, scene.cam_R, scene.cam_t, np.ones(M, bool),
                               scene.intrinsics, np.zeros(F, bool))
    # every merged observation, and no other
    assert drop.any(-1)[wrong].all()
    assert drop.sum() == 2 * wrong.sum()
    assert np.isfinite(o["obs"][..., 0]).sum() == n_obs - drop.sum()
    # those samples had only the two merged cameras: they are gaps now, not wrong points
    assert (o["recon"][wrong] == RECON_NONE).all()
    assert np.isnan(o["positions"][wrong]).all()
    assert np.isnan(widths[drop]).all()
    # the rest of the take is as it was
    assert (o["recon"][tri & ~wrong] == RECON_TRIANGULATED).all()


def test_a_merged_camera_of_three_leaves_a_sample_of_two(scene):
    rng = np.random.default_rng(12)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    three = (scene.visible.sum(-1) >= 3) & (o["recon"] == RECON_TRIANGULATED)
    f, p = np.argwhere(three[12:-12])[0] + [12, 0]
    c = int(np.flatnonzero(scene.visible[f, p])[0])
    widths = _widths(scene, rng)
    widths[f, p, c] *= 2.5
    row = o["obs"][f, p]
    row[c] += [7.0, 0.0]
    o["obs"][f, p] = row
    X, _ = retriangulate(o["obs"][f:f + 1, p:p + 1].astype(float), scene.cam_R[f:f + 1],
                         scene.cam_t[f:f + 1], scene.intrinsics, np.ones((1, 1), bool))
    o["positions"][f, p] = X[0, 0]
    before = _error(o, scene)[f, p]
    drop = reject_merged_blobs(o, widths, scene.cam_R, scene.cam_t, np.ones(M, bool),
                               scene.intrinsics, np.zeros(F, bool))
    assert np.argwhere(drop).tolist() == [[f, p, c]]
    assert o["recon"][f, p] == RECON_TRIANGULATED
    assert _error(o, scene)[f, p] < min(0.3, before / 3)


def test_a_blob_merged_along_its_length_for_a_long_run_is_removed(scene):
    rng = np.random.default_rng(14)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    ok = _one_caddy(o, scene)
    widths = _widths(scene, rng)
    lengths = _lengths(scene, rng)
    # one point of a one-caddy pair: camera 1's blob runs into a crease for 15 frames
    # (longer than the width's window): twice as long, as wide as before, its centre
    # 2 px off along the crease; that pair's depth is 1-3 mm off
    p = int(np.flatnonzero(ok.all(0))[0])
    a, b = 10, 25
    blk = o["obs"][a:b, p]
    blk[:, 1] += [1.6, 1.2]
    o["obs"][a:b, p] = blk
    lengths[a:b, p, 1] *= 2.0
    X, _ = retriangulate(o["obs"][a:b, p][:, None].astype(float), scene.cam_R[a:b],
                         scene.cam_t[a:b], scene.intrinsics, np.ones((b - a, 1), bool))
    o["positions"][a:b, p] = X[:, 0]
    assert _error(o, scene)[a:b, p].min() > 0.5
    # the width test alone does not see it
    assert not merged_blobs(widths)[a:b, p].any()
    drop = reject_merged_blobs(o, widths, scene.cam_R, scene.cam_t, np.ones(M, bool),
                               scene.intrinsics, np.zeros(F, bool), lengths=lengths)
    assert np.argwhere(drop[:, p]).tolist() == [[f, 1] for f in range(a, b)]
    # no other observation of the take
    assert drop.sum() == b - a
    # camera 0 is left: single-sensor samples (placed later from both sides), not
    # a wrong depth
    assert (o["recon"][a:b, p] == RECON_SINGLE_SENSOR).all()


def test_lengths_that_change_slowly_are_not_lengthened(scene):
    rng = np.random.default_rng(15)
    # a marker's length changes with its distance only (a few per cent); even 30 %
    # over the take, and a point-camera seen in too few frames, is not flagged
    L = _lengths(scene, rng, drift=0.3)
    assert not lengthened_blobs(L).any()
    sparse = np.full_like(L, np.nan)
    sparse[:4] = L[:4]
    sparse[3] *= 3
    assert not lengthened_blobs(sparse).any()


def test_widths_that_change_slowly_are_not_merged(scene):
    rng = np.random.default_rng(13)
    w = _widths(scene, rng)
    assert not merged_blobs(w).any()
    # a blob seen too rarely around a frame is not judged
    sparse = np.full_like(w, np.nan)
    sparse[::6] = w[::6]
    sparse[18] = 3 * np.nan_to_num(w[18], nan=2.0)
    assert not merged_blobs(sparse).any()


def _pair_target(noise=0.1):
    """The pair test's target as the clean-up sets it: twice the re-solve's outlier
    target (6 times the 2D noise, at least 0.5 px)."""
    return PAIR_TARGET_FACTOR * max(0.5, 6.0 * noise)


def _resolve(o, scene, f, p):
    X, res = retriangulate(o["obs"][f:f + 1, p:p + 1].astype(float), scene.cam_R[f:f + 1],
                           scene.cam_t[f:f + 1], scene.intrinsics, np.ones((1, 1), bool))
    o["positions"][f, p] = X[0, 0]
    o["residual"][f, p] = res[0, 0]


def _caddy_01_point(scene, seed):
    """Track arrays (``_arrays``, caddy (0, 1) alone where it sees a marker) and a point
    seen by that caddy throughout, with no observation in cameras 2 and 3."""
    o = _arrays(scene, np.random.default_rng(seed))
    ok = _one_caddy(o, scene)
    p = int(np.flatnonzero(ok.all(0))[0])
    for c in (2, 3):
        col = o["obs"][:, p, c]
        col[:] = np.nan
        o["obs"][:, p, c] = col
    return o, p


def test_a_blob_in_a_camera_that_does_not_see_the_point_is_removed_from_its_pair(scene):
    o, p = _caddy_01_point(scene, 21)
    F, M, C = scene.visible.shape
    # on two frames camera 1 misses it and camera 2 (which never observes it) has a dark
    # feature 8 px from its projection
    frames = (17, 18)
    for f in frames:
        row = o["obs"][f, p]
        row[1] = np.nan
        row[2] = scene.uv[f, p, 2] + [6.4, -4.8]
        o["obs"][f, p] = row
        _resolve(o, scene, f, p)
    assert (_error(o, scene)[list(frames), p] > 1.0).all()
    n_before = int(np.isfinite(o["obs"][..., 0]).sum())
    drop = reject_inconsistent_pairs(o, scene.cam_R, scene.cam_t, np.ones(M, bool),
                                     scene.intrinsics, np.zeros(F, bool), _pair_target())
    # camera 2's two observations, nothing else; the samples keep camera 0 alone
    assert sorted(map(tuple, np.argwhere(drop).tolist())) == [(f, p, 2) for f in frames]
    assert int(np.isfinite(o["obs"][..., 0]).sum()) == n_before - 2
    assert (o["recon"][list(frames), p] == RECON_SINGLE_SENSOR).all()


def test_right_pairs_and_a_pair_seen_throughout_are_left_alone(scene):
    rng = np.random.default_rng(22)
    o = _arrays(scene, rng)
    F, M, C = scene.visible.shape
    # every right pair of the take, cross-caddy ones included: nothing is removed
    pairs = (o["recon"] == RECON_TRIANGULATED) & (np.isfinite(o["obs"][..., 0]).sum(-1) == 2)
    assert pairs.sum() > 100
    before = o["obs"].copy()
    drop = reject_inconsistent_pairs(o, scene.cam_R, scene.cam_t, np.ones(M, bool),
                                     scene.intrinsics, np.zeros(F, bool), _pair_target())
    assert not drop.any()
    assert np.array_equal(before, o["obs"], equal_nan=True)
    # a point whose two cameras both observe it throughout, one of them 4 px off on
    # every frame: the pairs cannot say which camera is wrong, so none is removed (the
    # spurious points' test judges such a point as a whole)
    ok = _one_caddy(o, scene, cams=(0, 2))
    p = int(np.flatnonzero(ok.all(0))[0])
    col = o["obs"][:, p, 2]
    col += [0.0, 4.0]
    o["obs"][:, p, 2] = col
    for f in range(F):
        _resolve(o, scene, f, p)
    uv = project(o["positions"][:, p].astype(float)[:, None], scene.cam_R, scene.cam_t,
                 scene.intrinsics)[0][:, 0]
    err = np.linalg.norm(uv - o["obs"][:, p], axis=-1)[:, [0, 2]]
    assert (np.sqrt((err ** 2).mean(-1)) > _pair_target()).mean() > 0.8  # they do miss
    drop = reject_inconsistent_pairs(o, scene.cam_R, scene.cam_t, np.ones(M, bool),
                                     scene.intrinsics, np.zeros(F, bool), _pair_target())
    assert not drop[:, p].any()


def test_single_sensor_samples_no_other_camera_checked_become_gaps(scene):
    o, p = _caddy_01_point(scene, 23)
    F, M, C = scene.visible.shape
    # frames 10-13: camera 1 misses the marker, camera 0 goes on (anchored: its 2D
    # track is triangulated with camera 1 around); frames 25-29: the caddy loses it and
    # camera 3 alone has a blob 7 px from the marker's projection
    for f in range(10, 14):
        row = o["obs"][f, p]
        row[1] = np.nan
        o["obs"][f, p] = row
    for f in range(25, 30):
        row = o["obs"][f, p]
        row[:] = np.nan
        row[3] = scene.uv[f, p, 3] + [7.0, 0.0]
        o["obs"][f, p] = row
    o["recon"][10:14, p] = RECON_SINGLE_SENSOR
    o["recon"][25:30, p] = RECON_SINGLE_SENSOR
    single = o["recon"] == RECON_SINGLE_SENSOR
    lonely = unanchored_single_sensor(o, np.ones(M, bool))
    assert np.flatnonzero(lonely[:, p]).tolist() == list(range(25, 30))
    assert lonely.sum() == 5
    bad = reject_unanchored_single_sensor(o, np.ones(M, bool), np.zeros(F, bool))
    assert np.array_equal(bad, lonely)
    assert (o["recon"][25:30, p] == RECON_NONE).all()
    assert np.isnan(o["obs"][25:30, p]).all()
    # the anchored ones stay single-sensor samples
    assert (o["recon"][single & ~lonely] == RECON_SINGLE_SENSOR).all()
