"""The status bar's permanent widgets: point/selection summary, job progress and Cancel."""

from __future__ import annotations

from PySide6.QtWidgets import QLabel, QProgressBar, QPushButton, QStatusBar

from carapost.model.events import Change
from carapost.ui.context import ActionContext
from carapost.ui.fixed_label import fix_to_text


class JobStatus:
    """Fills a status bar from the context: messages, the summary and the running job."""

    def __init__(self, bar: QStatusBar, ctx: ActionContext) -> None:
        self.bar = bar
        self.ctx = ctx
        self.summary = QLabel()
        # which images the views show (proxy or original) and the proxies' progress
        self.frames_label = QLabel()
        self.frames_label.setToolTip("Images shown: Original (the camera videos) or Proxy "
                                     "(fast copies, while playing)")
        # Its text changes once a second while playing (the rate shown) and with the
        # proxies' progress; a label whose size follows its text made Qt lay out the
        # status bar and the whole main window each time, in the middle of playback.
        # Fixed at the size of its longest text, it lays nothing out.
        fix_to_text(self.frames_label,
                    "Images: Original  |  000/000 fps  |  Proxies 00/00 (000%)")
        self.progress = QProgressBar()
        self.progress.setMaximumWidth(260)
        self.progress.hide()
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.hide()
        self.cancel_button.clicked.connect(ctx.runner.cancel)
        for w in (self.frames_label, self.summary, self.progress, self.cancel_button):
            bar.addPermanentWidget(w)
        self._proxy_text = ""
        ctx.proxies.progressed.connect(self._proxy_progress)
        ctx.proxies.finished.connect(self._proxies_done)
        ctx.playback.playing_changed.connect(lambda _: self._show_frames())
        ctx.playback.rate_changed.connect(self._rate)
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

    # -- images shown and playback proxies ---------------------------------------------
    def _show_frames(self, rate: str = "") -> None:
        stats = self.ctx.frames.stats()
        if not stats:
            self.frames_label.setText(self._proxy_text)
            return
        kind = "Proxy" if stats.get("showing_proxies") else "Original"
        parts = [f"Images: {kind}", rate, self._proxy_text]
        self.frames_label.setText("  |  ".join(p for p in parts if p))

    def _rate(self, shown: float, fps: float) -> None:
        self._show_frames(f"{shown:.0f}/{fps:.0f} fps")

    def _proxy_progress(self, done: int, total: int, fraction: float) -> None:
        self._proxy_text = ("" if done >= total else
                            f"Proxies {done}/{total} ({100 * fraction:.0f}%)")
        self._show_frames()

    def _proxies_done(self, n: int) -> None:
        self._proxy_text = f"Proxies {n}/{self.ctx.project.n_cameras}" if n else ""
        self._show_frames()
