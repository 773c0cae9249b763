"""Playback drops frames by the schedule, not by the timer's jitter: the timer is set
for the next frame's due time, a frame a little late (less than LATE_FRAMES frame times)
is still shown and the next one follows at once, and only a frame later than that is
skipped. A fake clock drives the ticks."""

from __future__ import annotations

import pytest

from carapost.model.project import new_project
from carapost.ui.playback import LATE_FRAMES, RETRY_MS

FPS = 60.0
T0 = 100.0


@pytest.fixture
def playback(make_window):
    p = new_project(120, 2, image_size=(64, 48))
    p.take.fps = FPS
    w = make_window(p)
    p.set_view_range((0, 119))
    pb = w.context.playback
    now = {"t": T0}
    pb.clock = lambda: now["t"]
    pb.toggle(True)
    assert pb.playing

    def tick_at(frames: float) -> int:
        """Tick ``frames`` frame times after the start; the frame then on screen."""
        now["t"] = T0 + frames / FPS
        pb._tick()
        return p.current_frame

    yield pb, tick_at
    pb.stop()


def test_the_timer_is_set_for_the_next_frames_due_time(playback):
    pb, tick_at = playback
    assert tick_at(1.2) == 1
    # frame 2 is due 0.8 frame times (13.3 ms) later: the timer fires just after it
    assert pb.timer.isSingleShot() and pb.timer.isActive()
    assert pb.timer.interval() == 14
    assert tick_at(1.9) == 1  # a tick before that shows nothing new
    assert pb.timer.interval() == 2  # ceil(0.1 frame times = 1.7 ms)


def test_a_frame_a_little_late_is_shown_and_playback_catches_up(playback):
    pb, tick_at = playback
    assert tick_at(1.05) == 1
    # a tick delayed by 1.55 frame times (a long paint): frame 3 is due, but frame 2,
    # 1.05 frame times late, is shown rather than skipped
    assert tick_at(3.05) == 2
    assert pb.timer.interval() == RETRY_MS  # behind the clock: look again at once
    assert tick_at(3.2) == 3  # caught up
    assert (pb.shown, pb.dropped, pb.late) == (3, 0, 1)


def test_a_frame_later_than_the_limit_is_dropped(playback):
    pb, tick_at = playback
    assert tick_at(1.05) == 1
    late = 1 + 1 + LATE_FRAMES + 0.5  # frame 2 is 2.5 frame times late (4.5)
    assert tick_at(late) == int(late)  # playback jumps to the clock
    assert pb.dropped == int(late) - 2
    assert pb.shown == 2

