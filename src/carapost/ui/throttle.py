"""Panes that follow the current frame refresh a few times a second while playing.

At 60 frames/s the GUI thread has 16 ms per frame for everything: the four camera
views must redraw every frame, but a pane that shows the current frame's state in text
or colours (the Labelling pane's colours, the Selected Point pane's sample) cannot be
read at that rate anyway. `FrameThrottle` lets such a pane skip frame-only changes
while playback runs and refresh on a timer instead; every other change, and the frame
playback stops on, is shown as before.

Scrubbing (dragging the timebar, holding an arrow key) changes the frame as fast as
playing does: a frame change that comes within `SCRUB_REFRESH_MS` of the pane's last
refresh waits too, and the pane shows the frame the scrub stops on that much later.
A single step is shown at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QTimer

from carapost.model.events import Change

#: Milliseconds between two refreshes of a throttled pane while playing.
PLAYING_REFRESH_MS = 250
#: Least milliseconds between two refreshes for frame changes while not playing.
SCRUB_REFRESH_MS = 80

_FRAME_ONLY = frozenset({"current_frame"})


class FrameThrottle:
    """Defers frame-only changes during playback to a refresh every `interval_ms`.

    Parameters
    ----------
    view : ViewContext
        Its ``playing`` attribute says whether playback runs.
    refresh : callable
        What the pane does for a frame change (called with no argument).
    interval_ms : int
        Time between two refreshes while playing.
    scrub_ms : int
        Least time between two refreshes for frame changes while not playing.
    """

    def __init__(self, view: Any, refresh: Callable[[], None],
                 interval_ms: int = PLAYING_REFRESH_MS,
                 scrub_ms: int = SCRUB_REFRESH_MS) -> None:
        self.view = view
        self._refresh = refresh
        self.interval_ms = interval_ms
        self.scrub_s = scrub_ms / 1e3
        self._last = -float("inf")  # monotonic time of the last refresh
        self.timer = QTimer()
        self.timer.setSingleShot(True)
        self.timer.timeout.connect(self._fire)

    def defer(self, change: Change | None) -> bool:
        """True when ``change`` moves the frame only and playback runs, or the pane
        refreshed less than ``scrub_ms`` ago: the pane skips it (a refresh follows
        within ``interval_ms`` / ``scrub_ms``). False: the pane refreshes now."""
        now = time.monotonic()
        if (change is None or change.parts is None or not change.parts <= _FRAME_ONLY):
            self._last = now
            return False
        if getattr(self.view, "playing", False):
            wait_ms = self.interval_ms
        elif now - self._last < self.scrub_s:
            wait_ms = max(1, round((self._last + self.scrub_s - now) * 1e3))
        else:
            self._last = now
            return False
        if not self.timer.isActive():
            self.timer.start(wait_ms)
        return True

    def _fire(self) -> None:
        self._last = time.monotonic()
        try:
            self._refresh()
        except RuntimeError:  # the pane's widgets are already gone (window closing)
            pass
