"""The window reads the take's videos through its frame service: views never decode on
the GUI thread, show a clear message for a missing or short video, playback follows the
clock and says when it drops frames, jobs share the decoders."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carapost.model.project import new_project

W, H, N = 160, 120, 60


def _video(path, cam: int):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H), False)
    frames = []
    for f in range(N):
        img = np.full((H, W), 190, np.uint8)
        cv2.circle(img, (30 + f, 40 + 20 * cam), 5, 30, -1)
        img[:2, :2] = f
        frames.append(img)
        writer.write(img)
    writer.release()
    return frames


@pytest.fixture
def take(tmp_path):
    p = new_project(N, 3, image_size=(W, H))
    refs = []
    for c, cam in enumerate(p.take.cameras[:2]):
        refs.append(_video(tmp_path / f"t_cam{c}.mkv", c))
        cam.video_path = str(tmp_path / f"t_cam{c}.mkv")
    p.take.cameras[2].video_path = str(tmp_path / "lost_cam2.mkv")
    return p, refs


def _sensor_views(w):
    n = w.context.project.n_cameras
    return sorted((v for v in w.context.shell.all_views()
                   if v.kind == "sensor" and v.camera < n), key=lambda v: v.camera)


def test_views_get_images_from_decoder_threads_and_say_why_one_is_missing(
        make_window, take, qtbot):
    p, refs = take
    w = make_window(p)
    w.show()
    assert w.context.frames.asynchronous
    views = _sensor_views(w)[:3]
    w.set_frame(37)
    w.flush()
    qtbot.waitUntil(lambda: all(v.image_frame == 37 for v in views[:2]), timeout=10000)
    for v in views[:2]:
        np.testing.assert_array_equal(v._current_image, refs[v.camera][37])
    qtbot.waitUntil(lambda: views[2].notice.isVisible(), timeout=10000)
    assert "lost_cam2.mkv" in views[2].notice.text()
    assert "no such file" in views[2].notice.text()
    assert views[2].image_frame is None


def test_playback_follows_the_clock_and_reports_dropped_frames(
        make_window, take, qtbot, monkeypatch):
    from carapost.io import video

    p, _ = take
    p.take.cameras[2].video_path = p.take.cameras[1].video_path
    original = video.VideoSource.read

    def slow(self, index):  # a decoder much slower than the take's 60 frames/s
        import time

        time.sleep(0.04)
        return original(self, index)

    monkeypatch.setattr(video.VideoSource, "read", slow)
    w = make_window(p)
    w.show()
    messages = []
    w.context.status_message.connect(lambda text, ms: messages.append(text))
    p.set_view_range((0, N - 1))
    w.action("view.play").trigger()
    qtbot.waitUntil(lambda: not w.context.playback.playing, timeout=15000)
    pb = w.context.playback
    assert p.current_frame == N - 1
    assert pb.dropped > 0 and pb.shown > 0
    assert any("dropped" in m for m in messages)


def test_detect_current_frame_reads_through_the_shared_service(make_window, take, qtbot):
    p, _ = take
    p.take.cameras[2].video_path = p.take.cameras[1].video_path
    w = make_window(p)
    frames = w.context.frames
    assert frames.worker_copy() is frames  # no second set of decoders per job
    w.set_frame(12)
    w.action("process.blobs_current").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert len(p.detections.get(12, 0)["centre"]) == 1
    assert len(p.detections.get(12, 1)["centre"]) == 1


def test_proxies_are_written_after_import_and_shown_while_playing(make_window, take, qtbot):
    p, refs = take
    p.take.cameras[2].video_path = p.take.cameras[1].video_path
    w = make_window(p)
    w.show()
    frames = w.context.frames
    qtbot.waitUntil(lambda: frames.stats()["proxies"] == 3, timeout=30000)
    label = w.job_status.frames_label
    p.set_view_range((0, N - 1))
    w.action("view.play").trigger()
    assert frames.stats()["showing_proxies"]
    assert "Images: Proxy" in label.text()
    qtbot.waitUntil(lambda: not w.context.playback.playing, timeout=15000)
    assert not frames.stats()["showing_proxies"]
    views = _sensor_views(w)
    qtbot.waitUntil(lambda: all(v.image_frame == N - 1 for v in views), timeout=10000)
    for v in views:  # the original frame once playback stops
        np.testing.assert_array_equal(v._current_image, refs[min(v.camera, 1)][N - 1])
    assert "Images: Original" in label.text() and "Proxies 3/3" in label.text()


def test_cache_size_and_proxy_settings_are_user_settings(make_window):
    from carapost.io.frameservice import DEFAULT_CACHE_MB
    from carapost.ui.panes import PropertiesPane
    from carapost.ui.settings import build_proxies, frame_cache_mb

    w = make_window()
    assert frame_cache_mb(w.context.settings) == DEFAULT_CACHE_MB  # one default
    pane = next(p for p in w.findChildren(PropertiesPane) if hasattr(p, "frame_editors"))
    pane.frame_editors["frame_cache_mb"].setValue(800)
    pane.frame_editors["build_proxies_after_import"].setChecked(False)
    assert frame_cache_mb(w.context.settings) == 800
    assert build_proxies(w.context.settings) is False
    p = new_project(4, 1, image_size=(W, H))
    p.take.cameras[0].video_path = "/nonexistent/x_cam0.mkv"
    w.set_project(p)
    assert w.context.frames.stats()["cache_limit_mb"] == 800
