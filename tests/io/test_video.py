"""Frame access: bit-exact FFV1 decoding, random access, image sequences, cache, prefetch."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost.io import video as video_module
from carapost.io.errors import CaraFileError
from carapost.io.video import (
    TakeFrames,
    VideoSource,
    free_in_slices,
    image_sequence_files,
    natural_key,
)
from carapost.model.project import CameraChannel, Take

W, H = 96, 64


def make_frames(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Distinct, compressible gray frames (blurred noise, frame index in the corner)."""
    out = []
    for i in range(n):
        img = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 0)
        img[:4, :4] = i
        out.append(img)
    return out


def write_video(path: Path, frames: list[np.ndarray], fourcc: str = "FFV1",
                fps: float = 50.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps,
                             (frames[0].shape[1], frames[0].shape[0]), isColor=False)
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()
    return path


@pytest.fixture
def ffv1(tmp_path: Path, rng: np.random.Generator) -> tuple[Path, list[np.ndarray]]:
    frames = make_frames(rng, 40)
    return write_video(tmp_path / "t_cam0.mkv", frames), frames


def test_ffv1_sequential_decode_is_bit_exact(ffv1):
    path, frames = ffv1
    src = VideoSource(path)
    assert src.n_frames == len(frames)
    assert src.size == (W, H)
    assert src.fps == pytest.approx(50.0)
    for i, ref in enumerate(frames):
        img = src.read(i)
        assert img.dtype == np.uint8 and img.shape == (H, W)
        np.testing.assert_array_equal(img, ref)


@pytest.mark.parametrize("seek", ["auto", "seek", "decode"])
def test_ffv1_random_access_out_of_order_is_bit_exact(ffv1, seek, rng):
    path, frames = ffv1
    src = VideoSource(path, seek=seek)
    order = list(rng.permutation(len(frames))) + [39, 0, 38, 1, 1, 25, 24, 26]
    for i in order:
        np.testing.assert_array_equal(src.read(int(i)), frames[int(i)], err_msg=f"frame {i}")
    if seek == "auto":
        assert src.seek_exact is True


def test_mp4v_random_access_matches_sequential_decode(tmp_path, rng):
    frames = make_frames(rng, 30)
    path = write_video(tmp_path / "t_cam0.mp4", frames, "mp4v")
    src = VideoSource(path)
    seq = [src.read(i) for i in range(src.n_frames)]
    # lossy, but close to what was written, and random access gives the same decode
    assert np.abs(seq[7].astype(int) - frames[7]).mean() < 12
    for i in (20, 3, 29, 0, 15):
        np.testing.assert_array_equal(src.read(i), seq[i])


def test_read_outside_video_raises_index_error(ffv1):
    src = VideoSource(ffv1[0])
    with pytest.raises(IndexError, match="outside"):
        src.read(40)
    with pytest.raises(IndexError):
        src.read(-1)


def test_image_sequence_natural_order(tmp_path, rng):
    frames = make_frames(rng, 12)
    folder = tmp_path / "t_cam1"
    folder.mkdir()
    for i, f in enumerate(frames):  # 0..11 without zero padding: natural order matters
        cv2.imwrite(str(folder / f"img{i}.png"), f)
    (folder / "notes.txt").write_text("ignored")
    assert [p.name for p in image_sequence_files(folder)][:3] == ["img0.png", "img1.png",
                                                                   "img2.png"]
    src = VideoSource(folder)
    assert src.is_sequence and src.n_frames == 12 and src.size == (W, H)
    for i in (11, 2, 10, 0):
        np.testing.assert_array_equal(src.read(i), frames[i])


def test_natural_key():
    names = ["cam10", "cam2", "Cam1", "cam2b"]
    assert sorted(names, key=natural_key) == ["Cam1", "cam2", "cam2b", "cam10"]


def test_missing_damaged_and_empty_sources_name_the_file(tmp_path):
    with pytest.raises(CaraFileError, match="nope.mkv.*no such file"):
        VideoSource(tmp_path / "nope.mkv")
    bad = tmp_path / "bad.mkv"
    bad.write_bytes(b"this is not a video" * 100)
    with pytest.raises(CaraFileError, match="bad.mkv"):
        VideoSource(bad)
    empty = tmp_path / "empty_cam0"
    empty.mkdir()
    with pytest.raises(CaraFileError, match="empty_cam0.*no images"):
        VideoSource(empty)


def _take(paths: list[Path], n_frames: int, offsets=None) -> Take:
    offsets = offsets or [0] * len(paths)
    return Take(name="t", n_frames=n_frames, cameras=[
        CameraChannel(f"cam{i}", str(p), (W, H), frame_offset=o)
        for i, (p, o) in enumerate(zip(paths, offsets, strict=True))])


def test_take_frames_offset_blank_and_lru_bound(tmp_path, rng):
    a, b = make_frames(rng, 20), make_frames(rng, 20)
    pa = write_video(tmp_path / "t_cam0.mkv", a)
    pb = write_video(tmp_path / "t_cam1.mkv", b)
    one = W * H
    with TakeFrames(_take([pa, pb], 20, offsets=[0, 3]), cache_mb=5.5 * one / 1e6) as tf:
        np.testing.assert_array_equal(tf.get(4, 0), a[4])
        np.testing.assert_array_equal(tf.get(4, 1), b[7])  # video frame = take frame + 3
        blank = tf.get(18, 1)  # video frame 21 does not exist
        assert blank.shape == (H, W) and not blank.any()
        assert tf.get_cached(18, 1) is not None  # blank needs no decoding
        for f in range(10):
            tf.get(f, 0)
        assert tf.cache_used_bytes <= 5 * one
        assert tf.get_cached(9, 0) is not None and tf.get_cached(0, 0) is None
        img = tf.get(9, 0)
        with pytest.raises(ValueError):
            img[0, 0] = 1  # cached images are read-only
        with pytest.raises(IndexError):
            tf.get(20, 0)


def test_prefetch_fills_cache_and_reports_each_frame(tmp_path, rng):
    a = make_frames(rng, 30)
    paths = [write_video(tmp_path / f"t_cam{i}.mkv", a) for i in range(2)]
    ready: list[tuple[int, int]] = []
    lock = threading.Lock()

    def on_ready(frame: int, camera: int) -> None:
        with lock:
            ready.append((frame, camera))

    with TakeFrames(_take(paths, 30), on_ready=on_ready) as tf:
        assert tf.get_cached(5, 1) is None
        req = tf.prefetch(range(5, 25))
        assert req.wait(timeout=30)
        assert sorted(ready) == sorted((f, c) for f in range(5, 25) for c in range(2))
        for f in (5, 24):
            np.testing.assert_array_equal(tf.get_cached(f, 1), a[f])
        assert tf.get_cached(25, 0) is None


def test_prefetch_cancel_stops_decoding_and_close_is_clean(tmp_path, rng):
    a = make_frames(rng, 40)
    path = write_video(tmp_path / "t_cam0.mkv", a)
    started = threading.Event()
    release = threading.Event()

    def on_ready(frame: int, camera: int) -> None:
        started.set()
        release.wait(5)

    tf = TakeFrames(_take([path], 40), on_ready=on_ready, workers=1)
    req = tf.prefetch(range(40))
    assert started.wait(10)  # the first frame is decoded; the worker is in the callback
    req.cancel()
    release.set()
    assert req.wait(timeout=10)
    cached = sum(tf.get_cached(f, 0) is not None for f in range(40))
    assert 1 <= cached < 40
    # a newer request replaces (cancels) an older one
    r1 = tf.prefetch(range(40))
    r2 = tf.prefetch([39])
    assert r1.cancelled and not r2.cancelled
    tf.close()
    with pytest.raises(RuntimeError):
        tf.prefetch([0])


def test_missing_video_shows_blank_unless_strict(tmp_path):
    take = _take([tmp_path / "gone_cam0.mkv"], 5)
    with TakeFrames(take) as tf:
        assert not tf.get(2, 0).any()
    with TakeFrames(take, strict=True) as tf, pytest.raises(CaraFileError, match="gone_cam0"):
        tf.get(2, 0)


def test_truncated_video_frame_count_is_corrected(tmp_path, rng, caplog):
    """A copy that stopped part-way opens with the frames that are really there (the
    keyframe index counts them; the container header still claims 40)."""
    frames = make_frames(rng, 40)
    path = write_video(tmp_path / "t_cam0.mkv", frames)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])
    src = VideoSource(path)
    n = src.verify_frame_count()
    assert 0 < n < 40 and src.n_frames == n
    for i in (n - 1, 0, n // 2):
        np.testing.assert_array_equal(src.read(i), frames[i])
    with pytest.raises(IndexError):
        src.read(n)
    good = VideoSource(write_video(tmp_path / "u_cam0.mkv", frames))
    assert good.verify_frame_count() == 40
    np.testing.assert_array_equal(good.read(39), frames[39])


def test_reading_from_the_start_needs_no_seek(ffv1):
    """Frame 0 was decoded to open the file; reading 0, 1, 2... must not step back."""
    path, frames = ffv1
    src = VideoSource(path)
    for i in range(5):
        np.testing.assert_array_equal(src.read(i), frames[i])
    assert src._reader is not None and src._reader.seeks == 0
    np.testing.assert_array_equal(src.read(0), frames[0])


def test_reading_backwards_decodes_blocks_in_order(tmp_path, rng, monkeypatch):
    """Frame by frame towards the start (tracking backwards) costs one seek per block of
    BACKWARD_BLOCK frames, not one per image, and every image is still exact."""
    from carapost.io import video

    a = make_frames(rng, 40)
    take = _take([write_video(tmp_path / "t_cam0.mkv", a)], 40)
    moves = []
    original = video.AVReader._seek
    monkeypatch.setattr(video.AVReader, "_seek",
                        lambda self, index: (moves.append(index), original(self, index)))
    with TakeFrames(take, strict=True) as tf:
        for f in range(39, -1, -1):
            np.testing.assert_array_equal(tf.get(f, 0), a[f], err_msg=f"frame {f}")
    assert len(moves) <= 40 // video.BACKWARD_BLOCK + 2
    moves.clear()
    with TakeFrames(take, strict=True, cache_mb=0) as tf:  # no room for blocks
        for f in range(39, 29, -1):
            np.testing.assert_array_equal(tf.get(f, 0), a[f])
    assert len(moves) == 10


class _Freed:
    """Stands for a cached image: records when it is freed."""

    def __init__(self, log: list[int], key: int) -> None:
        self.log, self.key = log, key

    def __del__(self) -> None:
        self.log.append(self.key)


def test_free_in_slices_hands_the_gil_over_between_slices(monkeypatch):
    freed: list[int] = []
    handovers: list[int] = []  # images freed when the GIL was given away
    monkeypatch.setattr(video_module.time, "sleep", lambda s: handovers.append(len(freed)))
    images = {k: _Freed(freed, k) for k in range(21)}
    free_in_slices(images, slice_size=8)
    assert images == {} and sorted(freed) == list(range(21))
    assert handovers == [8, 16, 21]


def test_clear_cache_frees_outside_the_cache_lock(tmp_path, rng):
    frames = make_frames(rng, 6)
    path = write_video(tmp_path / "t_cam0.mkv", frames)
    tf = TakeFrames(_take([path], 6), cache_mb=50)
    try:
        for f in range(6):
            tf.get(f, 0)
        assert tf.cache_used_bytes == 6 * W * H
        lock_free: list[bool] = []

        class Probe:
            # freed among the images: a decoder (or the GUI thread's `get_cached`)
            # must find the lock free while a closing thread frees a full cache
            def __del__(self) -> None:
                got = tf._cache_lock.acquire(blocking=False)
                lock_free.append(got)
                if got:
                    tf._cache_lock.release()

        tf._cache[(99, 0)] = Probe()
        tf.clear_cache()
        assert lock_free == [True]
        assert tf.cache_used_bytes == 0 and tf.get_cached(3, 0) is None
        np.testing.assert_array_equal(tf.get(3, 0), frames[3])  # the cache fills again
        assert tf.cache_used_bytes == W * H
    finally:
        tf.close()
