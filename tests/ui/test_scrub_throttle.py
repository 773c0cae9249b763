"""Panes that follow the frame coalesce a scrub's frame changes: the first change of a
scrub is shown at once, the ones that follow within the scrub interval wait for one
trailing refresh, which shows the frame the scrub stopped on."""

from __future__ import annotations

import time

from carapost.model.events import Change
from carapost.ui.throttle import FrameThrottle


class _View:
    playing = False


def test_a_scrub_refreshes_at_once_then_once_more_when_it_stops(qtbot):
    view = _View()
    shown: list[int] = []
    frame = {"now": 0}
    throttle = FrameThrottle(view, lambda: shown.append(frame["now"]), scrub_ms=60)

    def move(f: int) -> None:
        frame["now"] = f
        if not throttle.defer(Change(frozenset({"current_frame"}), (f, f))):
            shown.append(f)

    move(1)
    assert shown == [1]  # a single step: at once
    for f in range(2, 12):  # a fast scrub: one change every ~2 ms
        move(f)
        time.sleep(0.002)
    assert shown == [1]  # the storm is not drawn frame by frame
    qtbot.waitUntil(lambda: shown[-1] == 11, timeout=2000)  # the frame it stopped on
    assert shown == [1, 11]
    qtbot.wait(100)
    n = len(shown)
    move(12)  # a step long after the last refresh: at once again
    assert shown[n:] == [12]
    # a change of the data is never held back
    assert not throttle.defer(Change(frozenset({"points", "current_frame"})))
    assert not throttle.defer(None)
