"""Brim dots seen at an angle: the offset of their image centroids, the dots' normals and
radii estimated from the take, and the cameras solved again without the offsets.

The reference for every offset is independent of the closed form under test: the disc's
rim sampled at 64 points, projected through the full camera model (lens distortion
included) and the area centroid of the polygon (`carapost.synth.blob_eval`, which scores
the blob detector against the renderer)."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.brim_discs import (
    brim_dot_normals,
    disc_image_offsets,
    disc_semi_axes,
    estimate_dot_radius,
    unbias_brim_cameras,
)
from carapost.algorithms.camera import camera_centres, pixels_to_normalised, project
from carapost.algorithms.pose import refine_poses
from carapost.synth import rig
from carapost.synth.blob_eval import projected_ellipses

RADIUS = 2.5


def _rig(frames: int = 1, flex_mm: float = 0.0, seed: int = 0):
    """The synthetic rig (4 cameras, lens distortion) and its brim, with per-frame flex."""
    intr, R0, t0 = rig.rig_cameras(4, (1280, 720))
    X, _ = rig.brim_model()
    N = rig.brim_normal(X)
    rng = np.random.default_rng(seed)
    R = np.broadcast_to(R0, (frames, 4, 3, 3)).copy()
    t = np.broadcast_to(t0, (frames, 4, 3)).copy() + rng.normal(0, flex_mm, (frames, 4, 3))
    return intr, X, N, R, t


def _rim_centroids(X, N, radius, R, t, intr):
    """(F, B, C, 2) area centroids of the rim polygons, and (F, B, C, 2) semi-axes."""
    F, C = R.shape[:2]
    cen = np.full((F, len(X), C, 2), np.nan)
    axes = np.full_like(cen, np.nan)
    for f in range(F):
        for c in range(C):
            a, m, ok = projected_ellipses(X, N, np.broadcast_to(radius, len(X)), R[f, c],
                                          t[f, c], intr.subset([c]))
            cen[f, ok, c] = m[ok]
            axes[f, ok, c] = a[ok]
    return cen, axes


def test_offsets_match_the_projected_rim_polygon():
    intr, X, N, R, t = _rig(frames=3, flex_mm=2.0)
    cen, _ = _rim_centroids(X, N, RADIUS, R, t, intr)
    uv, _ = project(X, R, t, intr)
    ref = cen - uv
    off = disc_image_offsets(X, N, RADIUS, R, t, intr)
    seen = np.isfinite(ref).all(-1)
    assert seen.sum() > 100
    # the offsets are tenths of a pixel at most, and the closed form gives them to a few
    # thousandths (the 64-point polygon and the distortion across a dot are the rest)
    assert 0.02 < np.median(np.linalg.norm(ref[seen], axis=-1)) < 0.2
    assert np.abs(off - ref)[seen].max() < 0.004
    # a disc facing the camera has none; the offset grows with the radius squared
    facing = -np.einsum("ij,bj->bi", R[0, 0].T, np.tile([0.0, 0.0, 1.0], (len(X), 1)))
    flat = disc_image_offsets(X, facing, RADIUS, R[:1, :1], t[:1, :1], intr.subset([0]))
    assert np.abs(flat).max() < 1e-3 * np.abs(off[:1, :, :1]).max() + 1e-9
    half = disc_image_offsets(X, N, RADIUS / 2, R, t, intr)
    assert np.allclose(half[seen], off[seen] / 4, atol=2e-4)


def test_semi_axes_match_the_projected_rim_polygon():
    intr, X, N, R, t = _rig(frames=2, flex_mm=2.0)
    _, ref = _rim_centroids(X, N, RADIUS, R, t, intr)
    axes = disc_semi_axes(X, N, R, t, intr, RADIUS)
    seen = np.isfinite(ref).all(-1)
    # the polygon is slightly inside the circle, and distortion is left out: within 1.5 %
    assert np.abs(axes[seen] / ref[seen] - 1).max() < 0.015


def test_normals_of_a_flat_and_of_a_curved_brim():
    # a flat sheet (a custom SVG brim): exact, and towards the cameras
    rng = np.random.default_rng(1)
    flat = np.c_[rng.uniform(-60, 60, 14), rng.uniform(-10, 10, 14), np.zeros(14)]
    n = brim_dot_normals(flat, [0.0, -50.0, -200.0])
    assert np.allclose(n, [0.0, 0.0, -1.0], atol=1e-9)
    # the synthetic rig's conical band, several layouts: within 2.5 deg of the truth
    intr, _, _, R, t = _rig()
    towards = camera_centres(R[0], t[0]).mean(0)
    for seed in (None, 3, 7, 11):
        X, _ = rig.brim_model(None if seed is None else np.random.default_rng(seed))
        est = brim_dot_normals(X, towards)
        err = np.degrees(np.arccos(np.clip((est * rig.brim_normal(X)).sum(1), -1, 1)))
        assert err.max() < 2.5, (seed, err.max())
    # too few dots, or all on a line: no normals (nothing is corrected with them)
    assert np.isnan(brim_dot_normals(flat[:2], [0, 0, -1.0])).all()
    line = np.c_[np.linspace(0, 50, 6), np.zeros(6), np.zeros(6)]
    assert np.isnan(brim_dot_normals(line, [0, 0, -1.0])).all()


def test_radius_from_the_blobs_semi_major_axes():
    intr, X, N, R, t = _rig(frames=12, flex_mm=1.0)
    _, axes = _rim_centroids(X, N, RADIUS, R, t, intr)
    major = axes[..., 0] * 1.01  # the detector's blobs are ~1 % wider (blur)
    major[:, 0, :] *= 0.8 / 1.01  # a smaller dot
    major[2:, 1, :] = np.nan  # a dot with two blobs, too few for a radius of its own
    major[:2, 1, 1:] = np.nan
    r = estimate_dot_radius(X, N, major, R, t, intr)
    assert r[0] == pytest.approx(0.8 * RADIUS, rel=0.01)
    assert np.allclose(r[2:], RADIUS, rtol=0.02)
    # it takes the median of every blob's (mostly the other dots')
    assert r[1] == pytest.approx(1.01 * RADIUS, rel=0.01) and r[1] != r[2]
    assert np.isnan(estimate_dot_radius(X, N, np.full_like(major, np.nan), R, t, intr)).all()


def _resect(X, obs, R, t, intr):
    """Tracking's per-frame resection of every frame (the biased starting point)."""
    Rs, ts = R.copy(), t.copy()
    for f in range(len(R)):
        xn = np.swapaxes(pixels_to_normalised(obs[f], intr), 0, 1)
        out = refine_poses(X, xn, R[f], t[f], scale=intr.focal, iterations=6, huber_px=None,
                           min_points=6, linearise="camera")
        Rs[f], ts[f] = out.R, out.t
    return Rs, ts


def test_cameras_solved_without_the_offsets_see_the_face_where_the_truth_does():
    """Blob centroids at the discs' true image centroids (plus noise): the cameras
    resected from them are off by the offsets; re-solved without them, the face points'
    projections agree with the true cameras' several times better."""
    F = 20
    intr, X, N, R, t = _rig(frames=F, flex_mm=1.5, seed=2)
    cen, axes = _rim_centroids(X, N, RADIUS, R, t, intr)
    rng = np.random.default_rng(3)
    obs = cen + rng.normal(0, 0.01, cen.shape)
    R0, t0 = _resect(X, obs, R, t, intr)
    keep = np.zeros(F, bool)
    keep[5] = True
    out = unbias_brim_cameras(X, obs, axes[..., 0], R0, t0, intr, keep=keep)
    assert out is not None
    assert np.allclose(out.radius, RADIUS, rtol=0.02)
    face = np.c_[rng.uniform(-40, 40, 30), rng.uniform(-60, 30, 30), rng.uniform(80, 100, 30)]
    truth = project(face, R, t, intr)[0]

    def err(Rc, tc):
        d = project(face, Rc, tc, intr)[0] - truth
        return np.sqrt(np.nanmean((d ** 2).sum(-1), axis=(1, 2)))  # (F,) px

    before, after = err(R0, t0), err(out.R, out.t)
    free = ~keep
    assert np.median(before[free]) > 0.02
    assert np.median(after[free]) < np.median(before[free]) / 3
    # the kept frame keeps its pose; the corrected observations are the true centres'
    assert np.array_equal(out.R[5], R0[5]) and np.array_equal(out.t[5], t0[5])
    uv = project(X, R, t, intr)[0]
    seen = np.isfinite(obs).all(-1)
    assert (np.abs(out.obs - uv)[seen].mean()
            < 0.5 * np.abs(obs - uv)[seen].mean())
    # without blob axes there is no radius, so nothing is corrected
    assert unbias_brim_cameras(X, obs, np.full(obs.shape[:3], np.nan), R0, t0, intr) is None


def test_track_take_solves_the_cameras_without_the_offsets():
    """Track Take on detections whose brim centroids are the dots' true image centroids
    (as the detector gives them): with the correction the cameras it returns project the
    face where the true cameras do several times better than without it."""
    from carapost.algorithms.codes import KIND_BRIM
    from carapost.algorithms.tracking import InitialState, TrackingParameters, track_take
    from carapost.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig(preset="speech", frames=24, seed=2, size=(1280, 720)))
    intr = scene.intrinsics
    F, M, C = scene.visible.shape
    rng = np.random.default_rng(1)
    cen, axes = _rim_centroids(scene.brim3d, scene.brim_normals, scene.brim_radius_mm,
                               scene.cam_R, scene.cam_t, intr)
    dets = []
    for f in range(F):
        per = []
        for c in range(C):
            v = scene.visible[f, :, c]
            bv = scene.brim_visible[f, :, c] & np.isfinite(cen[f, :, c, 0])
            xy = np.concatenate([scene.uv[f, v, c] + rng.normal(0, 0.03, (v.sum(), 2)),
                                 cen[f, bv, c] + rng.normal(0, 0.01, (bv.sum(), 2))])
            ax = np.concatenate([np.full((v.sum(), 2), 5.0), axes[f, bv, c]])
            per.append((xy, ax))
        dets.append(per)
    B = len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    X0[:M][scene.visible[0].sum(-1) < 2] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    truth = project(scene.points3d, scene.cam_R, scene.cam_t, intr)[0]

    def camera_error(on):
        res = track_take(dets.__getitem__, InitialState(X0, kind), scene.cam_R[0],
                         scene.cam_t[0], intr, TrackingParameters(brim_dot_offsets=on),
                         start=0, n_frames=F)
        d = project(scene.points3d, res.R, res.t, intr)[0] - truth
        return np.sqrt(np.nanmean((d[1:] ** 2).sum(-1)))  # px, the frames re-solved

    without, with_ = camera_error(False), camera_error(True)
    assert without > 0.02
    assert with_ < without / 2.5, (without, with_)
