"""What a frame costs the GUI thread: the camera image drawn through a 32-bit copy with
the same pixels on screen, images landing without redrawing the overlays, panes that
follow the frame throttled while playing."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtGui import QImage, QPainter

from carapost.model.events import Change
from carapost.ui.throttle import FrameThrottle
from carapost.ui.views.frame_item import GrayImageItem


def _draw(item: pg.ImageItem, size: tuple[int, int], scale: float) -> np.ndarray:
    out = QImage(size[0], size[1], QImage.Format.Format_RGB32)
    out.fill(0)
    painter = QPainter(out)
    painter.scale(scale, scale)
    item.paint(painter)
    painter.end()
    return np.frombuffer(out.constBits(), np.uint8).reshape(size[1], size[0], 4).copy()


def test_gray_item_draws_the_pixels_pyqtgraph_draws(qtbot, rng):
    img = rng.integers(0, 256, (90, 160), dtype=np.uint8)
    ref = pg.ImageItem(axisOrder="row-major")
    ref.setImage(img, autoLevels=False, levels=(0, 255))
    fast = GrayImageItem(axisOrder="row-major")
    fast.setImage(img, autoLevels=False, levels=None)
    for size, scale in (((160, 90), 1.0), ((80, 45), 0.5), ((240, 135), 1.5),
                        ((320, 180), 2.0)):
        np.testing.assert_array_equal(_draw(fast, size, scale), _draw(ref, size, scale))
    # at other scales Qt's 32-bit scaler rounds the sample position its own way: every
    # pixel drawn is still one of the image's pixels next to the one it stands for
    drawn = _draw(fast, (100, 56), 0.625)
    assert (drawn[..., 0] == drawn[..., 1]).all() and (drawn[..., 3] == 255).all()
    ys, xs = np.mgrid[0:56, 0:100]
    cy, cx = ((ys + 0.5) / 0.625).astype(int), ((xs + 0.5) / 0.625).astype(int)
    near = np.zeros(drawn.shape[:2], bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            yy, xx = np.clip(cy + dy, 0, 89), np.clip(cx + dx, 0, 159)
            near |= img[yy, xx] == drawn[..., 0]
    assert near.all()
    assert fast.qimage.format() == QImage.Format.Format_RGB32
    assert fast.image is not None and fast.image.shape == (90, 160)  # the gray array
    # a new frame of another size is drawn from its own pixels
    img2 = rng.integers(0, 256, (40, 70), dtype=np.uint8)
    fast.setImage(img2, autoLevels=False, levels=None)
    ref.setImage(img2, autoLevels=False, levels=(0, 255))
    np.testing.assert_array_equal(_draw(fast, (70, 40), 1.0), _draw(ref, (70, 40), 1.0))
    # anything else (levels set) goes through pyqtgraph's own rendering
    fast.setImage(img2, autoLevels=False, levels=(50, 100))
    ref.setImage(img2, autoLevels=False, levels=(50, 100))
    np.testing.assert_array_equal(_draw(fast, (70, 40), 1.0), _draw(ref, (70, 40), 1.0))


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
