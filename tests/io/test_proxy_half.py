"""Half-resolution playback proxies: written at half width and height from the pixel
averages of the original, read as such, and used only while no view of the camera is
zoomed in beyond Actual Size."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost.io.frameservice import FrameService
from carapost.io.proxy import ProxyReader, existing_proxy, proxy_downscale, write_proxy
from carapost.model.project import CameraChannel, Take

W, H, N = 640, 360, 24


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> tuple[Path, list[np.ndarray]]:
    folder = tmp_path_factory.mktemp("half")
    rng = np.random.default_rng(11)
    base = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (9, 9), 0)
    path = folder / "h_cam0.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H),
                             isColor=False)
    frames = []
    for i in range(N):
        img = np.roll(base, 4 * i, axis=1).copy()
        cv2.circle(img, (100 + 10 * i, 180), 12, 250, -1)  # a marker that moves
        frames.append(img)
        writer.write(img)
    writer.release()
    return path, frames


def test_a_large_video_gets_a_half_resolution_proxy_of_its_pixel_averages(video):
    path, frames = video
    assert proxy_downscale(W, H) == 2 and proxy_downscale(320, 240) == 1
    out = write_proxy(path)
    assert out is not None and out == existing_proxy(path)
    reader = ProxyReader(out)
    assert reader.size == (W // 2, H // 2) and reader.n_frames == N
    for i in (0, N - 1, 5, 17):
        img = reader.read(i)
        assert img.shape == (H // 2, W // 2) and img.dtype == np.uint8
        ref = cv2.resize(frames[i], (W // 2, H // 2), interpolation=cv2.INTER_AREA)
        diff = np.abs(img.astype(int) - ref.astype(int))
        assert diff.mean() < 3.0 and np.percentile(diff, 99) < 16  # JPEG q4
        # the marker is where the original has it, at half the coordinates
        ys, xs = np.nonzero(img > 200)
        assert abs(xs.mean() * 2 + 0.5 - (100 + 10 * i)) < 1.5
        assert abs(ys.mean() * 2 + 0.5 - 180) < 1.5
    reader.close()
    # full resolution on request (and a small original is never shrunk)
    full = write_proxy(path.with_name("h_cam0.mkv"), downscale=1)
    assert full == out  # one proxy per video: the existing one is returned


def _take(path: Path) -> Take:
    return Take(name="h", n_frames=N, cameras=[
        CameraChannel(name="cam0", video_path=str(path), image_size=(W, H))])


def _wait(fs: FrameService, frame: int, proxy: bool, timeout: float = 10.0):
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        img, is_proxy = fs.display(frame, 0)
        if img is not None and is_proxy == proxy:
            return img
        time.sleep(0.002)
    raise AssertionError(f"frame {frame} never shown (proxy={proxy})")


def test_proxies_stand_in_until_a_view_is_zoomed_in_beyond_actual_size(video):
    path, frames = video
    write_proxy(path)
    with FrameService(_take(path)) as fs:
        assert fs.attach_proxies() == 1
        assert fs.proxy_downscale(0) == pytest.approx(2.0)
        fs.set_view_scale(0, 0.45, "view A")  # a four-view layout: half size or less
        fs.set_read_ahead(10, playing=True)
        fs.request(8, direction=1)
        img = _wait(fs, 8, proxy=True)
        assert img.shape == (H // 2, W // 2)
        fs.set_view_scale(0, 0.9, "view C")  # a one-view layout: the proxy still plays
        fs.request(5, direction=1)
        assert _wait(fs, 5, proxy=True).shape == (H // 2, W // 2)
        # a second view of the camera zoomed in beyond 1:1: the artist looks at pixels
        fs.set_view_scale(0, 2.0, "view B")
        assert fs.display(9, 0) == (None, False) or not fs.display(9, 0)[1]
        fs.request(9, direction=1)
        img = _wait(fs, 9, proxy=False)
        np.testing.assert_array_equal(img, frames[9])  # the original, bit for bit
        fs.set_view_scale(0, None, "view B")  # that view closed
        fs.request(N - 1, direction=1)  # beyond the originals read ahead meanwhile
        assert _wait(fs, N - 1, proxy=True).shape == (H // 2, W // 2)
        # processing reads the originals whatever is shown
        np.testing.assert_array_equal(fs.get(15, 0), frames[15])
        fs.set_read_ahead(24, playing=False)
        assert fs.display(16, 0)[1] is False
