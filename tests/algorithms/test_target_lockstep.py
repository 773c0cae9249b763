"""Lockstep target tracking: several tracks one frame at a time give the very results of
tracking each one alone, read each frame's images together, and stop together."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.target_lockstep import LockstepTracker, TrackRun
from carapost.algorithms.target_track import (
    STOP_CANCELLED,
    STOP_END,
    STOP_THRESHOLD,
    TargetTrackerParameters,
    track_target,
)
from tests.algorithms.test_target_track import Scene

P = TargetTrackerParameters(search_size=41)


@pytest.fixture(scope="module")
def cameras():
    """Four "cameras": one marker each; camera 2's marker vanishes at frame 12."""
    return [Scene(n=30, seed=0), Scene(n=30, seed=1), Scene(n=30, seed=3, hide=range(12, 30)),
            Scene(n=30, seed=4)]


def _runs(cameras, log=None, start=0, direction=1, stops=(29, 20, 29, 29)):
    def image(c):
        def get(f):
            if log is not None:
                log.append((int(f), c))
            return cameras[c].image(f)
        return get

    return [TrackRun(image(c), {start: sc.xy[start]}, start=start, stop=stop,
                     direction=direction, params=P) for c, (sc, stop)
            in enumerate(zip(cameras, stops, strict=True))]


def _same(a, b) -> None:
    assert a.reason == b.reason
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.score, b.score)
    np.testing.assert_array_equal(a.keyframe, b.keyframe)


@pytest.mark.parametrize("direction", [1, -1])
def test_lockstep_results_are_those_of_each_camera_alone(cameras, direction):
    start = 0 if direction > 0 else 29
    stops = (29, 20, 29, 29) if direction > 0 else (0, 9, 0, 0)
    if direction < 0:   # backwards, camera 2's marker is hidden from the start: visible one
        cameras = [cameras[0], cameras[1], Scene(n=30, seed=3, hide=range(0, 17)), cameras[3]]
    alone = [track_target(r.get_image, r.keyframes, start=r.start, stop=r.stop,
                          direction=r.direction, params=r.params)
             for r in _runs(cameras, start=start, direction=direction, stops=stops)]
    together = LockstepTracker(_runs(cameras, start=start, direction=direction,
                                     stops=stops)).run()
    for a, b in zip(alone, together, strict=True):
        _same(a, b)
    assert [r.reason for r in together] == [STOP_END, STOP_END, STOP_THRESHOLD, STOP_END]
    assert len(together[0].frames) == 30 and len(together[1].frames) == 21
    assert together[2].frames[-1] == (12 if direction > 0 else 16)   # where it vanished


def test_each_step_reads_one_frame_of_every_camera_still_tracking(cameras):
    log: list[tuple[int, int]] = []
    lock = LockstepTracker(_runs(cameras, log))
    frames = []
    while (f := lock.step()) is not None:
        frames.append(f)
        # every camera still going has tracked this frame; the others dropped out
        assert all(lock.runs[i].stop >= f for i in lock.active)
    assert frames == list(range(1, 30))
    tracked = [f for f, _ in log if f > 0]
    assert tracked == sorted(tracked)                 # the range is swept once
    assert {c for f, c in log if f == 15} == {0, 1, 3}   # camera 2 stopped at frame 12
    assert {c for f, c in log if f == 25} == {0, 3}       # camera 1 reached its stop


def test_progress_is_once_through_the_range_and_cancel_keeps_every_camera(cameras):
    seen: list[tuple[int, int]] = []

    def progress(done, total):
        seen.append((done, total))
        return done < 7

    res = LockstepTracker(_runs(cameras)).run(progress)
    assert seen == [(d, 29) for d in range(1, 8)]
    for r in (res[0], res[1], res[3]):
        assert r.reason == STOP_CANCELLED
        assert r.frames[-1] == 7 and np.isfinite(r.xy).all()
    assert res[2].reason == STOP_CANCELLED and res[2].frames[-1] == 7
    # what was kept is what tracking alone up to frame 7 gives
    alone = track_target(cameras[0].image, {0: cameras[0].xy[0]}, start=0, stop=7,
                         direction=1, params=P)
    np.testing.assert_array_equal(res[0].xy, alone.xy)


def test_before_step_names_the_frame_and_the_runs_tracking_it(cameras):
    calls: list[tuple[int, list[int]]] = []
    LockstepTracker(_runs(cameras)).run(before_step=lambda f, runs: calls.append((f, runs)))
    assert calls[0] == (1, [0, 1, 2, 3])
    assert dict(calls)[15] == [0, 1, 3] and dict(calls)[25] == [0, 3]
    assert calls[-1][0] == 29


def test_an_error_in_one_track_ends_them_all():
    sc = Scene(n=20)
    flat = np.full((120, 160), 128, np.uint8)
    runs = [TrackRun(sc.image, {0: sc.xy[0]}, 0, 19, 1, P),
            TrackRun(lambda f: flat, {0: (70.0, 60.0)}, 0, 19, 1, P)]
    lock = LockstepTracker(runs)
    with pytest.raises(ValueError, match="flat"):
        lock.run()
    assert lock.results == [None, None] and all(g is None for g in lock._lets)


def test_tracks_must_share_start_and_direction():
    sc = Scene(n=10)
    with pytest.raises(ValueError, match="share"):
        LockstepTracker([TrackRun(sc.image, {0: sc.xy[0]}, 0, 9, 1, P),
                         TrackRun(sc.image, {3: sc.xy[3]}, 3, 9, 1, P)])
    with pytest.raises(ValueError, match="at least one"):
        LockstepTracker([])


def test_a_failing_callback_leaves_no_track_suspended(cameras):
    def progress(done, total):
        if done == 3:
            raise RuntimeError("the window went away")

    lock = LockstepTracker(_runs(cameras))
    with pytest.raises(RuntimeError, match="went away"):
        lock.run(progress)
    assert all(g is None for g in lock._lets)
