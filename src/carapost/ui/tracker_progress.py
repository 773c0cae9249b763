"""The Target Tracker's progress bar below the play controls.

While a Tracker pane run (Track forward / back, to the end or one frame) is on the
worker, a thin bar under the timebar shows how far it has got through its range, with
the frame every camera has reached (the cameras are tracked in lockstep); it hides when
the run ends. Other jobs keep their progress in the status bar only.
"""

from __future__ import annotations

from PySide6.QtWidgets import QProgressBar

from carapost.ui.context import ActionContext

__all__ = ["TrackerProgress"]


class TrackerProgress(QProgressBar):
    """A progress bar that shows itself during Target Tracker runs only."""

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        self.setMaximumHeight(14)
        self.setTextVisible(True)
        self.setToolTip("Target Tracker run: frames tracked so far (Pause keeps them)")
        self.hide()
        self._title = ""
        self._start, self._direction = 0, 1
        ctx.runner.started.connect(self._started)
        ctx.runner.progressed.connect(self._progressed)
        ctx.runner.finished.connect(self._finished)
        ctx.runner.failed.connect(self._finished)

    def _started(self, title: str) -> None:
        from carapost.ui.handlers.target import TITLES

        run = next((k for k, v in TITLES.items() if v == title), None)
        if run is None:
            return
        self._title = title
        # a run starts at the current frame; every camera advances one frame per step
        self._start, self._direction = self.ctx.project.current_frame, run[0]
        self.setRange(0, 0)            # busy until the first frame is tracked
        self.setFormat(title)
        self.show()

    def _progressed(self, done: int, total: int) -> None:
        if not self._title:
            return
        self.setRange(0, max(int(total), 1))
        self.setValue(int(done))
        frame = self._start + self._direction * int(done)
        self.setFormat(f"{self._title}: frame {frame} ({int(done)} of {int(total)}, %p%)")

    def _finished(self, *_: object) -> None:
        self._title = ""
        self.hide()
