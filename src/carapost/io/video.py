"""Frame access to a take's camera videos: random access, an LRU cache and read-ahead.

Two layers:

- `VideoSource` reads one camera: a video file in any container OpenCV reads (FFV1
  ``.mkv``, ``.mp4``, ``.avi``, ``.mov``) or an image-sequence folder (``.png``, ``.tif``,
  ``.jpg``; files in natural order). Frames come back as 8-bit grayscale ``[H, W]``.
- `TakeFrames` serves every camera of a `~carapost.model.project.Take` by take frame
  (applying each camera's ``frame_offset``), keeps recently used images in an LRU cache
  bounded in megabytes and decodes ahead on background threads for playback.

Random access. Reading the next frame of a video is a plain decode; any other frame is
reached by seeking (``CAP_PROP_POS_FRAMES``) or, for short forward jumps, by skipping
frames. Seeking is checked once per file the first time it is needed: a few frames near
the start are decoded in order and compared bit for bit with the same frames reached by
seeks. If they differ (containers without a usable index), the source falls back to
decoding forward from the current position, or from the start, which is slow but exact.

Threads. Each `VideoSource` has a lock, so any thread may read from it. `TakeFrames`
decodes prefetch requests on a small thread pool, one task per camera, so a camera's
frames are decoded in order (sequential decoding is several times faster than seeking).
The GUI thread calls `TakeFrames.get_cached` (never decodes) and `TakeFrames.prefetch`
(never blocks); ``on_ready(frame, camera)`` is called from a worker thread when a
requested image lands in the cache, and a GUI adapts it to a queued Qt signal.

Images are returned read-only (they are shared with the cache); copy before changing.
Camera ``rotation`` is a display setting and is not applied here: 2D coordinates in
carapost always refer to the raw image.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.io.atomic import check_input_file
from carapost.io.decode import AVReader, av_available
from carapost.io.errors import CaraFileError

log = logging.getLogger("carapost.io")

__all__ = [
    "IMAGE_EXTENSIONS",
    "VIDEO_EXTENSIONS",
    "PrefetchRequest",
    "TakeFrames",
    "VideoSource",
    "image_sequence_files",
    "natural_key",
]

#: Frames decoded in order at once when a camera is read backwards (see `TakeFrames.get`).
BACKWARD_BLOCK = 16

#: Cached images freed between two hand-overs of the GIL when a cache is emptied
#: (`free_in_slices`): 8 images of 1280x720 take ~0.5 ms to free.
FREE_SLICE = 8

#: Containers imported as camera videos (anything OpenCV's FFmpeg reads would do; these
#: are the ones a take is looked up by).
VIDEO_EXTENSIONS = (".mkv", ".mp4", ".avi", ".mov")
#: Image files of an image-sequence folder.
IMAGE_EXTENSIONS = (".png", ".tif", ".tiff", ".jpg", ".jpeg")

# A forward jump of at most this many frames is decoded through instead of seeking: an
# OpenCV seek decodes from the keyframe before the target, about 12 frames on average
# for its own FFV1/mp4v writers (measured), so shorter jumps are cheaper decoded.
_SKIP_FORWARD = 12
# Frames decoded in order by the seek check (covers a few keyframe intervals of typical
# encoder settings; OpenCV's FFV1 and mp4v writers put a keyframe every 12 frames).
_SEEK_PROBE = 30

ReadyCallback = Callable[[int, int], None]


def natural_key(text: str) -> list[Any]:
    """Sort key that orders embedded numbers by value (``cam2`` before ``cam10``)."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", text)]


def image_sequence_files(folder: str | Path) -> list[Path]:
    """Image files of an image-sequence folder, in natural order (empty if none)."""
    folder = Path(folder)
    try:
        files = [
            p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()
        ]
    except OSError:
        return []
    return sorted(files, key=lambda p: natural_key(p.name))


def _to_gray(image: NDArray[Any]) -> NDArray[np.uint8]:
    if image.ndim == 3:
        if image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
        elif image.shape[2] == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        else:
            image = image[..., 0]
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = np.clip(image, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(image)


class VideoSource:
    """Random access to the frames of one camera.

    Parameters
    ----------
    path : str or Path
        A video file (any container OpenCV reads) or an image-sequence folder.
    seek : {"auto", "seek", "decode"}
        How frames other than the next one are reached: ``"auto"`` checks once that
        seeking is exact and falls back to decoding forward when it is not; ``"seek"``
        trusts seeking; ``"decode"`` never seeks (always exact, slow backwards).
    probe : bool
        Decode frame 0 while opening, so a file that cannot be decoded at all fails
        here (importing a take). False opens without decoding (the frame service: the
        first frame wanted is rarely frame 0, and a read error says the same later).
    decoder_threads : int
        FFmpeg's decoding threads for a video read through PyAV (0: FFmpeg's choice;
        see `carapost.io.decode.AVReader`).

    Attributes
    ----------
    path : Path
    n_frames : int
        Number of frames.
    size : tuple of int
        (width, height) in pixels.
    fps : float
        Frame rate stored in the container (0.0 when unknown, e.g. image sequences).
    is_sequence : bool
        True for an image-sequence folder.

    Raises
    ------
    CaraFileError
        If the file or folder is missing, is not a video OpenCV can decode, holds no
        frame, or is an image folder without images.
    """

    def __init__(self, path: str | Path, *, seek: str = "auto", probe: bool = True,
                 decoder_threads: int = 0) -> None:
        if seek not in ("auto", "seek", "decode"):
            raise ValueError(f"seek must be 'auto', 'seek' or 'decode', got {seek!r}")
        self.path = Path(path)
        self._lock = threading.Lock()
        self._cap: Any = None
        self._next = 0  # index the next cap.read() returns
        self._seek_mode = seek
        self._seek_ok: bool | None = {"auto": None, "seek": True, "decode": False}[seek]
        self._files: list[Path] = []
        self._frame0: NDArray[np.uint8] | None = None
        self._reader: AVReader | None = None
        self.fps = 0.0
        if not self.path.exists():
            raise CaraFileError(self.path, "no such file or folder")
        self.is_sequence = self.path.is_dir()
        if self.is_sequence:
            self._files = image_sequence_files(self.path)
            if not self._files:
                raise CaraFileError(
                    self.path,
                    "the folder holds no images (" + ", ".join(IMAGE_EXTENSIONS) + ")",
                )
            first = self._read_image(0)
            self.n_frames = len(self._files)
        elif seek != "decode" and av_available():
            # FFmpeg's demuxer with a keyframe index: exact seeks at a keyframe interval's
            # cost (OpenCV's seek re-reads from far back: ~0.9 s per jump on FFV1).
            check_input_file(self.path)  # a FIFO or device would block the demuxer
            self._reader = AVReader(self.path, threads=decoder_threads)
            self.n_frames = self._reader.n_frames
            self.fps = self._reader.fps
            self._seek_ok = True
            if not probe:
                self.size = self._reader.size
                return
            first = self._reader.read(0)
            self._frame0 = first
        else:
            check_input_file(self.path)  # a FIFO or device would block the demuxer
            self._open()
            self.n_frames = int(round(self._cap.get(cv2.CAP_PROP_FRAME_COUNT)))
            fps = float(self._cap.get(cv2.CAP_PROP_FPS))
            self.fps = fps if np.isfinite(fps) and fps > 0 else 0.0
            ok, image = self._cap.read()
            if not ok or image is None:
                self._release()
                raise CaraFileError(self.path, "no frame could be decoded (damaged or empty?)")
            self._next = 1
            first = _to_gray(image)
            # Frame 0 is kept: reading a take from its start would otherwise begin with
            # a step back (and the first-seek check, ~1.2 s for a 1280x720 FFV1 file).
            self._frame0 = first
            if self.n_frames <= 0:
                # Some containers carry no frame count: count by decoding once.
                n = 1
                while self._cap.grab():
                    n += 1
                self.n_frames = n
                self._rewind()
        self.size = (int(first.shape[1]), int(first.shape[0]))

    # -- opening -----------------------------------------------------------------------
    def _open(self) -> None:
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise CaraFileError(
                self.path, "cannot be opened as a video (unknown container or codec, or damaged)"
            )
        # Gray videos (FFV1/PNG-style Y800) decode straight to [H, W] without the
        # round trip through BGR; other pixel formats keep OpenCV's conversion.
        fmt = int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT))
        if fmt > 0 and fmt.to_bytes(4, "little") in (b"Y800", b"GREY", b"GRAY"):
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0.0)
        self._cap = cap
        self._next = 0

    def _release(self) -> None:
        if self._reader is not None:
            self._reader.close()
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _rewind(self) -> None:
        self._release()
        self._open()

    def close(self) -> None:
        """Release the decoder (the source reopens itself if read again)."""
        with self._lock:
            self._release()

    def __enter__(self) -> VideoSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"VideoSource({str(self.path)!r}, n_frames={self.n_frames}, size={self.size})"

    # -- reading -------------------------------------------------------------------------
    def read(self, index: int) -> NDArray[np.uint8]:
        """Frame ``index`` as an 8-bit grayscale image.

        Parameters
        ----------
        index : int
            Zero-based frame index in this file, ``0 <= index < n_frames``.

        Returns
        -------
        ndarray, shape (H, W) uint8

        Raises
        ------
        IndexError
            If ``index`` is outside the video.
        CaraFileError
            If the frame cannot be decoded.
        """
        index = int(index)
        if not 0 <= index < self.n_frames:
            raise IndexError(f"{self.path.name}: frame {index} is outside 0-{self.n_frames - 1}")
        with self._lock:
            if self.is_sequence:
                return self._read_image(index)
            return self._read_video(index)

    def _read_image(self, index: int) -> NDArray[np.uint8]:
        file = self._files[index]
        check_input_file(file)  # a FIFO named like an image would block imread
        try:
            image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
            if image is None:
                raise CaraFileError(file, "cannot be read as an image (damaged or unsupported)")
            return _to_gray(image)
        except cv2.error as exc:  # OpenCV refuses some damaged headers with an exception
            raise CaraFileError(file, f"cannot be read as an image ({exc.err or exc})") from None

    def _read_video(self, index: int) -> NDArray[np.uint8]:
        if index == 0 and self._frame0 is not None:
            return self._frame0.copy()
        if self._reader is not None:
            return self._reader.read(index)
        if self._cap is None:
            self._open()
        if index != self._next:
            self._position(index)
        ok, image = self._cap.read()
        if not ok or image is None:
            self._next = -1  # unknown position: the next read seeks again
            raise CaraFileError(self.path, f"frame {index} could not be decoded")
        self._next = index + 1
        return _to_gray(image)

    def _position(self, index: int) -> None:
        """Make the next ``read`` return frame ``index`` (lock held)."""
        ahead = index - self._next
        if 0 < ahead <= _SKIP_FORWARD and self._next >= 0:
            self._skip(ahead)
            return
        if self._seek_ok is None:
            self._seek_ok = self._check_seek()
        if self._seek_ok:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, float(index))
            self._next = index
            return
        if self._next < 0 or index < self._next:
            self._rewind()
        self._skip(index - self._next)

    def _skip(self, count: int) -> None:
        for _ in range(count):
            if not self._cap.grab():
                failed = self._next
                self._next = -1
                raise CaraFileError(self.path, f"frame {failed} could not be decoded")
            self._next += 1

    def _check_seek(self) -> bool:
        """Whether seeking lands bit-exactly on the requested frame (lock held)."""
        probe = min(self.n_frames, _SEEK_PROBE)
        if probe < 3:
            return True
        self._rewind()
        frames = []
        for _ in range(probe):
            ok, image = self._cap.read()
            if not ok:
                break
            frames.append(image)
        self._next = len(frames)
        if len(frames) < 3:
            return False
        # Out of order: late, early, middle, and one just after a likely keyframe.
        targets = sorted({len(frames) - 1, 1, len(frames) // 2, min(13, len(frames) - 1)},
                         reverse=True)
        exact = True
        for target in targets:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, float(target))
            ok, image = self._cap.read()
            if not ok or image is None or not np.array_equal(image, frames[target]):
                exact = False
                break
        self._rewind()
        if not exact:
            log.warning("%s: seeking is not frame-exact; decoding forward instead (slower)",
                        self.path.name)
        return exact

    def verify_frame_count(self) -> int:
        """Check that the last frame decodes; if not, count the frames by decoding.

        Container frame counts are estimates for some files (e.g. from the duration).
        Returns the (possibly corrected) ``n_frames``.
        """
        if self.is_sequence or self.n_frames < 2:
            return self.n_frames
        if self._reader is not None:
            # The keyframe index counted the packets; a file cut mid-packet leaves a
            # last frame that does not decode (checked once per file: the index keeps it).
            with self._lock:
                self.n_frames = self._reader.verify()
            return self.n_frames
        with self._lock:
            if self._cap is None:
                self._open()
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, float(self.n_frames - 1))
            ok = self._cap.grab()
            extra = self._cap.grab() if ok else False
            if not ok or extra:
                stated = self.n_frames
                self._rewind()
                n = 0
                while self._cap.grab():
                    n += 1
                self.n_frames = n
                log.warning("%s: the container says %d frames but %d decode; using %d",
                            self.path.name, stated, n, n)
            self._rewind()
        return self.n_frames

    @property
    def seek_exact(self) -> bool | None:
        """Result of the seek check (None until needed; always True for image folders)."""
        return True if self.is_sequence else self._seek_ok


class PrefetchRequest:
    """Handle of one `TakeFrames.prefetch` call.

    ``cancel()`` stops decoding at the next frame boundary; ``done()`` tells whether
    every task has finished (or was cancelled).
    """

    def __init__(self) -> None:
        self._cancel = threading.Event()
        self._futures: list[Future[None]] = []

    def cancel(self) -> None:
        """Stop decoding this request's remaining frames."""
        self._cancel.set()
        for fut in self._futures:
            fut.cancel()

    @property
    def cancelled(self) -> bool:
        """True once `cancel` was called."""
        return self._cancel.is_set()

    def done(self) -> bool:
        """True when no task of this request is still queued or running."""
        return all(f.done() for f in self._futures)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until done (for scripts and tests; never call from a GUI thread)."""
        from concurrent.futures import wait

        _, pending = wait(self._futures, timeout=timeout)
        return not pending


def free_in_slices(images: dict[Any, Any], slice_size: int = FREE_SLICE) -> None:
    """Empty ``images`` (e.g. a cache of decoded frames) ``slice_size`` items at a time,
    handing the GIL to any waiting thread between slices.

    Each image of a cache is a separate allocation that freeing gives back to the
    system (a ``munmap`` for a 1280x720 frame: 50-100 us, more on a loaded machine).
    ``dict.clear`` frees them all in one C call that holds the GIL throughout: 400
    cached frames kept the GUI thread from running for 28-81 ms when the previous take
    was closed behind it; in slices its longest wait is 1-4 ms (measured on 2 loaded
    cores, docs/benchmarks.md).

    Parameters
    ----------
    images : dict
        Emptied in place; nothing else may be using it.
    slice_size : int
        Items freed between two hand-overs of the GIL.
    """
    while images:
        for _ in range(min(slice_size, len(images))):
            images.popitem()
        time.sleep(0)  # releases the GIL; a thread that asked for it takes it now


class TakeFrames:
    """Images of every camera of a take, by take frame, with cache and read-ahead.

    Parameters
    ----------
    take : Take
        The take; its cameras' ``video_path``, ``image_size`` and ``frame_offset``
        are used.
    cache_mb : float
        Upper bound of the image cache in megabytes (least recently used images go).
    workers : int
        Decoding threads for `prefetch`.
    on_ready : callable, optional
        ``on_ready(frame, camera)``, called from a worker thread whenever a prefetched
        image has entered the cache. May also be set later as an attribute.
    strict : bool
        Raise `CaraFileError` for a camera whose video is missing or unreadable. When
        False (viewing), such a camera shows blank images and one warning is logged.

    Notes
    -----
    Video frame = take frame + ``frame_offset``; outside the video the image is blank
    (zeros of the camera's size).
    """

    def __init__(
        self,
        take: Any,
        *,
        cache_mb: float = 512.0,
        workers: int = 2,
        on_ready: ReadyCallback | None = None,
        strict: bool = False,
    ) -> None:
        if cache_mb < 0:
            raise ValueError(f"cache_mb must be >= 0, got {cache_mb}")
        self.take = take
        self.cache_bytes = int(cache_mb * 1e6)
        self.on_ready = on_ready
        self.strict = strict
        self._cache: OrderedDict[tuple[int, int], NDArray[np.uint8]] = OrderedDict()
        self._cache_used = 0
        self._cache_lock = threading.Lock()
        self._sources: dict[int, VideoSource | None] = {}
        self._source_lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=max(1, int(workers)),
                                        thread_name_prefix="carapost-frames")
        self._current: PrefetchRequest | None = None
        self._closed = False
        self._blank: dict[int, NDArray[np.uint8]] = {}
        self._last_get: dict[int, int] = {}  # camera -> frame of its last `get`

    # -- sources -------------------------------------------------------------------------
    def source(self, camera: int) -> VideoSource | None:
        """The opened source of a camera (None when its video is missing and not strict)."""
        with self._source_lock:
            if camera in self._sources:
                return self._sources[camera]
            cam = self.take.cameras[camera]
            src: VideoSource | None = None
            try:
                if not cam.video_path:
                    raise CaraFileError(f"<{cam.name}>", "the camera has no video file")
                src = VideoSource(cam.video_path)
            except CaraFileError as exc:
                if self.strict:
                    raise
                log.warning("Camera %s shows no images: %s", cam.name, exc)
            self._sources[camera] = src
            return src

    def _blank_image(self, camera: int) -> NDArray[np.uint8]:
        img = self._blank.get(camera)
        if img is None:
            w, h = self.take.cameras[camera].image_size
            img = np.zeros((int(h), int(w)), dtype=np.uint8)
            img.flags.writeable = False
            self._blank[camera] = img
        return img

    def _video_index(self, frame: int, camera: int) -> int | None:
        """Index into the camera's video, or None when outside it (or no video)."""
        index = int(frame) + int(self.take.cameras[camera].frame_offset)
        src = self.source(camera)
        if src is None or not 0 <= index < src.n_frames:
            return None
        return index

    # -- cache ---------------------------------------------------------------------------
    def _cache_get(self, key: tuple[int, int]) -> NDArray[np.uint8] | None:
        with self._cache_lock:
            img = self._cache.get(key)
            if img is not None:
                self._cache.move_to_end(key)
            return img

    def _cache_put(self, key: tuple[int, int], img: NDArray[np.uint8]) -> None:
        img.flags.writeable = False
        evicted = []  # freed after the lock is released: the GUI's lookups never wait
        with self._cache_lock:
            old = self._cache.pop(key, None)
            if old is not None:
                self._cache_used -= old.nbytes
                evicted.append(old)
            if img.nbytes > self.cache_bytes:
                return
            self._cache[key] = img
            self._cache_used += img.nbytes
            while self._cache_used > self.cache_bytes:
                _, dropped = self._cache.popitem(last=False)
                self._cache_used -= dropped.nbytes
                evicted.append(dropped)
        del evicted

    @property
    def cache_used_bytes(self) -> int:
        """Bytes currently held by cached images."""
        return self._cache_used

    def clear_cache(self) -> None:
        """Forget every cached image (e.g. after Relocate Files or an offset change).

        The images are freed outside the cache lock and a few at a time
        (`free_in_slices`), so a thread clearing a full cache (closing a take) never
        holds the GIL for long.
        """
        with self._cache_lock:
            images, self._cache = self._cache, OrderedDict()
            self._cache_used = 0
        free_in_slices(images)

    def reset_sources(self) -> None:
        """Reopen videos on next use (after a camera's video path changed)."""
        with self._source_lock:
            for src in self._sources.values():
                if src is not None:
                    src.close()
            self._sources.clear()
            self._blank.clear()
        self.clear_cache()

    # -- access --------------------------------------------------------------------------
    def _check(self, frame: int, camera: int) -> None:
        if not 0 <= camera < self.take.n_cameras:
            raise IndexError(f"camera {camera} is outside 0-{self.take.n_cameras - 1}")
        if not 0 <= frame < max(self.take.n_frames, 1):
            raise IndexError(f"frame {frame} is outside the take (0-{self.take.n_frames - 1})")

    def get(self, frame: int, camera: int) -> NDArray[np.uint8]:
        """Image of ``camera`` at take ``frame``, decoding it now if it is not cached.

        A camera read backwards frame by frame (tracking towards the start of a take) has
        the block of `BACKWARD_BLOCK` frames ending at a missing one decoded in order and
        cached: one seek per block instead of one per image.

        Returns
        -------
        ndarray, shape (H, W) uint8, read-only
        """
        frame, camera = int(frame), int(camera)
        self._check(frame, camera)
        previous = self._last_get.get(camera)
        self._last_get[camera] = frame
        index = self._video_index(frame, camera)
        if index is None:
            return self._blank_image(camera)
        key = (frame, camera)
        img = self._cache_get(key)
        if img is None:
            src = self.source(camera)
            assert src is not None
            if previous == frame + 1 and not src.is_sequence and self._holds_blocks():
                for f in range(max(frame - BACKWARD_BLOCK + 1, 0), frame):
                    i = self._video_index(f, camera)
                    if i is not None and self._cache_get((f, camera)) is None:
                        self._cache_put((f, camera), src.read(i))
            img = src.read(index)
            self._cache_put(key, img)
        return img

    def _holds_blocks(self) -> bool:
        """Whether the cache holds a backward block of every camera twice over."""
        size = sum(int(w) * int(h) for w, h in (c.image_size for c in self.take.cameras))
        return self.cache_bytes >= 2 * BACKWARD_BLOCK * size

    def get_cached(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        """The image if it can be had without decoding (cached or blank), else None."""
        frame, camera = int(frame), int(camera)
        self._check(frame, camera)
        key = (frame, camera)
        img = self._cache_get(key)
        if img is not None:
            return img
        with self._source_lock:
            opened = camera in self._sources
        if opened and self._video_index(frame, camera) is None:
            return self._blank_image(camera)
        return None

    def prefetch(
        self,
        frames: Iterable[int],
        cameras: Sequence[int] | None = None,
        *,
        replace: bool = True,
    ) -> PrefetchRequest:
        """Decode images on the worker threads; returns at once.

        Parameters
        ----------
        frames : iterable of int
            Take frames, in the order they are wanted (e.g. from the current frame on).
        cameras : sequence of int, optional
            Cameras to decode (default: all).
        replace : bool
            Cancel the previous request first (playback: only the newest request matters).

        Returns
        -------
        PrefetchRequest
            Handle with ``cancel()``; ``on_ready`` reports each image as it lands.
        """
        if self._closed:
            raise RuntimeError("TakeFrames is closed")
        cams = range(self.take.n_cameras) if cameras is None else [int(c) for c in cameras]
        frame_list = [int(f) for f in frames if 0 <= int(f) < self.take.n_frames]
        request = PrefetchRequest()
        if replace and self._current is not None:
            self._current.cancel()
        self._current = request
        for cam in cams:
            if not 0 <= cam < self.take.n_cameras:
                raise IndexError(f"camera {cam} is outside 0-{self.take.n_cameras - 1}")
            wanted = [f for f in frame_list if self._cache_get((f, cam)) is None]
            if wanted:
                request._futures.append(self._pool.submit(self._decode, wanted, cam, request))
        return request

    def _decode(self, frames: list[int], camera: int, request: PrefetchRequest) -> None:
        for frame in frames:
            if request.cancelled or self._closed:
                return
            try:
                index = self._video_index(frame, camera)
                if index is None:
                    continue
                if self._cache_get((frame, camera)) is None:
                    src = self.source(camera)
                    assert src is not None
                    self._cache_put((frame, camera), src.read(index))
            except (CaraFileError, IndexError) as exc:
                log.warning("Camera %s, frame %d: %s", self.take.cameras[camera].name, frame, exc)
                return
            callback = self.on_ready
            if callback is not None and not request.cancelled:
                try:
                    callback(frame, camera)
                except Exception:  # a broken listener must not kill decoding
                    log.exception("on_ready callback failed")

    def close(self) -> None:
        """Cancel pending decoding, stop the threads and release the videos."""
        if self._closed:
            return
        self._closed = True
        if self._current is not None:
            self._current.cancel()
        self._pool.shutdown(wait=True, cancel_futures=True)
        with self._source_lock:
            for src in self._sources.values():
                if src is not None:
                    src.close()
            self._sources.clear()
        self.clear_cache()

    def __enter__(self) -> TakeFrames:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
