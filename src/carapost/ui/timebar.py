"""Timebar: current frame, playback buttons, active and view ranges, timecode."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QRectF, Qt, Signal
from PySide6.QtGui import QColor, QPainter, QPen
from PySide6.QtWidgets import QHBoxLayout, QLabel, QSpinBox, QToolButton, QWidget

from carapost.model.project import Project
from carapost.ui.fixed_label import fix_to_text


def timecode_text(project: Project, frame: int) -> str:
    """SMPTE timecode of a frame ("" when the take's start timecode is unusable)."""
    try:
        from carapost.io.timecode import frame_index_to_timecode

        tc, sub = frame_index_to_timecode(frame, project.take.timecode_start, project.take.fps)
        return str(tc) + (f".{sub}" if sub else "")
    except Exception:  # a take without a sensible timecode still shows frame numbers
        return ""


class TimeRuler(QWidget):
    """The bar itself: view range with ticks, the active range and the current frame.

    Click or drag scrubs; Ctrl+drag sets the active range; the wheel (or a middle-button
    drag) shuttles time.
    """

    frame_requested = Signal(int)
    range_dragged = Signal(int, int)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.project: Project | None = None
        self.setMinimumHeight(30)
        self._ctrl_start: int | None = None
        self._drag_range: tuple[int, int] | None = None
        self._middle_x: float | None = None

    def set_project(self, project: Project) -> None:
        """Show this project."""
        self.project = project
        self.update()

    def _span(self) -> tuple[int, int]:
        p = self.project
        if p is None or p.n_frames == 0:
            return (0, 1)
        a, b = p.view_range
        return a, max(b, a + 1)

    def frame_at(self, x: float) -> int:
        """Frame under the x pixel."""
        a, b = self._span()
        w = max(self.width() - 12, 1)
        f = a + (x - 6) / w * (b - a)
        return int(np.clip(round(f), a, b))

    def x_of(self, frame: float) -> float:
        """Pixel of a frame."""
        a, b = self._span()
        return 6 + (frame - a) / max(b - a, 1) * max(self.width() - 12, 1)

    def paintEvent(self, ev) -> None:
        painter = QPainter(self)
        painter.fillRect(self.rect(), QColor(45, 45, 48))
        p = self.project
        if p is None or p.n_frames == 0:
            painter.end()
            return
        h = self.height()
        a, b = self._span()
        # active range
        lo, hi = p.active_range
        painter.fillRect(QRectF(self.x_of(lo), 2, self.x_of(hi) - self.x_of(lo) + 1, h - 4),
                         QColor(70, 110, 160))
        if self._drag_range is not None:
            d0, d1 = self._drag_range
            painter.fillRect(QRectF(self.x_of(d0), 2, self.x_of(d1) - self.x_of(d0) + 1, h - 4),
                             QColor(120, 170, 255, 120))
        # ticks: about one label per 80 px
        span = b - a
        raw = span / max(self.width() / 80, 1)
        step = int(10 ** np.floor(np.log10(max(raw, 1))))
        for m in (1, 2, 5, 10):
            if step * m >= raw:
                step *= m
                break
        painter.setPen(QColor(190, 190, 190))
        first = (a // step) * step
        for f in range(int(first), b + 1, max(step, 1)):
            if f < a:
                continue
            x = self.x_of(f)
            painter.drawLine(int(x), h - 8, int(x), h - 2)
            painter.drawText(int(x) + 2, h - 10, str(f))
        # current frame
        x = self.x_of(p.current_frame)
        painter.setPen(QPen(QColor(255, 200, 0), 2))
        painter.drawLine(int(x), 0, int(x), h)
        painter.end()

    def mousePressEvent(self, ev) -> None:
        x = ev.position().x()
        if ev.button() == Qt.MouseButton.MiddleButton:
            self._middle_x = x
            return
        if ev.button() != Qt.MouseButton.LeftButton:
            return
        if ev.modifiers() & Qt.KeyboardModifier.ControlModifier:
            self._ctrl_start = self.frame_at(x)
            self._drag_range = (self._ctrl_start, self._ctrl_start)
            self.update()
        else:
            self.frame_requested.emit(self.frame_at(x))

    def mouseMoveEvent(self, ev) -> None:
        x = ev.position().x()
        if self._middle_x is not None and self.project is not None:
            step = int((x - self._middle_x) / 4)
            if step:
                self._middle_x = x
                self.frame_requested.emit(self.project.current_frame + step)
            return
        if self._ctrl_start is not None:
            f = self.frame_at(x)
            self._drag_range = (min(f, self._ctrl_start), max(f, self._ctrl_start))
            self.update()
        elif ev.buttons() & Qt.MouseButton.LeftButton:
            self.frame_requested.emit(self.frame_at(x))

    def mouseReleaseEvent(self, ev) -> None:
        self._middle_x = None
        if self._ctrl_start is not None and self._drag_range is not None:
            self.range_dragged.emit(*self._drag_range)
        self._ctrl_start = None
        self._drag_range = None
        self.update()

    def wheelEvent(self, ev) -> None:
        if self.project is None:
            return
        notches = ev.angleDelta().y() / 120
        step = int(np.sign(notches) * max(1, abs(round(notches))))
        if ev.modifiers() & Qt.KeyboardModifier.ShiftModifier:
            step *= 10
        self.frame_requested.emit(self.project.current_frame - step)


class Timebar(QWidget):
    """Buttons, ruler, frame spin box and timecode."""

    frame_requested = Signal(int)
    range_dragged = Signal(int, int)
    play_toggled = Signal(bool)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.project: Project | None = None
        layout = QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)

        def button(text: str, tip: str) -> QToolButton:
            b = QToolButton()
            b.setText(text)
            b.setToolTip(tip)
            b.setFocusPolicy(Qt.FocusPolicy.NoFocus)
            layout.addWidget(b)
            return b

        self.start_button = button("|<", "Go to Start Frame (Home)")
        self.prev_button = button("<", "Prev Frame (Left arrow)")
        self.play_button = button("Play", "Play / Stop (Space)")
        self.play_button.setCheckable(True)
        # as large as its longer text, so Play <-> Stop lays nothing out as playback starts
        hints = []
        for text in ("Stop", "Play"):
            self.play_button.setText(text)
            hints.append(self.play_button.sizeHint())
        self.play_button.setFixedSize(max(h.width() for h in hints),
                                      max(h.height() for h in hints))
        self.next_button = button(">", "Next Frame (Right arrow)")
        self.end_button = button(">|", "Go to End Frame (End)")
        self.ruler = TimeRuler()
        layout.addWidget(self.ruler, 1)
        self.spin = QSpinBox()
        self.spin.setKeyboardTracking(False)
        self.spin.setToolTip("Current frame (Go To Frame: Ctrl+G)")
        layout.addWidget(self.spin)
        self.label = QLabel()
        self.label.setMinimumWidth(210)
        layout.addWidget(self.label)
        self._label_text = ""
        self.start_button.clicked.connect(self._go_start)
        self.end_button.clicked.connect(self._go_end)
        self.prev_button.clicked.connect(self._step(-1))
        self.next_button.clicked.connect(self._step(1))
        self.play_button.toggled.connect(self.play_toggled)
        self.spin.valueChanged.connect(self.frame_requested)
        self.ruler.frame_requested.connect(self.frame_requested)
        self.ruler.range_dragged.connect(self.range_dragged)

    # slots return None: PySide6 mishandles Python slots that return a bool
    def _go_start(self) -> None:
        self.frame_requested.emit(0)

    def _go_end(self) -> None:
        self.frame_requested.emit(self.project.n_frames - 1 if self.project else 0)

    def _step(self, d: int):
        def step() -> None:
            self.frame_requested.emit((self.project.current_frame if self.project else 0) + d)
        return step

    def set_project(self, project: Project) -> None:
        """Show this project."""
        self.project = project
        self.ruler.set_project(project)
        self.spin.blockSignals(True)
        self.spin.setRange(0, max(project.n_frames - 1, 0))
        self.spin.blockSignals(False)
        self._fix_label_size()
        self.refresh()

    def _label(self, frame: int) -> str:
        p = self.project
        assert p is not None
        tc = timecode_text(p, frame) if p.n_frames else ""
        a, b = p.active_range
        return f"{tc}  frame {frame} / {max(p.n_frames - 1, 0)}  active {a}-{b}"

    def _fix_label_size(self) -> None:
        """Give the frame label the size of its widest text for this take.

        The label's text changes on every frame; a label whose size follows its text
        makes Qt lay the whole main window out again after each frame (the timebar's
        size hint changes with the digits), while a label of fixed width and height
        does not even tell its layout.
        """
        p = self.project
        if p is None:
            return
        n = "0" * len(str(max(p.n_frames - 1, 0)))
        last = max(p.n_frames - 1, 0)
        longest = max((timecode_text(p, f) for f in {0, min(1, last), last}), key=len)
        fix_to_text(self.label, f"{longest}  frame {n} / {n}  active {n}-{n}", min_width=210)

    def set_playing(self, playing: bool) -> None:
        """Reflect the play state on the button."""
        self.play_button.blockSignals(True)
        self.play_button.setChecked(playing)
        self.play_button.setText("Stop" if playing else "Play")
        self.play_button.blockSignals(False)

    def refresh(self) -> None:
        """Redraw after the frame or ranges changed."""
        p = self.project
        if p is None:
            return
        f = p.current_frame
        if self.spin.value() != f:
            self.spin.blockSignals(True)
            self.spin.setValue(f)
            self.spin.blockSignals(False)
        text = self._label(f)
        if text != self._label_text:
            self._label_text = text
            self.label.setText(text)
        self.ruler.update()
