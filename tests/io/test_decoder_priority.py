"""Decoder threads give way to the GUI thread: they run at a higher nice value."""

from __future__ import annotations

import os
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from carapost.io.decode import AVReader
from carapost.io.frameservice import DECODER_NICE, DECODER_THREADS, FrameService
from carapost.model.project import CameraChannel, Take
from tests.io.test_video import write_video


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice: Linux")
def test_decoder_threads_run_below_the_callers_priority(tmp_path):
    path = tmp_path / "n_cam0.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (32, 24),
                             isColor=False)
    for i in range(10):
        writer.write(np.full((24, 32), i * 20, np.uint8))
    writer.release()
    take = Take(name="n", n_frames=10, cameras=[
        CameraChannel(name="cam0", video_path=str(path), image_size=(32, 24))])
    mine = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    with FrameService(take) as fs:
        assert int(fs.get(3, 0)[0, 0]) == 60  # decoded on the camera's thread
        decoder = next(t for t in threading.enumerate() if t.name.startswith("carapost-decode"))
        t0 = time.perf_counter()
        while decoder.native_id is None and time.perf_counter() - t0 < 5:
            time.sleep(0.01)
        nice = os.getpriority(os.PRIO_PROCESS, decoder.native_id)
        assert nice == min(mine + DECODER_NICE, 19)
        # the calling thread keeps its own priority
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == mine


def test_frame_service_decoders_use_one_ffmpeg_thread_each(tmp_path):
    """Each camera has a decoder thread of its own, so FFmpeg adds no threads per
    decoder (they would compete with the GUI thread); the pixels are the same."""
    rng = np.random.default_rng(3)
    path = write_video(tmp_path / "t_cam0.mkv",
                       [rng.integers(0, 256, (48, 64), dtype=np.uint8) for _ in range(10)],
                       fps=60.0)
    take = Take(name="t", n_frames=10, cameras=[
        CameraChannel(name="cam0", video_path=str(path), image_size=(64, 48))])
    default = AVReader(path)
    assert default._stream.codec_context.thread_count != DECODER_THREADS
    with FrameService(take) as fs:
        images = [fs.get(f, 0) for f in (7, 2, 3)]
        reader = fs.source(0)._reader
        assert reader.threads == DECODER_THREADS
        assert reader._stream.codec_context.thread_count == DECODER_THREADS
        decoder = next(t for t in threading.enumerate()
                       if t.name.startswith("carapost-decode"))
    for img, f in zip(images, (7, 2, 3), strict=True):
        np.testing.assert_array_equal(img, default.read(f))
    default.close()
    decoder.join(timeout=5)
    assert not decoder.is_alive()  # closing the service ends its decoder threads
