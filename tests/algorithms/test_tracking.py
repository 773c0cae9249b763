"""Tracking: the pure tracker on synthetic detections derived from truth, and its commands.

Detections are the truth projections of every visible marker and brim dot plus Gaussian
noise, random clutter and random dropouts, so the tests run in seconds without images.
The rendered-image acceptance runs are in ``benchmarks/tracking.py`` and the slow tests.
"""

from __future__ import annotations

import copy
import logging
from functools import lru_cache

import numpy as np
import pytest

from carapost.algorithms.camera import project as project_points
from carapost.algorithms.codes import KIND_BRIM, SOURCE_BLOB
from carapost.algorithms.patch import patch_search
from carapost.algorithms.tracking import (
    InitialState,
    RaggedDetections,
    TrackingParameters,
    neighbour_graph,
    resect_cameras,
    track,
)
from carapost.commands.stack import CommandError, CommandStack
from carapost.model.project import RECON_SINGLE_SENSOR, RECON_TRIANGULATED, new_project
from carapost.synth import SynthConfig, build_scene


@lru_cache(maxsize=8)
def scene_of(preset: str, frames: int, seed: int = 1, markers: str = "standard", **config):
    return build_scene(SynthConfig(preset=preset, markers=markers, frames=frames, seed=seed,
                                   **config))


def synth_detections(scene, seed: int = 0, noise: float = 0.15, clutter: int = 10,
                     dropout: float = 0.01):
    """Per frame, per camera (centre, axes, truth id): id m < M face, M + b brim, -1 clutter."""
    rng = np.random.default_rng(seed)
    F, M, C = scene.visible.shape
    W, H = scene.size
    out = []
    for f in range(F):
        per = []
        for c in range(C):
            v = np.flatnonzero(scene.visible[f, :, c] & (rng.random(M) > dropout))
            b = np.flatnonzero(scene.brim_visible[f, :, c])
            cen = np.concatenate([scene.uv[f, v, c], scene.brim_uv[f, b, c],
                                  rng.random((clutter, 2)) * [W, H]])
            ids = np.concatenate([v, M + b, -np.ones(clutter, int)])
            cen = cen + rng.normal(0, noise, cen.shape)
            perm = rng.permutation(len(cen))
            per.append((cen[perm], np.full((len(cen), 2), 5.0), ids[perm]))
        out.append(per)
    return out


def run_tracker(scene, dets, *, start: int, stop: int, params=None, progress=None):
    M = len(scene.labels)
    B = len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[start], scene.brim3d])
    seen = np.r_[scene.visible[start].sum(-1) >= 2, np.ones(B, bool)]
    X0[~seen] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    axes = np.full((M + B, scene.n_cameras, 2), 5.0)  # the synthetic blobs' size
    res = track(lambda f: [(d[0], d[1]) for d in dets[f]], InitialState(X0, kind, axes=axes),
                scene.cam_R[start], scene.cam_t[start], scene.intrinsics,
                params or TrackingParameters(), start=start, stop=stop, progress=progress)
    return res, seen[:M]


def quality(scene, res, initialised):
    """Coverage of initialised markers seen by >= 2 cameras, swaps, RMSE (mm)."""
    M = len(scene.labels)
    sl = slice(res.first, res.last + 1)
    truth = scene.points3d[sl]
    pos = res.positions[:, :M].astype(np.float64)
    d = np.linalg.norm(pos - truth, axis=-1)
    seen = (scene.visible[sl].sum(-1) >= 2) & initialised[None]
    coverage = float(((d <= 2.0) & seen).sum() / seen.sum())
    # a swap: a point sitting on another marker
    diff = pos[:, :, None, :] - truth[:, None, :, :]
    dd = np.linalg.norm(diff, axis=-1)
    dd[:, np.arange(M), np.arange(M)] = np.inf
    swaps = int(np.sum(np.nanmin(dd, axis=2) <= 2.0))
    ok = np.isfinite(d)
    rmse = float(np.sqrt(np.mean(d[ok] ** 2)))
    return coverage, swaps, rmse


def test_speech_forwards_tracks_initialised_markers():
    scene = scene_of("speech", 60)
    dets = synth_detections(scene)
    res, init = run_tracker(scene, dets, start=0, stop=59)
    assert (res.first, res.last, res.frames_done, res.cancelled) == (1, 59, 59, False)
    coverage, swaps, rmse = quality(scene, res, init)
    assert coverage >= 0.97
    assert swaps == 0
    assert rmse <= 0.3
    # every blob observation is the right marker's detection
    M = len(scene.labels)
    f, p, c = np.nonzero(res.source[:, :M] == SOURCE_BLOB)
    truth_id = np.array([dets[res.first + fi][ci][2][res.detection[fi, pi, ci]]
                         for fi, pi, ci in zip(f, p, c, strict=True)])
    assert np.mean(truth_id == p) >= 0.999
    # the cameras are re-solved from the brim every frame, close to the flexing truth
    uv_est, _ = project_points(scene.brim3d, res.R, res.t, scene.intrinsics)
    uv_true, _ = project_points(scene.brim3d, scene.cam_R[1:60], scene.cam_t[1:60],
                                scene.intrinsics)
    assert np.nanmedian(np.linalg.norm(uv_est - uv_true, axis=-1)) < 0.3


def test_backwards_matches_forwards_quality():
    scene = scene_of("speech", 60)
    dets = synth_detections(scene)
    fwd, init_f = run_tracker(scene, dets, start=0, stop=59)
    bwd, init_b = run_tracker(scene, dets, start=59, stop=0)
    assert (bwd.first, bwd.last) == (0, 58)
    cf, sf, rf = quality(scene, fwd, init_f)
    cb, sb, rb = quality(scene, bwd, init_b)
    assert sb == sf == 0
    assert cb >= 0.97 and abs(cb - cf) <= 0.02
    assert rb <= 0.3


def test_cancel_keeps_tracked_frames():
    scene = scene_of("speech", 60)
    dets = synth_detections(scene)
    calls = []

    def progress(done, total):
        calls.append((done, total))
        return done < 5

    res, _ = run_tracker(scene, dets, start=30, stop=0, progress=progress)
    assert res.cancelled and res.frames_done == 5
    assert (res.first, res.last) == (25, 29)
    assert res.positions.shape[0] == 5
    assert np.isfinite(res.positions[:, 0]).all()
    assert calls[-1] == (5, 30)


def test_blink_eyelids_reacquired_and_never_wrong():
    scene = scene_of("blink", 150)
    dets = synth_detections(scene, dropout=0.0)
    res, init = run_tracker(scene, dets, start=0, stop=149)
    M = len(scene.labels)
    lids = np.flatnonzero(scene.eyelid & init)
    assert lids.size
    pos = res.positions[:, :M].astype(np.float64)
    d = np.linalg.norm(pos - scene.points3d[1:150], axis=-1)
    # never attached to a wrong detection, never placed far from the truth
    for p in lids:
        det = res.detection[:, p]
        fi, ci = np.nonzero(det >= 0)
        ids = np.array([dets[1 + f][c][2][det[f, c]] for f, c in zip(fi, ci, strict=True)])
        assert np.all(ids == p), scene.labels[p]
        assert np.nanmax(d[:, p]) <= 2.0
    # reacquired within 2 frames of reappearing in >= 2 cameras
    seen = scene.visible[1:150][:, lids].sum(-1) >= 2
    n_blinks = 0
    for j, p in enumerate(lids):
        back = np.flatnonzero(seen[1:, j] & ~seen[:-1, j]) + 1
        for k in back:
            if k + 2 < len(seen) and seen[k:k + 3, j].all():
                n_blinks += 1
                assert np.isfinite(d[k:k + 3, p]).any(), (scene.labels[p], k + 1)
    assert n_blinks >= 1


@pytest.mark.parametrize("single_sensor", [True, False])
def test_lost_point_revived_by_one_camera_only_with_single_sensor(single_sensor):
    """A marker lost in every camera that comes back in one camera only (the other
    camera of its caddy cut off by the image edge, say) is placed again by single sensor
    tracking, on its own blob, as if it had never been lost; never when that is off."""
    scene = scene_of("speech", 60)
    base = synth_detections(scene, dropout=0.0)
    # a cheek marker seen by every camera throughout: it moves with its neighbours, so
    # they predict it within the Single Sensor Tracking Threshold (the philtrum, between
    # the nose and the moving upper lip, is predicted 1-1.5 mm off while the mouth opens)
    m = list(scene.labels).index("Cheek_Hi_L")
    assert scene.visible[:, m].all()
    one_cam = range(25, 60)

    def without_marker(frames, keep_camera):
        dets = copy.deepcopy(base)
        for f in frames:
            for c in range(scene.n_cameras):
                if c != keep_camera:
                    cen, axes, ids = dets[f][c]
                    keep = ids != m
                    dets[f][c] = (cen[keep], axes[keep], ids[keep])
        return dets

    params = TrackingParameters(allow_single_sensor_tracking=single_sensor)
    # lost in every camera for frames 20-24, then seen by camera 0 only
    dets = without_marker(range(20, 25), -1)
    dets[25:] = without_marker(one_cam, 0)[25:]
    res, init = run_tracker(scene, dets, start=0, stop=59, params=params)
    assert init[m]
    rows = np.arange(res.first, res.last + 1)
    later = np.isin(rows, one_cam)
    pos = res.positions[:, m].astype(np.float64)
    placed = later & np.isfinite(pos).all(-1)
    if not single_sensor:
        assert not placed.any()
        return
    # the same take without the gap: camera 0 alone carries the point from frame 25
    control, _ = run_tracker(scene, without_marker(one_cam, 0), start=0, stop=59,
                             params=params)
    placed_control = later & np.isfinite(control.positions[:, m]).all(-1)
    assert placed_control.sum() >= 10
    assert (placed == placed_control)[later].mean() >= 0.9
    assert np.all(res.recon[placed, m] == RECON_SINGLE_SENSOR)
    err = np.linalg.norm(pos[placed] - scene.points3d[rows[placed], m], axis=-1)
    assert err.max() < 1.0
    det = res.detection[placed, m]
    assert np.all(det[:, 1:] < 0)
    ids = np.array([dets[f][0][2][d] for f, d in zip(rows[placed], det[:, 0], strict=True)])
    assert np.all(ids == m)


def test_resect_cameras_recovers_perturbed_pose(rng):
    scene = scene_of("speech", 2)
    X = scene.brim3d
    uv = np.where(scene.brim_visible[0][..., None], scene.brim_uv[0], np.nan)
    from carapost.algorithms.camera import rodrigues_to_matrix

    dR = rodrigues_to_matrix(rng.normal(0, 0.01, (4, 3)))
    R0 = dR @ scene.cam_R[0]
    t0 = scene.cam_t[0] + rng.normal(0, 1.0, (4, 3))
    R, t, solved = resect_cameras(X, uv, R0, t0, scene.intrinsics)
    assert solved.all()
    uv_fit, _ = project_points(X, R, t, scene.intrinsics)
    err = np.linalg.norm(uv_fit - scene.brim_uv[0], axis=-1)[scene.brim_visible[0]]
    assert err.max() < 0.01


def test_neighbour_graph_excludes_self_and_missing():
    X = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [np.nan, 0, 0], [5, 5, 5.0]])
    idx, w = neighbour_graph(X, 2)
    assert idx[0].tolist() == [1, 2]
    assert np.all(idx[3] == 5) and np.all(w[3] == 0)
    assert not np.any(idx == np.arange(5)[:, None])
    assert np.all(np.diff(w[0]) <= 0)


def test_patch_search_finds_shifted_patch(rng):
    img = rng.integers(0, 255, (120, 160)).astype(np.uint8)
    import cv2

    img = cv2.GaussianBlur(img, (0, 0), 2.0)
    moved = np.roll(img, (3, -5), axis=(0, 1))
    uv, score = patch_search(img, moved, (80.0, 60.0), (78.0, 62.0), 15, 10.0)
    assert score > 0.95
    assert np.allclose(uv, (75.0, 63.0), atol=0.3)
    uv, score = patch_search(img, moved, (2.0, 2.0), (2.0, 2.0), 15, 10.0)
    assert score == -1.0 and np.isnan(uv).all()


def test_parameters_validate_and_read_properties():
    from carapost.model.properties import Properties

    props = Properties()
    params = TrackingParameters.from_mapping(props.section("Tracking Parameters"))
    assert params.face_point_tracking_distance == 35.0
    assert params.max_3d_point_error == 5.0
    with pytest.raises(ValueError, match="face_point_tracking_distance"):
        TrackingParameters(face_point_tracking_distance=-1.0)
    with pytest.raises(ValueError, match="blob_size_difference_threshold"):
        TrackingParameters(blob_size_difference_threshold=2.0)


def test_blob_size_test_rejects_merged_blob():
    """A candidate twice the size of the point's last blob is not matched at 0.1."""
    scene = scene_of("speech", 3)
    dets = synth_detections(scene, clutter=0, dropout=0.0)
    M = len(scene.labels)
    p = int(np.flatnonzero(scene.visible[1].sum(-1) == 4)[0])
    for c in range(4):
        cen, ax, ids = dets[1][c]
        ax[ids == p] = 12.0
    for thr, expect in ((0.1, False), (0.75, True)):
        res, _ = run_tracker(scene, dets, start=0, stop=1,
                             params=TrackingParameters(blob_size_difference_threshold=thr))
        assert (res.detection[0, p] >= 0).any() == expect
    assert res.positions.shape[1] == M + len(scene.brim3d)



def test_camera_left_out_by_the_robust_triangulation_is_detached_without_2d_removal():
    """matching.py: a blob the robust triangulation rejects is a wrong match and is
    detached even with Remove Bad 2D Projections off (that option only adds the 2D
    reprojection-error test). Remove Bad 3D Points is off too: its wrong-blob test would
    detach this blob as well."""
    scene = scene_of("speech", 3)
    p = int(np.flatnonzero(scene.visible[1].sum(-1) == 4)[0])
    # px: the triangulation leaves it out (it keeps 3 px), yet below the 2D test's limit
    c, shift = 2, 4.5
    params = TrackingParameters(remove_bad_2d_projections=False, remove_bad_3d_points=False)
    assert shift < params.max_2d_projection_error
    for dx, attached in ((0.0, True), (shift, False)):
        dets = synth_detections(scene, clutter=0, dropout=0.0, noise=0.05)
        cen, _, ids = dets[1][c]
        cen[ids == p] += [dx, 0.0]  # the only blob near the point in camera c
        res, _ = run_tracker(scene, dets, start=0, stop=1, params=params)
        assert (res.detection[0, p, c] >= 0) == attached
        assert np.isfinite(res.obs[0, p, c]).all() == attached
        others = [k for k in range(scene.n_cameras) if k != c]
        assert (res.detection[0, p, others] >= 0).all()  # the point keeps the others
        assert res.recon[0, p] == RECON_TRIANGULATED
        # its 3D position is solved from the good cameras only
        assert np.linalg.norm(res.positions[0, p] - scene.points3d[1, p]) < 0.2

# ------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------
def synth_project(scene, dets, start: int = 0):
    """A project with the synthetic detections, brim points, and face points at ``start``."""
    F, M, C = scene.visible.shape
    B = len(scene.brim3d)
    prj = new_project(F, C, image_size=scene.size)
    prj.calibration.intrinsics = scene.intrinsics.copy()
    prj.calibration.R[start] = scene.cam_R[start]
    prj.calibration.t[start] = scene.cam_t[start]
    prj.calibration.solved[start] = True
    images = [(f, c) for f in range(F) for c in range(C)]
    tables = []
    for f, c in images:
        cen, ax, _ = dets[f][c]
        n = len(cen)
        tables.append({"centre": cen, "axes": ax, "angle": np.zeros(n), "colour":
                       np.zeros(n, np.int8), "score": np.ones(n)})
    prj.detections.replace_images(images, tables)
    init = scene.visible[start].sum(-1) >= 2
    face = np.flatnonzero(init)
    cols = prj.points.append(len(face), labels=[scene.labels[m] for m in face])
    bcols = prj.points.append(B, labels=list(scene.brim_labels), kind=KIND_BRIM)
    pts = prj.points
    pts.positions[:, bcols] = scene.brim3d.astype(np.float32)
    pts.positions[start, cols] = scene.points3d[start, face]
    pts.recon[start, cols] = RECON_TRIANGULATED
    for c in range(C):
        ids = dets[start][c][2]
        for col, m in [(cols, face), (bcols, M + np.arange(B))]:
            where = {int(v): k for k, v in enumerate(ids)}
            for j, mm in zip(col, m, strict=True):
                k = where.get(int(mm))
                if k is not None:
                    pts.detection[start, j, c] = k
                    pts.obs[start, j, c] = dets[start][c][0][k]
                    pts.source[start, j, c] = SOURCE_BLOB
    prj.set_active_range((0, F - 1))
    return prj


def snapshot(prj) -> dict:
    pts = prj.points
    return {
        "ids": pts.ids.tobytes(), "labels": list(pts.labels), "kind": pts.kind.tobytes(),
        "arrays": {k: v.tobytes() for k, v in pts.arrays.items()},
        "det": {k: v.tobytes() for k, v in prj.detections.arrays.items()},
        "offsets": prj.detections.offsets.tobytes(),
        "R": prj.calibration.R.tobytes(), "t": prj.calibration.t.tobytes(),
        "solved": prj.calibration.solved.tobytes(), "sticks": copy.deepcopy(prj.sticks),
        "label_list": list(prj.labels),
    }


def test_track_command_undo_redo_bit_identical():
    from carapost.commands.tracking import TrackCommand

    scene = scene_of("speech", 40)
    dets = synth_detections(scene)
    prj = synth_project(scene, dets)
    stack = CommandStack(prj)
    before = snapshot(prj)
    cmd = stack.push(TrackCommand(prj, 1))
    assert cmd.description.startswith("Track Forwards [Sequence]")
    after = snapshot(prj)
    assert prj.calibration.solved.all()
    assert np.isfinite(prj.points.positions[1:, 0]).all()
    assert stack.undo()
    assert snapshot(prj) == before
    assert stack.redo()
    assert snapshot(prj) == after
    assert cmd.memory() > 0


def test_track_single_frame_backwards_and_selection():
    from carapost.commands.tracking import TrackCommand

    scene = scene_of("speech", 40)
    dets = synth_detections(scene)
    prj = synth_project(scene, dets, start=20)
    prj.set_current_frame(20)
    first = int(prj.points.ids[0])
    prj.set_selection(points=[first])
    CommandStack(prj).push(TrackCommand(prj, -1, single_frame=True))
    pos = prj.points.positions
    assert np.isfinite(pos[19, 0]).all()
    assert np.isnan(pos[19, 1]).all()  # not selected: untouched
    assert np.isnan(pos[18, 0]).all()  # one frame only
    assert prj.calibration.solved[19] and not prj.calibration.solved[18]


def test_track_command_refuses_bad_input(caplog):
    from carapost.commands.tracking import TrackCommand

    scene = scene_of("speech", 40)
    dets = synth_detections(scene)
    prj = synth_project(scene, dets)
    with caplog.at_level(logging.ERROR, logger="carapost.process"):
        with pytest.raises(CommandError, match="nothing to track"):
            TrackCommand(prj, -1)
    assert "nothing to track" in caplog.text
    prj.set_current_frame(5)
    with pytest.raises(CommandError, match="no point has a 3D position"):
        TrackCommand(prj, 1)
    prj.calibration.intrinsics = None
    with pytest.raises(CommandError, match="no camera calibration"):
        TrackCommand(prj, 1)


def test_track_command_cancel_keeps_frames():
    from carapost.commands.tracking import TrackCommand

    scene = scene_of("speech", 40)
    dets = synth_detections(scene)
    prj = synth_project(scene, dets)
    cmd = TrackCommand(prj, 1, progress=lambda d, n: d < 7)
    assert cmd.computation.cancelled
    CommandStack(prj).push(cmd)
    pos = prj.points.positions[:, 0, 0]
    assert np.isfinite(pos[:8]).all() and np.isnan(pos[8:]).all()
    assert prj.calibration.solved[:8].all() and not prj.calibration.solved[8:].any()


def test_ragged_detections_serves_model_layout():
    prj = new_project(2, 2)
    prj.detections.replace_images([(1, 1)], [{
        "centre": np.array([[1.0, 2.0], [3.0, 4.0]]), "axes": np.ones((2, 2)),
        "angle": np.zeros(2), "colour": np.zeros(2, np.int8), "score": np.ones(2)}])
    src = RaggedDetections(prj.detections.offsets, prj.detections.arrays["centre"],
                           prj.detections.arrays["axes"], 2)
    frame = src(1)
    assert len(frame) == 2 and len(frame[0][0]) == 0
    assert frame[1][0].tolist() == [[1.0, 2.0], [3.0, 4.0]]


def test_patch_tracking_bridges_a_missing_blob():
    """With images, a marker whose blob is missing in one camera is patch-tracked there."""
    from carapost.model.project import SOURCE_PATCH
    from carapost.synth import render_frame

    scene = scene_of("speech", 4)
    dets = synth_detections(scene, clutter=0, dropout=0.0)
    p = int(np.flatnonzero(scene.visible[:4].sum(-1).min(0) == 4)[0])
    for f in range(1, 4):
        cen, ax, ids = dets[f][0]
        keep = ids != p
        dets[f][0] = (cen[keep], ax[keep], ids[keep])
    M, B = len(scene.labels), len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    obs0 = np.concatenate([scene.uv[0], scene.brim_uv[0]])
    res = track(lambda f: [(d[0], d[1]) for d in dets[f]], InitialState(X0, kind, obs0),
                scene.cam_R[0], scene.cam_t[0], scene.intrinsics, start=0, stop=3,
                get_image=lambda f, c: render_frame(scene, f, c))
    assert np.all(res.source[:, p, 0] == SOURCE_PATCH)
    err = np.linalg.norm(res.obs[:, p, 0] - scene.uv[1:4, p, 0], axis=-1)
    assert err.max() < 1.0
    assert np.all(res.quality[:, p, 0] >= 0.8)


# ------------------------------------------------------------------------------------------
# Whole-take tracking with markers found on the way
# ------------------------------------------------------------------------------------------
def take_quality(scene, positions):
    """Evaluate-style coverage, swaps, RMSE (mm), spurious points over every marker seen
    by >= 2 cameras."""
    from carapost.synth.scoring import track_quality

    return track_quality(scene.points3d, scene.visible, positions)


def test_track_take_finds_markers_initialisation_missed():
    """Initialised with only the markers four cameras see at frame 0, the take tracker
    finds the rest and carries them back to frame 0 without doubles or swaps."""
    from carapost.algorithms.tracking import make_spawner, track_take

    scene = scene_of("speech", 60)
    dets = synth_detections(scene, noise=0.05)
    M, B = len(scene.labels), len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    four = scene.visible[0].sum(-1) == 4
    X0[:M][~four] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    axes = np.full((M + B, 4, 2), 5.0)
    res = track_take(lambda f: [(d[0], d[1]) for d in dets[f]], InitialState(X0, kind,
                     axes=axes), scene.cam_R[0], scene.cam_t[0], scene.intrinsics,
                     start=0, n_frames=60,
                     spawn=make_spawner(scene.intrinsics, ((0, 1), (2, 3)),
                                        brim_model=scene.brim3d))
    assert (res.first, res.last) == (0, 59)
    assert res.n_new >= (~four & (scene.visible[0].sum(-1) >= 2)).sum() // 2
    pos = np.concatenate([res.positions[:, :M], res.positions[:, M + B:]], axis=1)
    coverage, swaps, rmse, spurious = take_quality(scene, pos)
    only_init, _, _, _ = take_quality(scene, res.positions[:, :M])
    assert coverage >= 0.98 and coverage > only_init + 0.05
    assert swaps == 0 and spurious == 0
    assert rmse <= 0.3


def test_track_take_command_appends_points_undo_redo():
    from carapost.commands.tracking import TrackTakeCommand

    scene = scene_of("speech", 30)
    dets = synth_detections(scene)
    prj = synth_project(scene, dets)
    # forget a few initialised markers: the command must find them again
    face = np.flatnonzero(prj.points.kind != KIND_BRIM)
    prj.points.positions[0, face[:5]] = np.nan
    prj.points.detection[0, face[:5]] = -1
    prj.points.obs[0, face[:5]] = np.nan
    stack = CommandStack(prj)
    before = snapshot(prj)
    n_before = prj.points.count
    cmd = stack.push(TrackTakeCommand(prj, 0))
    assert prj.points.count == n_before + cmd.computation.result.n_new
    assert cmd.computation.result.n_new >= 3
    assert prj.calibration.solved.all()
    after = snapshot(prj)
    assert stack.undo()
    assert snapshot(prj) == before
    assert stack.redo()
    assert snapshot(prj) == after


def test_hop_segments_flags_only_the_frames_on_another_marker(rng):
    """A track that jumps to the neighbouring marker for a while (and back) is split
    there; clean tracks with gaps and noise are not."""
    from carapost.algorithms.tracking import hop_segments

    scene = scene_of("speech", 60)
    X = scene.points3d.copy()
    X += rng.normal(0, 0.1, X.shape)
    X[rng.random(X.shape[:2]) < 0.1] = np.nan  # gaps
    nb, w = neighbour_graph(scene.points3d[0], 12)
    p = 30
    q = int(np.argsort(np.linalg.norm(scene.points3d[0] - scene.points3d[0, p], axis=-1))[1])
    X[20:31, p] = scene.points3d[20:31, q]
    spacing = float(np.median(np.sort(np.linalg.norm(
        scene.points3d[0][:, None] - scene.points3d[0][None], axis=-1), axis=1)[:, 1]))
    group = hop_segments(X, nb, w, 0.5 * spacing)
    seen = np.isfinite(X[..., 0])
    assert np.all(group[~seen] == -1)
    wrong = np.zeros(seen.shape, bool)
    wrong[20:31, p] = True
    assert np.all(group[wrong & seen] > 0)
    assert np.all(group[~wrong & seen] == 0)


def _take_run(preset, frames, start, initialised=None):
    from carapost.algorithms.tracking import make_spawner, track_take

    scene = scene_of(preset, frames)
    dets = synth_detections(scene, noise=0.05)
    M, B = len(scene.labels), len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[start], scene.brim3d])
    keep = scene.visible[start].sum(-1) >= (2 if initialised is None else initialised)
    X0[:M][~keep] = np.nan
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    res = track_take(lambda f: [(d[0], d[1]) for d in dets[f]],
                     InitialState(X0, kind, axes=np.full((M + B, 4, 2), 5.0)),
                     scene.cam_R[start], scene.cam_t[start], scene.intrinsics, start=start,
                     n_frames=frames, spawn=make_spawner(scene.intrinsics, ((0, 1), (2, 3)),
                                                         brim_model=scene.brim3d))
    assert (res.first, res.last) == (0, frames - 1)
    pos = np.concatenate([res.positions[:, :M], res.positions[:, M + B:]], axis=1)
    return scene, take_quality(scene, pos)


def test_track_take_from_the_last_frame_is_as_good_as_forwards():
    """Started at the last frame, the take tracker goes backwards finding markers, then
    forwards over the whole take guided by that pass (no unmerged doubles)."""
    _, (coverage, swaps, rmse, spurious) = _take_run("speech", 60, 59)
    assert coverage >= 0.99
    assert swaps == 0 and spurious == 0
    assert rmse <= 0.2


def test_track_take_fast_motion_without_swaps():
    """Fast speech (jaw and chin up to ~48 px per frame): no point ends on another marker."""
    _, (coverage, swaps, rmse, spurious) = _take_run("fast", 40, 0)
    assert swaps == 0
    assert coverage >= 0.98
    assert rmse <= 0.3  # round 2: 0.75 mm and one spurious point on this take
    assert spurious == 0


@pytest.mark.slow
@pytest.mark.parametrize("preset, start, min_coverage",
                         [("fast", 0, 0.97), ("speech", 599, 0.99)])
def test_track_take_600_frames_acceptance(preset, start, min_coverage):
    """The issue's acceptance runs on truth-derived detections: fast preset forwards
    (coverage >= 0.97, 0 swaps) and speech initialised at its last frame (as good as
    forwards: >= 0.99). Round 2 on these detections: fast 0.80 coverage, 208 swaps, 63
    spurious points; backwards 0.987."""
    _, (coverage, swaps, rmse, spurious) = _take_run(preset, 600, start)
    assert coverage >= min_coverage
    assert swaps == 0 and spurious == 0
    assert rmse <= 0.2


def test_elastic_passes_parameter_is_validated():
    assert TrackingParameters().elastic_passes == 5
    with pytest.raises(ValueError, match="elastic_passes"):
        TrackingParameters(elastic_passes=0)
    assert TrackingParameters().consensus_radius_factor == 2.0
    with pytest.raises(ValueError, match="consensus_radius_factor"):
        TrackingParameters(consensus_radius_factor=0.5)


def test_region_moving_further_than_the_search_radius_keeps_identities():
    """Fast speech filmed at 30 frames/s: the jaw opens or closes by more than Face Point
    Tracking Distance (and more than the 32 px marker spacing) between two frames while
    the bottom row of chin markers hides and reappears. The wide region vote of the
    anchor pass matches the region around the displacement its markers agree on; limited
    to the plain radius, the chin markers slip onto their neighbours' blobs (3 swaps and
    RMSE 0.51 mm on this take; the round-2 tracker: 0.90 coverage, 2 swaps, RMSE 2.7 mm
    on a take like it)."""
    scene = scene_of("fast", 40, seed=2, fps=30.0)
    dets = synth_detections(scene)
    start, stop = 10, 39
    params = TrackingParameters()
    # the scenario: markers seen in both frames move further than the search radius
    uv, vis = scene.uv[start:stop + 1], scene.visible[start:stop + 1]
    step = np.linalg.norm(np.diff(uv, axis=0), axis=-1)
    assert step[vis[1:] & vis[:-1]].max() > params.face_point_tracking_distance + 5.0
    res, init = run_tracker(scene, dets, start=start, stop=stop, params=params)
    coverage, swaps, rmse = quality(scene, res, init)
    assert swaps == 0
    assert coverage >= 0.98
    assert rmse <= 0.33  # noise alone gives ~0.29 mm; one wrong blob pair far more
    narrow = TrackingParameters(consensus_radius_factor=1.0)
    res1, _ = run_tracker(scene, dets, start=start, stop=stop, params=narrow)
    assert quality(scene, res1, init)[1] > 0


def test_markers_on_the_edge_of_the_set_are_picked_up_again():
    """Markers on the edge of the set (jaw line, temples) have only far neighbours;
    after a dropout they must be picked up again, not lost for the rest of the take
    (round 2: Jaw_Lo_R tracked in 47 % of the frames of this take)."""
    scene = scene_of("speech", 120)
    dets = synth_detections(scene)
    res, init = run_tracker(scene, dets, start=0, stop=119)
    M = len(scene.labels)
    d = np.linalg.norm(res.positions[:, :M] - scene.points3d[1:120], axis=-1)
    seen = (scene.visible[1:120].sum(-1) >= 2) & init[None]
    per_marker = ((d <= 2.0) & seen).sum(0)[init] / np.maximum(seen.sum(0)[init], 1)
    assert per_marker.min() >= 0.9, scene.labels[np.flatnonzero(init)[per_marker.argmin()]]


def test_robust_mean_leaves_out_a_neighbour_on_a_wrong_blob():
    """A neighbour solved from a wrong blob pair moves tens of mm; it must not drag the
    3D prediction, while ordinary differences between neighbours are averaged."""
    from carapost.algorithms.tracking.neighbours import robust_mean

    moves = np.array([[[0.0, -5.0, -7.0], [0.0, -6.5, -7.0], [0.0, -7.0, -5.0],
                       [27.0, -4.0, 29.0], [0.0, -2.0, -1.0]]])
    valid = np.ones((1, 5), bool)
    w = np.array([[0.4, 0.3, 0.25, 0.3, 0.1]])
    mean, support = robust_mean(moves, valid, w, gate=10.0)
    keep = [0, 1, 2, 4]
    expect = (w[0, keep, None] * moves[0, keep]).sum(0) / w[0, keep].sum()
    assert np.allclose(mean[0], expect)
    assert support[0] == pytest.approx(w[0, keep].sum())
    # two neighbours only: no median to judge by, both are used
    valid2 = np.zeros((1, 5), bool)
    valid2[0, [0, 3]] = True
    mean2, support2 = robust_mean(moves, valid2, w, gate=10.0)
    assert support2[0] == pytest.approx(0.7)
    assert np.allclose(mean2[0], (0.4 * moves[0, 0] + 0.3 * moves[0, 3]) / 0.7)


def test_shadows_flags_lost_points_drifted_onto_tracked_markers():
    """A lost point whose carried estimate sits on a tracked marker is a shadow; a lost
    point in its own place, a tracked point and a brim point are not."""
    from carapost.algorithms.tracking.neighbours import marker_spacing, shadows

    X = scene_of("speech", 1).points3d[0].copy()
    M = len(X)
    spacing = marker_spacing(X)
    lost = np.zeros(M, bool)
    lost[[3, 7]] = True
    X[3] = X[10] + [0.0, 0.2 * spacing, 0.0]  # drifted onto marker 10
    face = np.ones(M, bool)
    out = shadows(X, lost, ~lost, face, spacing)
    assert out.tolist() == [i == 3 for i in range(M)]
    face[3] = False  # not a face point (brim): never a shadow
    assert not shadows(X, lost, ~lost, face, spacing).any()
    # nothing tracked to lie on
    assert not shadows(X, lost, np.zeros(M, bool), np.ones(M, bool), spacing).any()


def test_blocked_point_takes_no_blob_but_keeps_a_carried_estimate():
    """match_frame(blocked=...) leaves the blocked point's blobs to the others while its
    neighbour-carried prediction is still formed."""
    from carapost.algorithms.tracking import FrameMatcher, pack_detections

    scene = scene_of("speech", 2)
    dets = synth_detections(scene, clutter=0, dropout=0.0)
    M, B = len(scene.labels), len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
    matcher = FrameMatcher(scene.intrinsics, kind, X0, TrackingParameters())
    fr = pack_detections([(d[0], d[1]) for d in dets[1]], 4)
    axes = np.full((M + B, 4, 2), 5.0)
    p = int(np.flatnonzero(scene.visible[1].sum(-1) == 4)[0])
    free = matcher.match_frame(fr, X0, scene.cam_R[0], scene.cam_t[0], axes)
    assert (free["detection"][p] >= 0).all()
    blocked = np.zeros(M + B, bool)
    blocked[p] = True
    res = matcher.match_frame(fr, X0, scene.cam_R[0], scene.cam_t[0], axes, blocked=blocked)
    assert (res["detection"][p] == -1).all()
    assert np.isnan(res["positions"][p]).all()
    assert np.linalg.norm(res["X_elastic"][p] - scene.points3d[1, p]) < 1.0
    # nobody else took the blocked point's blobs, and no other point changed blob; a
    # neighbour may lose a camera (the blocked point no longer helps to predict it: here
    # Forehead_C_Lo loses one of four), but not many
    others = np.arange(M + B) != p
    a, b = res["detection"][others], free["detection"][others]
    assert np.all((a == b) | (a == -1))
    assert ((a == -1) & (b >= 0)).sum() <= 2
    for c in range(4):
        taken = res["detection"][others, c]
        assert not np.isin(free["detection"][p, c], taken)


def test_track_take_with_images_detects_frames_without_detections_and_undoes():
    """Track Take given the images detects the frames that have no detections (step 5 of
    the guide's tracking), stores what it found with the points that use it, as one
    undoable step."""
    from carapost.commands.tracking import TrackTakeCommand
    from carapost.synth import render_frame

    scene = scene_of("speech", 16)
    prj = synth_project(scene, synth_detections(scene, clutter=0, dropout=0.0))
    empty = {"centre": np.zeros((0, 2)), "axes": np.zeros((0, 2)), "angle": np.zeros(0),
             "colour": np.zeros(0, np.int8), "score": np.zeros(0)}
    blank = [(f, c) for f in range(8, 11) for c in range(scene.n_cameras)]
    prj.detections.replace_images(blank, [empty] * len(blank))
    stack = CommandStack(prj)
    before = snapshot(prj)
    stack.push(TrackTakeCommand(prj, 0, get_image=lambda f, c: render_frame(scene, f, c)))
    counts = prj.detections.counts()
    assert (counts[8:11] > 20).all()
    pts = prj.points
    for f in range(8, 11):
        used = np.argwhere(pts.detection[f] >= 0)
        assert len(used) > 100
        for p, c in used:  # every observation is the centre of the stored detection it names
            cen = prj.detections.centres(f, int(c))[pts.detection[f, p, c]]
            np.testing.assert_allclose(pts.obs[f, p, c], cen, atol=1e-3)
    face = np.flatnonzero(pts.kind != KIND_BRIM)
    assert np.isfinite(pts.positions[8:11, face, 0]).mean() > 0.9
    stack.undo()
    assert snapshot(prj) == before


@pytest.mark.parametrize("shift", [(2.5, 0.0), (0.0, 2.5)])
def test_biased_blob_of_a_resuming_camera_does_not_move_a_one_camera_point(shift):
    """A marker carried by one camera (single sensor) whose second camera comes back with
    a blob 2.5 px off (a marker merged with a shadow) must not be solved from that blob:
    the two-camera point would sit millimetres deep and keep that depth afterwards."""
    scene = scene_of("speech", 40)
    dets = copy.deepcopy(synth_detections(scene, dropout=0.0))
    # a brow marker: it moves with its neighbours, so they predict it well
    brow = [i for i, lab in enumerate(scene.labels) if lab.startswith("Brow_Mid")]
    m = next(i for i in brow if scene.visible[:, i, :2].all())
    for f in range(10, 40):
        for c in (1, 2, 3):
            cen, axes, ids = dets[f][c]
            if f == 20 and c == 1:  # camera 1 sees it again for one frame, biased
                cen = np.where((ids == m)[:, None], cen + np.asarray(shift), cen)
                dets[f][c] = (cen, axes, ids)
                continue
            keep = ids != m
            dets[f][c] = (cen[keep], axes[keep], ids[keep])
    res, init = run_tracker(scene, dets, start=0, stop=39)
    assert init[m]
    rows = np.arange(res.first, res.last + 1)
    pos = res.positions[:, m].astype(np.float64)
    later = rows >= 20
    err = np.linalg.norm(pos[later] - scene.points3d[rows[later], m], axis=-1)
    assert np.isfinite(err).mean() > 0.8
    assert np.nanmax(err) < 1.0


def test_stitch_takes_the_found_piece_over_a_ghost_of_the_earlier_point():
    # A marker lost at frame 25 is found again as a new point from frame 30 to 87; the
    # lost point was revived meanwhile on a ghost 8 mm off (frames 40-60) and later back
    # on its marker (90-119). The two pieces disagree where both exist, but the found
    # piece keeps to the marker: it replaces the ghost and the marker is one point.
    from carapost.algorithms.codes import (
        KIND_FACE,
        POINT_FILLS,
        RECON_TRIANGULATED,
        blank_point_array,
    )
    from carapost.algorithms.tracking.identity import stitch

    rng = np.random.default_rng(3)
    F, C = 120, 4
    gx, gy = np.meshgrid(np.arange(5) * 10.0, np.arange(5) * 10.0)
    grid = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(25)])
    marker = 12  # the centre of the grid
    t = np.arange(F)[:, None]
    motion = np.stack([2.0 * np.sin(t / 15.0), 1.5 * np.cos(t / 20.0), 0.5 * t / F], -1)
    truth = grid[None] + motion + rng.normal(0, 0.02, (F, 25, 3))
    n = 25 + 1  # the last column: the piece found at frame 30
    A = {k: blank_point_array(k, F, n, C) for k in POINT_FILLS}
    X = truth.copy()
    X[26:40, marker] = np.nan
    X[40:61, marker] = truth[40:61, marker] + [8.0, 0.0, 0.0]  # the ghost
    X[61:90, marker] = np.nan
    found = np.full((F, 3), np.nan)
    found[30:88] = truth[30:88, marker]
    A["positions"][:] = np.concatenate([X, found[:, None]], axis=1)
    A["recon"][:] = np.where(np.isfinite(A["positions"][..., 0]), RECON_TRIANGULATED, 0)
    kind = np.full(n, KIND_FACE, np.int8)
    keep = np.ones(n, bool)
    stitch(A, kind, keep, 25, 1.0)
    assert not keep[25]
    got = A["positions"][:, marker].astype(np.float64)
    err = np.linalg.norm(got - truth[:, marker], axis=-1)
    on = np.isfinite(err)
    assert on[:26].all() and on[30:88].all() and on[90:].all()
    assert err[on].max() < 0.2  # the ghost is gone
