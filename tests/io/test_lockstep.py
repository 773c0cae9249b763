"""The playback schedule alone: every camera is given the same frames, a camera ahead
waits for the slowest, passed frames are dropped whole, started ones finished."""

from __future__ import annotations

from carapost.io.lockstep import PlaySchedule


class Cameras:
    """Which frames each camera has decoded, and which it is decoding."""

    def __init__(self, n: int) -> None:
        self.have: list[set[int]] = [set() for _ in range(n)]
        self.busy: dict[int, int] = {}  # camera -> frame in flight

    def done(self, frame: int, camera: int) -> bool:
        return frame in self.have[camera]

    def started(self, frame: int) -> bool:
        return frame in self.busy.values() or any(frame in h for h in self.have)

    def take(self, schedule: PlaySchedule, camera: int, end: int = 1000) -> int | None:
        f = schedule.next(camera, self.done, self.started, end)
        if f is not None:
            self.busy[camera] = f
        return f

    def finish(self, camera: int) -> None:
        self.have[camera].add(self.busy.pop(camera))


def test_every_camera_is_given_the_same_frames_and_the_fastest_waits():
    cams = Cameras(3)
    s = PlaySchedule(3, slack=2, ahead_slack=4)
    s.set_clock(10)
    assert [cams.take(s, c) for c in range(3)] == [10, 10, 10]
    # ahead of the clock, camera 0 reads on while the others have fewer than 4 to do
    for f in (11, 12, 13):
        cams.finish(0)
        assert cams.take(s, 0) == f
    cams.finish(0)
    assert cams.take(s, 0) is None  # cameras 1 and 2 have four to do: camera 0 waits
    cams.finish(1)
    cams.finish(2)
    assert cams.take(s, 1) == 11 and cams.take(s, 2) == 11
    # behind the clock, the others may have two frames to do at most
    s.set_clock(12)
    assert cams.take(s, 0) is None  # 11 (in flight, passed), 12 and 13: three
    cams.finish(1)
    cams.finish(2)
    assert cams.take(s, 1) == 12 and cams.take(s, 2) == 12
    assert cams.take(s, 0) == 14  # caught up with the clock: reading ahead again


def test_frames_the_clock_passed_are_dropped_whole_and_started_ones_finished():
    cams = Cameras(2)
    s = PlaySchedule(2, slack=2)
    s.set_clock(0)
    assert cams.take(s, 0) == 0 and cams.take(s, 1) == 0
    cams.finish(0)
    assert cams.take(s, 0) == 1
    s.set_clock(5)  # the decoders are slow: the clock runs ahead
    cams.finish(1)
    # frame 1 was started by camera 0: camera 1 finishes it too, though it is late
    assert cams.take(s, 1) == 1
    cams.finish(0)
    cams.finish(1)
    # nothing scheduled is left to do: the next frame is the clock's; 2-4 are dropped
    assert cams.take(s, 0) == 5 and cams.take(s, 1) == 5
    assert s.frames == [5]
    assert cams.have[0] == cams.have[1] == {0, 1}


def test_frames_read_ahead_stop_at_the_limit_and_the_clock_going_back_restarts():
    cams = Cameras(1)
    s = PlaySchedule(1)
    s.set_clock(0)
    taken = []
    while (f := cams.take(s, 0, end=4)) is not None:
        taken.append(f)
        cams.finish(0)
    assert taken == [0, 1, 2, 3]
    s.set_clock(2)
    assert cams.take(s, 0, end=6) == 4
    cams.finish(0)
    s.set_clock(0)  # played again from the start: frames 0-4 are cached, 5 is next
    assert s.frames == []
    assert cams.take(s, 0, end=8) == 5
    s.reset()
    assert s.clock is None and cams.take(s, 0) is None
