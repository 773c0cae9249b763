"""Stepping through a take or playing it does not lay the main window out again: the
timebar's frame label and Play button and the status bar's image label have the fixed
size of their widest text, so a new text changes no size hint."""

from __future__ import annotations

from PySide6.QtCore import QEvent, QObject

from carapost.model.project import new_project
from tests.ui.test_frames_gui import take  # noqa: F401  (a fixture: 3 cameras' videos)


class _Layouts(QObject):
    """Counts the layout requests Qt posts to a widget."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def eventFilter(self, obj, ev) -> bool:
        if ev.type() == QEvent.Type.LayoutRequest:
            self.count += 1
        return False


def _settled(qtbot, widgets) -> _Layouts:
    """A layout counter on ``widgets``, installed once the window's own first layouts
    are over (no request for 300 ms; a loaded machine takes longer to get there)."""
    layouts = _Layouts()
    for widget in widgets:
        widget.installEventFilter(layouts)
    for _ in range(20):
        layouts.count = 0
        qtbot.wait(300)
        if layouts.count == 0:
            break
    assert layouts.count == 0, "the window never settled"
    return layouts


def test_stepping_frames_lays_nothing_out_again(make_window, qtbot):
    p = new_project(12_000, 2, image_size=(64, 48))
    w = make_window(p)
    w.show()
    bar = w.timebar
    layouts = _settled(qtbot, (w, w.centralWidget(), bar))
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


def test_playing_lays_nothing_out(make_window, take, qtbot):  # noqa: F811
    """Play <-> Stop and the rate shown once a second in the status bar keep their
    sizes: a 2 s playback posts no layout request to the window, the status bar or
    the timebar."""
    p, _ = take
    p.take.cameras[2].video_path = p.take.cameras[1].video_path
    p.take.fps = 30.0  # 60 frames: 2 s, so the rate is reported once while playing
    w = make_window(p)
    w.show()
    layouts = _settled(qtbot, (w, w.centralWidget(), w.timebar, w.statusBar()))
    rates = []
    label = w.job_status.frames_label
    w.context.playback.rate_changed.connect(lambda shown, fps: rates.append(label.text()))
    p.set_view_range((0, p.n_frames - 1))
    w.action("view.play").trigger()
    assert w.timebar.play_button.text() == "Stop"
    qtbot.waitUntil(lambda: not w.context.playback.playing, timeout=15000)
    assert rates and "fps" in rates[0]  # the rate was shown while playing
    assert w.timebar.play_button.text() == "Play"
    assert layouts.count == 0
