"""The status bar's permanent widgets: point/selection summary, job progress and Cancel."""

from __future__ import annotations

from PySide6.QtWidgets import QLabel, QProgressBar, QPushButton, QStatusBar

from carapost.model.events import Change
from carapost.ui.context import ActionContext


class JobStatus:
    """Fills a status bar from the context: messages, the summary and the running job."""

    def __init__(self, bar: QStatusBar, ctx: ActionContext) -> None:
        self.bar = bar
        self.ctx = ctx
        self.summary = QLabel()
        self.progress = QProgressBar()
        self.progress.setMaximumWidth(260)
        self.progress.hide()
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.hide()
        self.cancel_button.clicked.connect(ctx.runner.cancel)
        for w in (self.summary, self.progress, self.cancel_button):
            bar.addPermanentWidget(w)
        ctx.runner.started.connect(self._started)
        ctx.runner.progressed.connect(self._progressed)
        ctx.runner.finished.connect(self._finished)
        ctx.status_message.connect(bar.showMessage)
        ctx.view.changed.connect(self._changed)

    def _changed(self, change: Change) -> None:
        p = self.ctx.project
        self.summary.setText(f"{p.n_points} points | {len(p.selection.points)} selected")

    def _started(self, title: str) -> None:
        self.progress.setRange(0, 0)  # busy until the first progress report
        self.progress.setFormat(f"{title} %p%")
        self.progress.show()
        self.cancel_button.show()
        self.bar.showMessage(title)

    def _progressed(self, done: int, total: int) -> None:
        self.progress.setRange(0, max(total, 1))
        self.progress.setValue(done)

    def _finished(self, title: str, cancelled: bool) -> None:
        self.progress.hide()
        self.cancel_button.hide()
        # the runner sets its outcome before it emits finished
        self.bar.showMessage(f"{title} {self.ctx.runner.outcome}", 4000)
