"""The frame service tells the window about the images it waits for, not about every
frame it reads ahead (each would wake the GUI thread for nothing)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

from carapost.io.frameservice import FrameService
from carapost.model.project import CameraChannel, Take

W, H, N = 64, 48, 60


def test_read_ahead_fills_the_cache_without_a_signal_per_frame(tmp_path):
    path = tmp_path / "l_cam0.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H), False)
    for i in range(N):
        writer.write(np.full((H, W), i * 4 % 256, np.uint8))
    writer.release()
    take = Take(name="l", n_frames=N, cameras=[
        CameraChannel(name="cam0", video_path=str(path), image_size=(W, H))])
    landed: list[int] = []
    lock = threading.Lock()

    def on_ready(frame: int, camera: int) -> None:
        with lock:
            landed.append(frame)

    with FrameService(take, on_ready=on_ready, read_ahead=20) as fs:
        fs.request(10, direction=1)
        deadline = time.perf_counter() + 10
        while fs.get_cached(30, 0) is None:  # the read-ahead has come this far
            assert time.perf_counter() < deadline
            time.sleep(0.005)
        assert all(fs.get_cached(f, 0) is not None for f in range(10, 31))
        with lock:
            assert 10 in landed  # the frame asked for
            assert not set(range(11, 31)) & set(landed)  # none of those read ahead
        # a step onto a frame read ahead: the view finds it cached (no decode, no wait)
        fs.request(11, direction=1)
        assert fs.get_display(11, 0) is not None
        assert int(fs.get(11, 0)[0, 0]) == 44  # and it is the right frame


def test_after_a_jump_the_nearest_frames_on_both_sides_are_read_first(tmp_path):
    from carapost.io.encode import FFV1Writer

    path = tmp_path / "o_cam0.mkv"
    with FFV1Writer(path, (W, H), 60.0) as writer:  # all-intra, like the synthetic takes
        for i in range(N):
            writer.write(np.full((H, W), i, np.uint8))
    take = Take(name="o", n_frames=N, cameras=[
        CameraChannel(name="cam0", video_path=str(path), image_size=(W, H))])
    order: list[int] = []
    with FrameService(take, read_ahead=12) as fs:
        put = fs._cache_put

        def recording(key, img):
            order.append(key[0])
            put(key, img)

        fs._cache_put = recording
        fs.request(30)
        deadline = time.perf_counter() + 10
        while fs.get_cached(42, 0) is None or fs.get_cached(26, 0) is None:
            assert time.perf_counter() < deadline
            time.sleep(0.005)
        # the frame asked for, the next two, the two before, then onwards; then back
        assert order[:5] == [30, 31, 32, 29, 28]
        assert order.index(42) < order.index(27)
        assert all(int(fs.get(f, 0)[0, 0]) == f for f in (26, 28, 29, 31, 42))
