"""The frame service: exact frames by request and by job, newest request wins, bounded
cache, read-ahead, and clear messages for missing or damaged videos."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost.io.decode import KeyframeIndex
from carapost.io.errors import CaraFileError
from carapost.io.frameservice import FrameService
from carapost.model.project import CameraChannel, Take

W, H = 80, 48
N = 150


def _frames(rng: np.random.Generator, n: int, cam: int) -> list[np.ndarray]:
    base = cv2.GaussianBlur(rng.integers(0, 256, (H, W), dtype=np.uint8), (5, 5), 0)
    out = []
    for i in range(n):
        img = np.roll(base, i, axis=1).copy()
        img[:3, :3] = i % 256
        img[3:6, :3] = cam
        out.append(img)
    return out


def _write(path: Path, frames: list[np.ndarray]) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H),
                             isColor=False)
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def _sequential(path: Path) -> list[np.ndarray]:
    """A fresh in-order decode by an independent reader (OpenCV)."""
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    return out


def _take(paths: list[Path | None], n: int) -> Take:
    cams = [CameraChannel(name=f"cam{i}", video_path=str(p) if p else "", image_size=(W, H))
            for i, p in enumerate(paths)]
    return Take(name="t", n_frames=n, cameras=cams)


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("fs")
    rng = np.random.default_rng(7)
    return [_write(folder / f"t_cam{c}.mkv", _frames(rng, N, c)) for c in range(2)]


def _wait_for(service: FrameService, frame: int, camera: int, timeout: float = 10.0):
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        img = service.get_cached(frame, camera)
        if img is not None:
            return img
        time.sleep(0.001)
    raise AssertionError(f"frame {frame} camera {camera} never arrived")


def test_requested_frames_are_bit_identical_forwards_and_backwards(videos):
    refs = [_sequential(p) for p in videos]
    assert all(len(r) == N for r in refs)
    rng = np.random.default_rng(3)
    positions = rng.integers(0, N, 200)
    with FrameService(_take(videos, N), cache_mb=0.5) as fs:  # ~65 images: evictions
        for k, frame in enumerate(positions):
            direction = 1 if k % 2 else -1
            fs.request(int(frame), direction=direction)
            for c in range(2):
                np.testing.assert_array_equal(_wait_for(fs, int(frame), c), refs[c][frame],
                                              err_msg=f"frame {frame} camera {c}")
        # stepping backwards then forwards through a stretch, as an artist scrubs
        for frame in list(range(120, 60, -1)) + list(range(60, 100)):
            fs.request(frame)
            np.testing.assert_array_equal(_wait_for(fs, frame, 1), refs[1][frame])
        assert fs.cache_used_bytes <= fs.cache_bytes


def test_jobs_get_exact_frames_from_other_threads(videos):
    refs = [_sequential(p) for p in videos]
    order = list(np.random.default_rng(5).integers(0, N, 60)) + list(range(N - 1, N - 30, -1))
    got: list[tuple[int, int, np.ndarray]] = []

    def job() -> None:
        for f in order:
            for c in range(2):
                got.append((int(f), c, fs.get(int(f), c)))

    with FrameService(_take(videos, N), cache_mb=2) as fs:
        t = threading.Thread(target=job)
        t.start()
        for f in range(0, N, 7):  # the view scrubs meanwhile
            fs.request(f)
        t.join(60)
        assert not t.is_alive()
    assert len(got) == 2 * len(order)
    for f, c, img in got:
        np.testing.assert_array_equal(img, refs[c][f])


def test_a_job_frame_decodes_every_camera_alongside(videos):
    with FrameService(_take(videos, N)) as fs:
        fs.get(77, 0)
        _wait_for(fs, 77, 1, timeout=5)  # camera 1 was queued with camera 0


def test_stale_requests_are_dropped(videos):
    with FrameService(_take(videos, N), read_ahead=0) as fs:
        decoded = []
        fs.on_ready = lambda f, c: decoded.append((f, c))
        for frame in range(0, N, 3):  # a fast scrub: far more requests than decodes
            fs.request(frame)
        last = (N - 1) // 3 * 3
        _wait_for(fs, last, 0)
        _wait_for(fs, last, 1)
        assert fs.dropped > 0
        requested = {f for f in range(0, N, 3)}
        served = {f for f, _ in decoded} & requested
        assert len(served) < len(requested)
        assert last in served


def test_read_ahead_follows_the_direction(videos):
    with FrameService(_take(videos, N), read_ahead=10) as fs:
        fs.request(50, direction=1)
        _wait_for(fs, 60, 0)
        assert fs.get_cached(48, 0) is not None  # decoded on the way from the keyframe
        fs.request(100, direction=-1)
        _wait_for(fs, 90, 1)
        # then a third as far the other way, so that a step back is a cache hit too
        _wait_for(fs, 103, 1)
        time.sleep(0.3)
        assert fs.get_cached(104, 1) is None and fs.get_cached(89 - 12, 1) is None


def test_a_step_back_after_a_jump_is_read_ahead_in_all_intra_videos(tmp_path, rng):
    """With a keyframe on every frame a jump decodes nothing before its target; the idle
    decoder still reads a few frames back, so Prev Frame finds them cached."""
    from carapost.io.encode import FFV1Writer

    frames = _frames(rng, 60, 0)
    path = tmp_path / "i_cam0.mkv"
    with FFV1Writer(path, (W, H), 60.0) as w:
        for img in frames:
            w.write(img)
    from carapost.io.video import VideoSource

    VideoSource(path).verify_frame_count()  # as importing does (else one decode more)
    with FrameService(_take([path], 60), read_ahead=9) as fs:
        fs.request(30, direction=1)
        _wait_for(fs, 39, 0)
        for f in (29, 28, 27):
            np.testing.assert_array_equal(_wait_for(fs, f, 0), frames[f])
        reader = fs.source(0)._reader
        assert reader.decoded == 9 + 1 + 3  # ahead, the target, behind: nothing twice
        time.sleep(0.2)
        assert fs.get_cached(26, 0) is None and fs.get_cached(40, 0) is None
        fs.set_read_ahead(9, playing=True)  # playing: forward only
        fs.request(10, direction=1)
        _wait_for(fs, 19, 0)
        time.sleep(0.2)
        assert fs.get_cached(9, 0) is None


def test_missing_and_truncated_videos_give_a_message_not_a_freeze(videos, tmp_path):
    data = videos[0].read_bytes()
    cut = tmp_path / "cut_cam1.mkv"
    cut.write_bytes(data[: len(data) // 2])
    take = _take([tmp_path / "gone_cam0.mkv", cut], N)
    with FrameService(take) as fs:
        t0 = time.perf_counter()
        fs.request(140)
        deadline = time.perf_counter() + 10
        while (fs.message(140, 0) is None or fs.message(140, 1) is None) \
                and time.perf_counter() < deadline:
            time.sleep(0.005)
        assert "gone_cam0.mkv" in fs.message(140, 0) and "no such file" in fs.message(140, 0)
        assert "cut_cam1.mkv has frames 0-" in fs.message(140, 1)
        assert time.perf_counter() - t0 < 10
        assert not fs.get_cached(140, 1).any()  # past the end: blank, said so
        assert fs.message(3, 1) is None
        fs.request(3)
        _wait_for(fs, 3, 1)
        with pytest.raises(CaraFileError, match="gone_cam0"):
            fs.get(5, 0)


def test_keyframe_index_is_cached_and_invalidated(tmp_path, rng):
    path = _write(tmp_path / "k_cam0.mkv", _frames(rng, 30, 0))
    from carapost.io.decode import AVReader

    reader = AVReader(path)
    assert reader.n_frames == 30 and reader.index.max_interval <= 12
    stored = KeyframeIndex.load(path)
    assert stored is not None and np.array_equal(stored.pts, reader.index.pts)
    _write(path, _frames(rng, 20, 0))  # the file changes: the stored index is stale
    assert KeyframeIndex.load(path) is None
    assert AVReader(path).n_frames == 20


def test_a_stored_index_that_fails_to_parse_is_rebuilt(tmp_path, rng, monkeypatch):
    """CPython 3.11 can raise a spurious SystemError while threads parse at once
    (python/cpython#106905), inside np.load's header parse: the stored index then
    counts as missing and is rebuilt from the file, never a decoder thread's death."""
    from carapost.io import decode

    path = _write(tmp_path / "p_cam0.mkv", _frames(rng, 30, 0))
    assert decode.AVReader(path).n_frames == 30  # stores the index
    assert KeyframeIndex.load(path) is not None

    def spurious(*args, **kwargs):
        raise SystemError("AST constructor recursion depth mismatch (before=51, after=48)")

    monkeypatch.setattr(decode.np, "load", spurious)
    assert KeyframeIndex.load(path) is None
    assert decode.AVReader(path).n_frames == 30


def test_opening_decodes_only_the_frame_wanted(tmp_path, rng):
    """A jump right after opening decodes from the keyframe before the target only: no
    probe of frame 0, and the check that the last frame decodes is done once per file
    (the stored index keeps it), not on every opening."""
    frames = _frames(rng, 60, 0)
    path = _write(tmp_path / "o_cam0.mkv", frames)
    from carapost.io.video import VideoSource

    assert VideoSource(path).verify_frame_count() == 60  # as importing the take does
    assert KeyframeIndex.load(path).decodable == 60
    target = 41
    with FrameService(_take([path], 60)) as fs:
        np.testing.assert_array_equal(fs.get(target, 0), frames[target])
        reader = fs.source(0)._reader
        assert reader.decoded == target - reader.index.keyframe_before(target) + 1
    # A file never checked: the check runs while the decoder is idle, and is stored.
    fresh = _write(tmp_path / "p_cam0.mkv", frames)
    with FrameService(_take([fresh], 60)) as fs:
        fs.request(5)
        _wait_for(fs, 5, 0)
        deadline = time.perf_counter() + 10
        while KeyframeIndex.load(fresh) is None or KeyframeIndex.load(fresh).decodable is None:
            assert time.perf_counter() < deadline, "the last frame was never checked"
            time.sleep(0.01)
        assert KeyframeIndex.load(fresh).decodable == 60


def test_proxies_stand_in_while_playing_and_never_for_processing(videos):
    from carapost.io.proxy import existing_proxy, proxy_path, write_proxy

    refs = [_sequential(p) for p in videos]
    calls = []
    assert write_proxy(videos[0], progress=lambda d, n: calls.append(d) or d < 10) is None
    assert existing_proxy(videos[0]) is None  # cancelled: no partial file left
    assert not list(proxy_path(videos[0]).parent.glob("*partial*"))
    for v in videos:
        assert write_proxy(v) == existing_proxy(v)
    with FrameService(_take(videos, N)) as fs:
        assert fs.attach_proxies() == 2
        fs.set_read_ahead(30, playing=True)
        assert fs.showing_proxies
        fs.request(90, direction=1)
        t0 = time.perf_counter()
        while fs.get_display(90, 1) is None and time.perf_counter() - t0 < 10:
            time.sleep(0.002)
        shown = fs.get_display(90, 1)
        assert shown is not None and fs.get_cached(90, 1) is None  # a proxy image
        diff = np.abs(shown.astype(int) - refs[1][90].astype(int))
        assert diff.mean() < 3 and not np.array_equal(shown, refs[1][90])
        # processing reads the originals, bit for bit, even while playing
        np.testing.assert_array_equal(fs.get(90, 1), refs[1][90])
        fs.set_read_ahead(24, playing=False)
        assert not fs.showing_proxies and fs.get_display(91, 1) is None


def test_a_changed_video_never_plays_a_stale_proxy(tmp_path, rng):
    from carapost.io.proxy import existing_proxy, write_proxy

    path = _write(tmp_path / "p_cam0.mkv", _frames(rng, 20, 0))
    write_proxy(path)
    assert existing_proxy(path) is not None
    _write(path, _frames(rng, 25, 0))
    assert existing_proxy(path) is None


def test_idle_decoders_do_not_spin_on_missing_or_short_videos(videos, tmp_path):
    data = videos[0].read_bytes()
    cut = tmp_path / "short_cam1.mkv"
    cut.write_bytes(data[: len(data) // 3])
    with FrameService(_take([tmp_path / "gone_cam0.mkv", cut], N), read_ahead=40) as fs:
        fs.request(N - 20, direction=1)
        deadline = time.perf_counter() + 10
        while fs.message(N - 20, 1) is None and time.perf_counter() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)
        t0 = time.process_time()
        time.sleep(1.0)
        assert time.process_time() - t0 < 0.05  # the decoder threads wait, not spin


def test_decoder_threads_started_by_the_launcher_serve_and_close(videos):
    """The first request of a take hands its decoder threads to the launcher thread
    (`carapost.io.launcher`; the GUI thread does not wait for them to run): the frame
    still arrives exact, and a service closed at once after its first request, its
    threads perhaps not started yet, leaves none behind."""
    from carapost.io import launcher

    with FrameService(_take(videos, N)) as fs:
        fs.request(7)
        threads = [c.thread for c in fs._cams]
        assert all(t is not None for t in threads)
        np.testing.assert_array_equal(_wait_for(fs, 7, 0), _sequential(videos[0])[7])
    assert not any(t.is_alive() for t in threads)
    for _ in range(20):
        fs = FrameService(_take(videos, N))
        fs.request(3)
        fs.close()
        assert not any(c.thread.is_alive() for c in fs._cams if c.thread is not None)
    # a thread never handed to the launcher is reported, not waited for forever
    assert not launcher.started(threading.Thread(target=lambda: None), timeout=0.05)
