"""The Target Tracker's Session actions on a rendered synthetic take with truth.

Each action: its effect on the model against the truth, one History entry, undo
bit-identical, redo equal to the first do; bad input refused with a message and
nothing changed.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from carapost import Session
from carapost.algorithms.codes import (
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
    SOURCE_KEYFRAME,
    SOURCE_TARGET,
)
from carapost.commands.stack import CommandError
from carapost.synth.demo_project import scene_project
from tests.commands.test_edit_commands import snapshot

FRAMES = 30


@pytest.fixture(scope="module")
def take():
    project, scene, get = scene_project(frames=FRAMES, size=(640, 360), preset="speech",
                                        seed=3)
    return project, scene, functools.lru_cache(maxsize=None)(get)


@pytest.fixture(scope="module")
def fast_take():
    """The fast preset: lip markers move up to 30 px between frames (about 500 mm/s)."""
    project, scene, get = scene_project(frames=FRAMES, size=(640, 360), preset="fast",
                                        seed=3)
    return project, scene, functools.lru_cache(maxsize=None)(get)


@pytest.fixture
def session(take):
    import copy

    project, scene, get = take
    return Session(copy.deepcopy(project), get_image=get), scene


def _marker(scene, label="Cheek_L"):
    return list(scene.labels).index(label)


def _from_truth(s: Session, scene, m: int) -> int:
    """Give marker ``m``'s point (column ``m`` in scene_project) its exact 2D and 3D."""
    pts = s.project.points
    vis = scene.visible[:, m]
    pts.obs[:, m] = np.where(vis[..., None], scene.uv[:, m], np.nan)
    pts.source[:, m] = np.where(vis, 1, 0)
    pts.keyframe[:, m] = False
    pts.positions[:, m] = scene.points3d[:, m]
    pts.recon[:, m] = RECON_TRIANGULATED
    return m


def _too_big(s: Session) -> None:
    """A pattern larger than the image: cameras of a smaller sensor size."""
    import dataclasses

    cams = s.project.take.cameras
    s.project.take.cameras = [dataclasses.replace(c, image_size=(640, 250)) for c in cams]
    try:
        s.target_track(+1, pattern_size=255, search_size=255, overwrite_existing_tracks=True)
    finally:
        s.project.take.cameras = cams


def _undo_redo(s: Session, before: dict) -> None:
    after = snapshot(s.project)
    assert after != before
    assert s.undo() and snapshot(s.project) == before
    assert s.redo() and snapshot(s.project) == after


def test_create_and_track_a_new_target_tracked_point(session):
    s, scene = session
    m = _marker(scene)
    s.current_frame = 0
    before = snapshot(s.project)
    with s.group("New Target Track"):
        s.add_target_track(0, 0, scene.uv[0, m, 0])
        (pid,) = s.project.selection.points
        s.edit_target_track(pid, 1, 0, scene.uv[0, m, 1])
    pts = s.project.points
    col = int(pts.index_of([pid])[0])
    assert pts.keyframe[0, col, :2].all() and (pts.source[0, col, :2] == SOURCE_KEYFRAME).all()
    assert pts.recon[0, col] == RECON_TRIANGULATED
    tracked_before = snapshot(s.project)
    s.target_track(+1)
    assert [h.description for h in s.history()] == [
        "New Target Track", "Track Forward [frame 0, 1 point]"]
    obs = pts.obs[1:, col, :2]
    err = np.linalg.norm(obs - scene.uv[1:, m, :2], axis=-1)
    assert err.max() < 0.2
    assert (pts.source[1:, col, :2] == SOURCE_TARGET).all()
    assert (pts.quality[1:, col, :2] > 0.9).all() and not pts.keyframe[1:, col].any()
    assert np.isnan(pts.obs[:, col, 2:]).all()          # other cameras untouched
    e3 = np.linalg.norm(pts.positions[:, col] - scene.points3d[:, m], axis=-1)
    assert np.sqrt(np.mean(e3 ** 2)) < 0.2               # mm
    assert (pts.recon[:, col] == RECON_TRIANGULATED).all()
    _undo_redo(s, tracked_before)
    assert s.undo() and s.undo() and snapshot(s.project) == before


def test_fill_a_gap_between_two_keyframes_tracking_backwards(session):
    s, scene = session
    m = _marker(scene, "Nasolabial_L")
    pts = s.project.points
    col = _from_truth(s, scene, m)
    cams = np.flatnonzero(np.isfinite(pts.obs[9, col, :, 0]) &
                          np.isfinite(pts.obs[21, col, :, 0]))
    assert len(cams) >= 2
    # a gap of 11 frames: no 2D, no 3D (as the automatic tracker leaves it)
    for name in ("obs", "positions", "residual"):
        pts.arrays[name][10:21, col] = np.nan
    pts.source[10:21, col] = 0
    pts.detection[10:21, col] = -1
    pts.recon[10:21, col] = 0
    s.select(points=[int(pts.ids[col])])
    s.gaps_to_keys()
    assert pts.keyframe[[9, 21], col][:, cams].all()
    before = snapshot(s.project)
    s.current_frame = 21
    s.target_track("backwards")
    obs = pts.obs[10:21, col][:, cams]
    err = np.linalg.norm(obs - scene.uv[10:21, m][:, cams], axis=-1)
    assert np.isfinite(err).all() and err.max() < 0.3
    assert (pts.source[10:21, col][:, cams] == SOURCE_TARGET).all()
    assert np.isfinite(pts.positions[10:21, col]).all()
    # Stop On Next Keyframe: the keyframe at 9 is kept as it was
    assert pts.keyframe[9, col][cams].all() and (pts.source[9, col][cams] == SOURCE_KEYFRAME).all()
    _undo_redo(s, before)


def test_frame_by_frame_with_a_keyframe_added_at_the_failure(session):
    s, scene = session
    m = _marker(scene, "Cheek_R")
    pts = s.project.points
    col = _from_truth(s, scene, m)
    s.select(points=[int(pts.ids[col])])
    s.set_property("Target Tracker", "tracker_overwrite_existing_tracks", True)
    s.current_frame = 5
    n0 = len(s.history())
    for f in range(5, 8):
        s.current_frame = f
        s.target_track(+1, single_frame=True)
    assert len(s.history()) == n0 + 3
    cams = np.flatnonzero(pts.keyframe[5, col])          # auto-keyed at the start
    assert len(cams) >= 2 and (pts.source[6:9, col][:, cams] == SOURCE_TARGET).all()
    s.current_frame = 8
    before = snapshot(s.project)
    s.add_keyframe()
    assert pts.keyframe[8, col][cams].all()
    _undo_redo(s, before)
    s.target_track(+1, single_frame=True)
    err = np.linalg.norm(pts.obs[9, col][cams] - scene.uv[9, m][cams], axis=-1)
    assert err.max() < 0.2


def test_single_sensor_tracking_keeps_the_point_on_its_ray(session):
    s, scene = session
    m = _marker(scene, "Cheek_Hi_L")
    pts = s.project.points
    col = _from_truth(s, scene, m)
    # only camera 0 from frame 10 on (frame 10 keeps its 3D: the depth to hold)
    pts.obs[10:, col, 1:] = np.nan
    pts.source[10:, col, 1:] = 0
    pts.positions[11:, col] = np.nan
    s.select(points=[int(pts.ids[col])])
    s.set_property("Target Tracker", "tracker_overwrite_existing_tracks", True)
    s.current_frame = 10
    s.target_track(+1, to=20)
    assert (pts.recon[11:21, col] == RECON_SINGLE_SENSOR).all()
    e3 = np.linalg.norm(pts.positions[11:21, col] - scene.points3d[11:21, m], axis=-1)
    assert e3.max() < 3.0                                 # depth from a neighbour frame
    err = np.linalg.norm(pts.obs[11:21, col, 0] - scene.uv[11:21, m, 0], axis=-1)
    assert err.max() < 0.2


def test_single_sensor_depth_follows_the_neighbours_motion(session):
    """A chin marker keyed in one camera and tracked there: its depth on the ray comes
    from its neighbours' motion since the keyframe, not from the keyframe's 3D (the
    chin moves up to 8 mm over the take; held at the keyframe's depth it is 4.9 mm off)."""
    s, scene = session
    m = _marker(scene, "Chin_Crease")
    pts = s.project.points
    col = _from_truth(s, scene, m)
    pts.obs[:, col, 1:] = np.nan                  # camera 0 only, keyed on frame 0
    pts.obs[1:, col] = np.nan                     # (and its 3D): nothing after it
    pts.source[:, col, 1:] = 0
    pts.source[1:, col] = 0
    pts.positions[1:, col] = np.nan
    pts.recon[1:, col] = 0
    s.select(points=[int(pts.ids[col])])
    s.set_property("Target Tracker", "tracker_overwrite_existing_tracks", True)
    s.current_frame = 0
    s.target_track(+1)
    got = np.flatnonzero(np.isfinite(pts.obs[1:, col, 0, 0])) + 1
    assert len(got) >= 5
    assert (pts.recon[got, col] == RECON_SINGLE_SENSOR).all()
    e3 = np.linalg.norm(pts.positions[got, col] - scene.points3d[got, m], axis=-1)
    assert e3.max() < 0.5


def test_clear_tracked_points_removes_target_data_only(session):
    s, scene = session
    m = _marker(scene)
    s.current_frame = 0
    s.add_target_track(0, 0, scene.uv[0, m, 0])
    (pid,) = s.project.selection.points
    s.target_track(+1, to=5)
    before = snapshot(s.project)
    s.clear_tracked_points(pid)
    col = int(s.project.points.index_of([pid])[0])
    assert np.isnan(s.project.points.obs[:, col]).all()
    _undo_redo(s, before)


def test_pause_keeps_what_was_tracked_as_one_entry(session):
    s, scene = session
    pts = s.project.points
    col = _from_truth(s, scene, _marker(scene, "Cheek_L"))
    s.select(points=[int(pts.ids[col])])
    s.set_property("Target Tracker", "tracker_overwrite_existing_tracks", True)
    s.current_frame = 0
    calls = []

    def progress(done, total):
        calls.append(done)
        return done < 4

    s.target_track(+1, progress=progress)
    assert s.history()[-1].description.endswith("(cancelled: partial)")
    # every camera was tracked up to the pause (lockstep), none beyond it
    cams = np.flatnonzero(scene.visible[0, col])
    assert len(cams) >= 2
    assert (pts.source[1:5, col, cams] == SOURCE_TARGET).all()
    assert (pts.source[6:, col, cams] != SOURCE_TARGET).all()
    assert calls == [1, 2, 3, 4]


def test_a_run_tracks_every_camera_in_lockstep_as_each_alone(session, take):
    from carapost.algorithms.target_track import track_target

    s, scene = session
    get = take[2]
    pts = s.project.points
    col = _from_truth(s, scene, _marker(scene, "Cheek_L"))
    s.select(points=[int(pts.ids[col])])
    s.set_property("Target Tracker", "tracker_overwrite_existing_tracks", True)
    s.current_frame = 0
    pts.sigma[:, col] = 0.05                 # an earlier estimate of the 3D's uncertainty
    before = snapshot(s.project)
    job = s.prepare_target_track(+1)
    assert len(job.tracks) >= 2
    alone = {tr.camera: track_target(lambda f, c=tr.camera: get(f, c), tr.keys,
                                     start=job.start, stop=tr.stop, direction=1,
                                     params=tr.params or job.params, start_xy=tr.start_xy,
                                     start_velocity=tr.velocity) for tr in job.tracks}
    wanted, calls = [], []
    job.request = lambda f, cams, d: wanted.append((f, tuple(cams), d))
    s.apply(job.compute(lambda done, total: calls.append((done, total))))
    # the progress goes once through the range, each frame's cameras are asked at once
    assert calls == [(d, FRAMES - 1) for d in range(1, FRAMES)]
    cams = tuple(sorted(alone))
    assert wanted == [(f, cams, 1) for f in range(1, FRAMES)]
    for c, res in alone.items():
        ok = res.tracked
        np.testing.assert_array_equal(pts.obs[res.frames[ok], col, c],
                                      res.xy[ok].astype(np.float32))
        np.testing.assert_array_equal(pts.quality[res.frames[ok], col, c],
                                      res.score[ok].astype(np.float16))
    # the re-solved frames' old uncertainty is gone with their old 3D; undo brings it back
    assert np.isnan(pts.sigma[1:, col]).all() and pts.sigma[0, col] == np.float32(0.05)
    assert s.undo() and snapshot(s.project) == before


def test_bad_input_is_refused_and_changes_nothing(session):
    s, scene = session
    m = _from_truth(s, scene, _marker(scene))
    hidden = _marker(scene, "Philtrum")
    s.project.points.obs[0, hidden] = np.nan           # no 2D position on frame 0
    before = snapshot(s.project)
    with pytest.raises(CommandError, match="does not fit"):
        s.add_target_track(0, 0, (3.0, 100.0))         # keyframe box outside the image
    with pytest.raises(CommandError, match="no camera 7"):
        s.add_target_track(7, 0, scene.uv[0, m, 0])
    with pytest.raises(CommandError, match="no point is selected"):
        s.target_track(+1)
    s.select(points=[int(s.project.points.ids[hidden])])
    with pytest.raises(CommandError, match="no 2D position on frame 0"):
        s.target_track(+1)
    s.select(points=[int(s.project.points.ids[m])])
    with pytest.raises(CommandError, match="at least the Pattern Size"):
        s.target_track(+1, pattern_size=41, search_size=31)
    with pytest.raises(CommandError, match="larger than the 640 x 250 image"):
        _too_big(s)
    with pytest.raises(CommandError, match="no image source"):
        Session(s.project).target_track(+1)
    with pytest.raises(CommandError, match="no gap"):
        s.gaps_to_keys()
    assert len(s.history()) == 0
    s.select(points=[])
    assert snapshot(s.project) == before


def test_a_lost_tracks_message_says_what_its_last_frame_matched():
    """A measured match is truncated (never rounded up to the threshold it fell below);
    a first step with no disc, or two alike, has no match to report ("match 0.000" was
    shown for it)."""
    from carapost.commands.target_track import _match_text

    assert _match_text(0.89999) == "match 0.899"
    assert _match_text(0.0) == "no unambiguous match"
    assert _match_text(float("nan")) == "no unambiguous match"


def test_cameras_that_lost_the_marker_are_tracked_again_from_the_others_3d(fast_take):
    """A mouth marker keyed on frame 0 in every camera: some cameras lose it on the
    fast lip motion, one tracks on. Projected from that camera's 3D the marker is found
    again in the others (a restart from the projection), so the frames are triangulated
    instead of placed on one ray at a predicted depth."""
    import copy

    project, scene, get = fast_take
    m = _marker(scene, "Mouth_Outer_L")
    runs = {}
    for again in (False, True):
        s = Session(copy.deepcopy(project), get_image=get)
        pts = s.project.points
        pts.obs[0, m], pts.positions[0, m] = scene.uv[0, m], scene.points3d[0, m]
        for name, fill in (("obs", np.nan), ("positions", np.nan), ("source", 0),
                           ("detection", -1), ("recon", 0), ("keyframe", False)):
            pts.arrays[name][1:, m] = fill
        s.select(points=[int(pts.ids[m])])
        s.current_frame = 0
        s.add_keyframe()
        before = snapshot(s.project)
        job = s.prepare_target_track(+1)
        job.reacquire = again
        result = job.compute()
        s.apply(result)
        runs[again] = (pts.obs[:, m].copy(), pts.positions[:, m].copy(),
                       pts.recon[:, m].copy(), result.message)
        if again:
            _undo_redo(s, before)
    (obs0, X0, _, msg0), (obs1, X1, recon1, msg1) = runs[False], runs[True]
    n0 = np.isfinite(obs0[1:, :, 0]).sum(1)
    n1 = np.isfinite(obs1[1:, :, 0]).sum(1)
    assert ((n0 == 1) & (n1 >= 2)).sum() >= 8          # one-camera frames triangulated
    back = np.isfinite(obs1[..., 0]) & ~np.isfinite(obs0[..., 0])
    err = np.linalg.norm(obs1[back] - scene.uv[:, m][back], axis=-1)
    assert err.max() < 0.5                              # the marker, not a neighbour
    assert (recon1[back.any(1)] == RECON_TRIANGULATED).all()
    rmse = [float(np.sqrt(np.nanmean(np.sum((X[1:] - scene.points3d[1:, m]) ** 2, -1))))
            for X in (X0, X1)]
    assert rmse[1] < rmse[0]
    # on the frames put back (one camera before, triangulated now) the 3D is better
    moved = np.flatnonzero((n0 == 1) & (n1 >= 2)) + 1
    rmse_moved = [float(np.sqrt(np.mean(np.sum((X[moved] - scene.points3d[moved, m]) ** 2, -1))))
                  for X in (X0, X1)]
    assert rmse_moved[1] < 0.85 * rmse_moved[0]
    assert "tracked again" in msg1 and "tracked again" not in msg0
    # what was tracked in the first pass is kept as it was
    kept = np.isfinite(obs0[..., 0])
    np.testing.assert_array_equal(obs1[kept], obs0[kept])
