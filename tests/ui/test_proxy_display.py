"""A camera view playing from a half-resolution proxy draws it over the original's
pixels (overlays and image coordinates unchanged), and shows the original once the view
is zoomed in beyond Actual Size or playback stops."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QPointF, QRectF

from carapost.model.project import new_project

W, H, N = 640, 360, 40


@pytest.fixture
def take(tmp_path):
    p = new_project(N, 1, image_size=(W, H))
    path = tmp_path / "z_cam0.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H), False)
    frames = []
    for f in range(N):
        img = np.full((H, W), 120, np.uint8)
        cv2.circle(img, (200 + 5 * f, 150), 10, 250, -1)
        frames.append(img)
        writer.write(img)
    writer.release()
    p.take.cameras[0].video_path = str(path)
    return p, frames


def _window_with_proxy(make_window, p, qtbot):
    """The window on the take once its proxy is written, its camera view showing the
    image at most at half size (so playback draws the proxy)."""
    w = make_window(p)
    w.show()
    w.resize(900, 700)
    qtbot.waitUntil(lambda: w.context.frames.stats()["proxies"] == 1, timeout=30000)
    view = next(v for v in w.context.shell.all_views() if v.kind == "sensor")
    view.fit()
    if view.image_scale() > 0.5:
        view.vb.setRange(QRectF(-0.5, -0.5, 3 * W, 3 * H), padding=0)
    assert view.image_scale() <= 0.5
    return w, view


def test_a_proxy_is_drawn_over_the_originals_pixels_until_zoomed_in(make_window, take, qtbot):
    p, frames = take
    w, view = _window_with_proxy(make_window, p, qtbot)
    frames_src = w.context.frames
    frames_src.set_playing(60.0)  # what View > Play does first
    # (frames beyond the originals read ahead at opening: a cached original is shown
    # rather than its proxy)
    try:
        w.set_frame(30)
        qtbot.waitUntil(lambda: view.image_frame == 30 and view.showing_proxy, timeout=10000)
        img = view.image.image
        assert img.shape == (H // 2, W // 2)
        # stretched over the original's pixel rectangle (in image coordinates)
        rect = view.image.mapRectToParent(view.image.boundingRect())
        assert rect.width() == pytest.approx(W) and rect.height() == pytest.approx(H)
        assert rect.left() == pytest.approx(-0.5) and rect.top() == pytest.approx(-0.5)
        assert view.image_size() == (W, H)
        # the marker drawn where the original has it
        ys, xs = np.nonzero(img > 200)
        # (pixel i of the item covers i..i+1 of its own coordinates)
        centre = view.image.mapToParent(QPointF(float(xs.mean()) + 0.5,
                                                float(ys.mean()) + 0.5))
        assert abs(centre.x() - (200 + 5 * 30)) < 1.5 and abs(centre.y() - 150) < 1.5
        # the image turned off and on again (Image in the view's menu) in between
        opts = w.context.view.options
        opts.image = False
        view.refresh(None)
        assert not view.showing_proxy
        opts.image = True
        # Actual Size (1:1) still plays the proxy; zoomed in beyond it, the original
        view.actual_size()
        assert frames_src.service._use_proxy(0)
        centre = view.vb.viewRect().center()
        view.vb.setRange(QRectF(centre.x() - 25, centre.y() - 15, 50, 30), padding=0)
        assert view.image_scale() > 1.05
        w.set_frame(31)
        qtbot.waitUntil(lambda: view.image_frame == 31 and not view.showing_proxy,
                        timeout=10000)
        np.testing.assert_array_equal(view.image.image, frames[31])
        rect = view.image.mapRectToParent(view.image.boundingRect())
        assert rect.width() == pytest.approx(W) and rect.left() == pytest.approx(-0.5)
        w.set_frame(30)  # its proxy image is cached, but too coarse at this zoom
        qtbot.waitUntil(lambda: view.image_frame == 30, timeout=10000)
        assert not view.showing_proxy
        np.testing.assert_array_equal(view.image.image, frames[30])
    finally:
        frames_src.set_playing(None)


def test_stopping_playback_shows_the_original_and_redraws_only_proxy_views(
        make_window, take, qtbot, monkeypatch):
    """View > Play, then stop: a view left on a proxy frame turns to the original; a
    view that already shows the original at the current frame is not drawn again."""
    p, frames = take
    w, view = _window_with_proxy(make_window, p, qtbot)
    playback = w.context.playback
    playback.toggle(True)
    playback.timer.stop()  # playing, held on one frame (the clip is 0.7 s long)
    try:
        w.set_frame(30)
        qtbot.waitUntil(lambda: view.image_frame == 30 and view.showing_proxy, timeout=10000)
    finally:
        playback.toggle(False)
    # the original of the frame on screen replaces the proxy once it is decoded
    frame = w.context.project.current_frame
    qtbot.waitUntil(lambda: view.image_frame == frame and not view.showing_proxy,
                    timeout=10000)
    np.testing.assert_array_equal(view.image.image, frames[frame])
    # on the original already: stopping again draws nothing
    drawn: list[int] = []
    monkeypatch.setattr(view, "refresh", lambda change: drawn.append(1))
    playback.toggle(True)
    playback.toggle(False)
    assert drawn == []
