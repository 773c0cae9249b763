"""Playback in lockstep: while playing, every camera's decoder works through the same
schedule of frames, so when the decoders cannot keep up with the clock whole frames
are dropped and every frame decoded is complete (all cameras have it)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from carapost.io import video
from carapost.io.encode import FFV1Writer
from carapost.io.frameservice import FrameService
from carapost.io.lockstep import LOCKSTEP_SLACK
from carapost.model.project import CameraChannel, Take

W, H, N, CAMERAS = 64, 48, 240, 4
FPS = 60.0


def _write(path: Path, cam: int, gop: int = 1) -> Path:
    with FFV1Writer(path, (W, H), FPS, gop=gop) as writer:
        for i in range(N):
            img = np.full((H, W), 40 * cam, np.uint8)
            img[:4, :4] = i % 256
            writer.write(img)
    return path


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("lockstep")
    return [_write(folder / f"t_cam{c}.mkv", c) for c in range(CAMERAS)]


def _take(paths: list[Path]) -> Take:
    cams = [CameraChannel(name=f"cam{i}", video_path=str(p), image_size=(W, H))
            for i, p in enumerate(paths)]
    return Take(name="t", n_frames=N, cameras=cams, fps=FPS)


@pytest.fixture
def slow_decoders(monkeypatch):
    """Decoders slower than the take's 60 frames/s, each camera at its own speed (the
    situation in which cameras chasing the clock alone decode different frames)."""
    original = video.VideoSource.read
    delay = {f"t_cam{c}.mkv": 0.020 + 0.006 * c for c in range(CAMERAS)}

    def slow(self, index):
        time.sleep(delay.get(Path(self.path).name, 0.0))
        return original(self, index)

    monkeypatch.setattr(video.VideoSource, "read", slow)


def _play(fs: FrameService, seconds: float) -> int:
    """Advance the playback clock at the take's rate for ``seconds``; the last frame."""
    fs.set_read_ahead(int(2 * FPS), playing=True)
    t0 = time.perf_counter()
    due = 0
    while time.perf_counter() - t0 < seconds:
        due = int((time.perf_counter() - t0) * FPS)
        fs.set_clock(due)
        time.sleep(1 / (2 * FPS))
    return due


def _decoded(fs: FrameService, camera: int) -> set[int]:
    return {f for f in range(N) if fs.get_cached(f, camera) is not None}


def test_slow_decoders_decode_the_same_frames_and_drop_whole_frames(videos, slow_decoders):
    with FrameService(_take(videos)) as fs:
        last = _play(fs, 1.5)
        per_camera = [_decoded(fs, c) for c in range(CAMERAS)]  # still playing
    complete = set.intersection(*per_camera)
    partial = set.union(*per_camera) - complete
    # the clock ran faster than any decoder: frames were dropped, whole
    assert 10 <= len(complete) < last
    # every frame a decoder worked on was finished by all cameras, except the newest
    # ones, in flight
    assert len(partial) <= LOCKSTEP_SLACK
    assert all(f > max(complete) for f in partial)


def test_with_keyframe_intervals_the_frames_decoded_on_the_way_are_complete_too(
        tmp_path, slow_decoders):
    # a video of another system: a keyframe every 12 frames; reaching a scheduled frame
    # decodes from the keyframe before it, and every camera keeps those frames
    paths = [_write(tmp_path / f"t_cam{c}.mkv", c, gop=12) for c in range(CAMERAS)]
    with FrameService(_take(paths)) as fs:
        _play(fs, 1.5)
        per_camera = [_decoded(fs, c) for c in range(CAMERAS)]
        assert len(fs._play.frames) <= 2 * FPS  # frames complete and passed are forgotten
    complete = set.intersection(*per_camera)
    partial = set.union(*per_camera) - complete
    assert len(complete) >= 10
    assert all(f > max(complete) for f in partial)  # only the newest, in flight


def test_a_camera_without_video_does_not_hold_the_others(videos, tmp_path, slow_decoders):
    paths = list(videos[:3]) + [tmp_path / "lost_cam3.mkv"]
    with FrameService(_take(paths)) as fs:
        _play(fs, 0.8)
        per_camera = [_decoded(fs, c) for c in range(3)]
        assert fs.message(0, 3) is not None
    assert len(set.intersection(*per_camera)) >= 5


def test_decoders_that_keep_up_read_every_frame_ahead_of_the_clock(videos):
    with FrameService(_take(videos)) as fs:
        fs.set_read_ahead(30, playing=True)
        fs.set_clock(10)
        t0 = time.perf_counter()
        while (not all(fs.get_cached(39, c) is not None for c in range(CAMERAS))
               and time.perf_counter() - t0 < 10):
            time.sleep(0.005)
        for c in range(CAMERAS):
            assert _decoded(fs, c) >= set(range(10, 40))
        # the images are the videos' own
        assert int(fs.get_cached(25, 2)[0, 0]) == 25
        assert int(fs.get_cached(25, 2)[10, 10]) == 80
