"""What a frame costs the GUI thread: the camera image drawn as a plain gray image with
the same pixels on screen, images landing without redrawing the overlays, panes that
follow the frame throttled while playing."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtGui import QImage, QPainter

from carapost.model.events import Change
from carapost.ui.throttle import FrameThrottle


def _draw(item: pg.ImageItem, size: tuple[int, int], scale: float) -> np.ndarray:
    out = QImage(size[0], size[1], QImage.Format.Format_RGB32)
    out.fill(0)
    painter = QPainter(out)
    painter.scale(scale, scale)
    item.paint(painter)
    painter.end()
    return np.frombuffer(out.constBits(), np.uint8).reshape(size[1], size[0], 4).copy()


def test_camera_images_are_drawn_without_levels_with_the_same_pixels(make_window, demo,
                                                                      qtbot, rng):
    from carapost.ui.frames import ArrayFrameSource

    project, _ = demo
    img = rng.integers(0, 256, (360, 640), dtype=np.uint8)
    w = make_window(project, ArrayFrameSource(lambda f, c: img))
    view = next(v for v in w.workspace.views() if v.kind == "sensor")
    w.flush()
    qtbot.wait(20)
    item = view.image
    assert item.levels is None and np.shares_memory(item.image, img)
    item.render()
    # a gray QImage over the frame itself: no colour table, no copy per frame
    assert item.qimage.format() == QImage.Format.Format_Grayscale8
    ref = pg.ImageItem(axisOrder="row-major")
    ref.setImage(img, autoLevels=False, levels=(0, 255))  # the indexed path
    for size, scale in (((640, 360), 1.0), ((400, 225), 0.625), ((960, 540), 1.5)):
        np.testing.assert_array_equal(_draw(item, size, scale), _draw(ref, size, scale))


class _View:
    playing = False


def test_frame_changes_wait_while_playing_and_others_do_not(qtbot):
    view = _View()
    calls: list[int] = []
    throttle = FrameThrottle(view, lambda: calls.append(1), interval_ms=30)
    frame = Change(frozenset({"current_frame"}), (5, 5))
    points = Change(frozenset({"points", "current_frame"}))
    assert not throttle.defer(frame)  # not playing: every change is shown
    view.playing = True
    assert throttle.defer(frame) and throttle.defer(frame)
    assert not throttle.defer(points) and not throttle.defer(None)
    qtbot.waitUntil(lambda: calls == [1], timeout=2000)  # one refresh for the two
    qtbot.wait(80)
    assert calls == [1]


def test_an_image_landing_redraws_the_image_only(make_window, demo, qtbot):
    from carapost.ui.frames import ArrayFrameSource

    project, _ = demo
    w = make_window(project, ArrayFrameSource(
        lambda f, c: np.full((360, 640), (f + 40 * c) % 256, np.uint8)))
    view = next(v for v in w.workspace.views() if v.kind == "sensor")
    w.set_frame(3)
    w.flush()
    qtbot.wait(20)
    assert view.image_frame == 3
    overlays: list[int] = []
    original = view._draw_overlays
    view._draw_overlays = lambda frame: (overlays.append(frame), original(frame))
    view.image_landed(3)
    assert overlays == [] and view.image_frame == 3
    assert int(view.image.image[0, 0]) == (3 + 40 * view.camera) % 256
    view.image_landed(4)  # not the frame drawn: a full redraw of the current one
    assert overlays == [3]


def test_label_colours_follow_the_frame_row_by_row(make_window, demo, qtbot):
    project, frames = demo
    w = make_window(project, frames)
    pane = w.pane("Labelling")
    p = w.project
    labels = [n for n in p.points.labels if n]
    assert labels
    # a label absent at some frames: its state changes with the frame
    col = p.points.labels.index(labels[0])
    p.points.positions[10:20, col] = np.nan
    for f in (0, 12, 30):
        w.set_frame(f)
        w.flush()
        names = [pane.list.item(i).text() for i in range(pane.list.count())]
        assert pane.label_states(names) == [pane.label_state(n) for n in names]
        state = "absent" if 10 <= f < 20 else "assigned"
        item = pane.list.item(names.index(labels[0]))
        # steps this fast are a scrub: the pane follows within the scrub interval
        qtbot.waitUntil(lambda: item.toolTip() == f"{labels[0]}: {state}", timeout=2000)


def test_playback_sends_the_decoders_once_per_frame_due(make_window, demo, qtbot):
    from carapost.ui.frames import ArrayFrameSource

    class Counting(ArrayFrameSource):
        def __init__(self, render):
            super().__init__(render)
            self.requests: list[int] = []

            self.moving = False

        def request(self, frame, camera=None, direction=0):
            if not self.moving:  # playback's own requests, not those of moving to a frame
                self.requests.append(frame)

        def set_clock(self, frame):  # where the playback clock is (lockstep decoding)
            self.requests.append(frame)

    project, frames = demo
    source = Counting(frames._render)
    w = make_window(project, source)
    ctx = w.context
    set_frame = ctx.set_frame

    def moving_to(frame):
        source.moving = True
        try:
            set_frame(frame)
        finally:
            source.moving = False

    ctx.set_frame = moving_to
    pb = ctx.playback
    pb.toggle(True)
    assert w.view_context.playing
    qtbot.waitUntil(lambda: not pb.playing, timeout=20000)  # plays the take to its end
    assert not w.view_context.playing
    assert source.requests, "playback asks the decoders for the frames due"
    # the timer ticks at twice the frame rate: each frame due is asked for once
    assert len(source.requests) == len(set(source.requests))


def test_images_other_than_uint8_keep_their_levels(make_window, demo, qtbot):
    from carapost.ui.frames import ArrayFrameSource

    project, _ = demo
    img = np.linspace(0, 255, 360 * 640, dtype=np.float32).reshape(360, 640)
    w = make_window(project, ArrayFrameSource(lambda f, c: img))
    view = next(v for v in w.workspace.views() if v.kind == "sensor")
    w.flush()
    qtbot.wait(20)
    item = view.image
    assert tuple(item.levels) == (0, 255)
    item.render()
    assert item.qimage is not None and item.qimage.width() == 640
