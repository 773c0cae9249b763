"""What a window without a take shows: how to start (instead of four empty sensors)."""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtWidgets import QLabel, QWidget

from carapost.model.events import Change
from carapost.ui.context import ActionContext

__all__ = ["EmptyHint", "HINT"]

HINT = (
    "<div style='font-size:15pt; color:#e6e6e6'>No take is open</div>"
    "<p style='color:#c8c8c8'>"
    "<b>File &gt; Open...</b> (Ctrl+O) a <i>.cara</i> project,<br>"
    "<b>File &gt; Import Camera Files...</b> to start from a take's videos,<br>"
    "or run <code>carapost demo</code> for a labelled synthetic take.</p>")


class EmptyHint(QLabel):
    """An overlay on the workspace while the window holds no take."""

    def __init__(self, parent: QWidget, ctx: ActionContext) -> None:
        super().__init__(HINT, parent)
        self.ctx = ctx
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setTextFormat(Qt.TextFormat.RichText)
        self.setAttribute(Qt.WidgetAttribute.WA_TransparentForMouseEvents)
        self.setStyleSheet("QLabel { background: rgba(24, 24, 26, 225); "
                           "border: 1px solid #555; border-radius: 6px; padding: 18px; }")
        parent.installEventFilter(self)
        ctx.view.changed.connect(self._changed)
        self._place()
        self.update_visibility()

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        if event.type() == QEvent.Type.Resize:
            self._place()
        return False

    def _place(self) -> None:
        parent = self.parentWidget()
        self.adjustSize()
        w, h = self.sizeHint().width() + 40, self.sizeHint().height() + 20
        self.setGeometry((parent.width() - w) // 2, (parent.height() - h) // 3, w, h)

    def _changed(self, change: Change) -> None:
        self.update_visibility()

    def update_visibility(self) -> None:
        """Shown while the project has no frames (nothing imported or opened)."""
        p = self.ctx.project
        self.setVisible(p is None or p.n_frames == 0)
        self.raise_()
