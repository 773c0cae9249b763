"""Panes that follow the current frame refresh a few times a second while playing.

At 60 frames/s the GUI thread has 16 ms per frame for everything: the four camera
views must redraw every frame, but a pane that shows the current frame's state in text
or colours (the Labelling pane's colours, the Selected Point pane's sample) cannot be
read at that rate anyway. `FrameThrottle` lets such a pane skip frame-only changes
while playback runs and refresh on a timer instead; every other change, and the frame
playback stops on, is shown as before.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QTimer

from carapost.model.events import Change

#: Milliseconds between two refreshes of a throttled pane while playing.
PLAYING_REFRESH_MS = 250

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
    """

    def __init__(self, view: Any, refresh: Callable[[], None],
                 interval_ms: int = PLAYING_REFRESH_MS) -> None:
        self.view = view
        self._refresh = refresh
        self.timer = QTimer()
        self.timer.setSingleShot(True)
        self.timer.setInterval(interval_ms)
        self.timer.timeout.connect(self._fire)

    def defer(self, change: Change | None) -> bool:
        """True when ``change`` moves the frame only and playback runs: the pane skips
        it (a refresh follows within ``interval_ms``)."""
        if (change is None or change.parts is None or not getattr(self.view, "playing", False)
                or not change.parts <= _FRAME_ONLY):
            return False
        if not self.timer.isActive():
            self.timer.start()
        return True

    def _fire(self) -> None:
        try:
            self._refresh()
        except RuntimeError:  # the pane's widgets are already gone (window closing)
            pass
