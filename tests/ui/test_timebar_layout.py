"""Stepping through a take does not lay the main window out again: the timebar's frame
label has the fixed size of its widest text, so its new text each frame changes no
size hint."""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject

from carapost.model.project import new_project


class _Layouts(QObject):
    """Counts the layout requests Qt posts to a widget."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def eventFilter(self, obj, ev) -> bool:
        if ev.type() == QEvent.Type.LayoutRequest:
            self.count += 1
        return False


def test_stepping_frames_lays_nothing_out_again(make_window, qtbot):
    p = new_project(12_000, 2, image_size=(64, 48))
    w = make_window(p)
    w.show()
    qtbot.wait(400)  # the window's own first layouts settle
    bar = w.timebar
    layouts = _Layouts()
    for widget in (w, w.centralWidget(), bar):
        widget.installEventFilter(layouts)
    # 9 -> 10 -> ... -> 10010: the digits of the frame number change
    for f in (9, 10, 99, 100, 999, 1000, 9999, 10_000, 11_999):
        w.set_frame(f)
        w.flush()
        qtbot.wait(5)
        assert f"frame {f} /" in bar.label.text()
        # the whole text fits in the fixed width (nothing is cut off)
        assert bar.label.fontMetrics().horizontalAdvance(bar.label.text()) <= bar.label.width()
    assert layouts.count == 0


def test_the_frame_label_grows_with_a_longer_take(make_window):
    w = make_window(new_project(50, 2, image_size=(64, 48)))
    short = w.timebar.label.width()
    w.set_project(new_project(360_000, 2, image_size=(64, 48)))
    assert w.timebar.label.width() > short
    w.set_frame(359_999)
    w.flush()
    label = w.timebar.label
    assert label.fontMetrics().horizontalAdvance(label.text()) <= label.width()
