"""Playback of the view range at the take's frame rate (View > Play, Space)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import QObject, QTimer, Signal

if TYPE_CHECKING:
    from carapost.ui.context import ActionContext


class Playback(QObject):
    """Steps the current frame through the view range and stops at its end.

    Signals
    -------
    playing_changed(bool)
        Playback started or stopped (the timebar button and View > Play follow).
    """

    playing_changed = Signal(bool)

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__(ctx)
        self.ctx = ctx
        self.timer = QTimer(self)
        self.timer.timeout.connect(self._tick)

    @property
    def playing(self) -> bool:
        """Whether playback runs."""
        return self.timer.isActive()

    def toggle(self, on: bool) -> None:
        """Play (from the view range's start when at its end) or stop."""
        p = self.ctx.project
        if on and p.n_frames:
            if p.current_frame >= p.view_range[1]:
                self.ctx.set_frame(p.view_range[0])
            # one timer tick per frame of the take's rate (at least 1 ms)
            self.timer.start(max(int(1000 / max(p.take.fps, 1)), 1))
        else:
            self.timer.stop()
        self.playing_changed.emit(self.playing)

    def stop(self) -> None:
        """Stop playback (nothing happens when it is not running)."""
        if self.playing:
            self.toggle(False)

    def _tick(self) -> None:
        p = self.ctx.project
        if p.current_frame >= p.view_range[1]:
            self.stop()
            return
        self.ctx.set_frame(p.current_frame + 1)
