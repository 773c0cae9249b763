"""Frame-exact random access to a video file through FFmpeg's demuxer (PyAV).

`KeyframeIndex` lists every frame's presentation timestamp and which frames are
keyframes. It is built once per file by demuxing (reading packets without decoding:
~60 ms per 1,000 frames of 1280x720 FFV1) and kept in the user cache, keyed by the
file's absolute path and checked against its size and modification time, so a file that
changed is indexed again. `AVReader` uses it to reach frame ``k``: a seek to the last
keyframe at or before ``k`` and a decode of the frames between (on average half a
keyframe interval), where OpenCV's ``CAP_PROP_POS_FRAMES`` seek takes ~0.9 s per jump on
the same files (measured, docs/benchmarks.md). Reading the next frame is a plain decode.

Images come back as 8-bit grayscale ``[H, W]``: 8-bit gray streams as stored, 16-bit
gray shifted to 8 bits, colour streams converted through BGR with OpenCV's weights, so
the pixels are those `cv2.VideoCapture` gives (the tests compare them bit for bit).

The cache folder is ``$CARAPOST_CACHE_DIR`` or ``$XDG_CACHE_HOME/carapost`` (default
``~/.cache/carapost``), subfolder ``video-index``; deleting it loses nothing.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.io.errors import CaraFileError

log = logging.getLogger("carapost.io")

__all__ = ["AVReader", "KeyframeIndex", "av_available", "cache_dir"]

# Format of the stored index (bump when its meaning changes: old files are rebuilt).
_INDEX_VERSION = 1
#: one KeyframeIndex.load at a time (see there)
_LOAD_LOCK = threading.Lock()


def av_available() -> bool:
    """Whether PyAV can be imported (it is a core dependency; a broken install falls
    back to OpenCV's reader)."""
    try:
        import av  # noqa: F401
    except ImportError:
        return False
    return True


def cache_dir() -> Path:
    """carapost's user cache folder (``$CARAPOST_CACHE_DIR``, else the XDG cache)."""
    env = os.environ.get("CARAPOST_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "carapost"


class KeyframeIndex:
    """Timestamps and keyframes of every frame of one video stream.

    Parameters
    ----------
    pts : ndarray, shape (N,) int64
        Presentation timestamp of frame ``i`` (stream time base), increasing.
    keyframe : ndarray, shape (N,) bool
        Whether frame ``i`` is a keyframe (decoding can start there).
    decodable : int, optional
        Frames known to decode (the last one was decoded once: `AVReader.verify`);
        None until checked. A file cut mid-packet lists a last frame that does not.

    Examples
    --------
    >>> import numpy as np
    >>> ix = KeyframeIndex(np.arange(0, 50, 10), np.array([1, 0, 0, 1, 0], bool))
    >>> ix.n_frames, ix.keyframe_before(2), ix.keyframe_before(4)
    (5, 0, 3)
    """

    def __init__(self, pts: NDArray[np.int64], keyframe: NDArray[np.bool_],
                 decodable: int | None = None) -> None:
        self.pts = np.asarray(pts, np.int64)
        self.decodable = None if decodable is None else int(decodable)
        self.keyframe = np.asarray(keyframe, bool)
        if len(self.keyframe):
            self.keyframe[0] = True  # decoding always starts at the first frame
        self._keys = np.flatnonzero(self.keyframe)

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(len(self.pts))

    @property
    def max_interval(self) -> int:
        """Longest run of frames from one keyframe to the next."""
        edges = np.append(self._keys, self.n_frames)
        return int(np.diff(edges).max()) if len(edges) > 1 else self.n_frames

    def keyframe_before(self, index: int) -> int:
        """The last keyframe at or before frame ``index``."""
        if 0 <= index < len(self.keyframe) and self.keyframe[index]:
            # all-intra videos (every frame of ours): no search, which costs ~40 us of
            # GIL on every frame a decoder thread reads
            return int(index)
        k = int(np.searchsorted(self._keys, index, side="right")) - 1
        return int(self._keys[max(k, 0)])

    # -- building and storing ----------------------------------------------------------
    @classmethod
    def build(cls, container: Any, stream: Any) -> KeyframeIndex:
        """Index a stream by demuxing the whole file (packets are read, not decoded)."""
        pts: list[int] = []
        keys: list[bool] = []
        try:
            for packet in container.demux(stream):
                if packet.pts is None or packet.size == 0:
                    continue
                pts.append(int(packet.pts))
                keys.append(bool(packet.is_keyframe))
        except Exception as exc:  # a truncated file ends the index at the damage
            log.warning("%s: the file ends early (%s); %d frames are readable",
                        getattr(container, "name", "video"), exc, len(pts))
        order = np.argsort(np.asarray(pts, np.int64), kind="stable")
        return cls(np.asarray(pts, np.int64)[order], np.asarray(keys, bool)[order])

    @staticmethod
    def _cache_file(path: Path) -> Path:
        digest = hashlib.sha1(str(path.absolute()).encode("utf-8")).hexdigest()[:20]
        return cache_dir() / "video-index" / f"{digest}.npz"

    @classmethod
    def load(cls, path: Path) -> KeyframeIndex | None:
        """The stored index of ``path`` if it is still valid for the file, else None."""
        file = cls._cache_file(path)
        try:
            st = path.stat()
            # np.load parses each array's header with ast.literal_eval, and CPython
            # 3.11 can raise a spurious "AST constructor recursion depth mismatch"
            # SystemError when threads parse at once (python/cpython#106905): the
            # decoder threads of a take open their indexes together. One reader at a
            # time here; a parse that fails anyway only costs a rebuilt index.
            with _LOAD_LOCK, np.load(file) as z:
                stamp = z["stamp"]
                if (int(stamp[0]) != _INDEX_VERSION or int(stamp[1]) != st.st_size
                        or int(stamp[2]) != st.st_mtime_ns):
                    return None
                # "decodable" is optional: indexes stored before it was kept lack it
                decodable = int(z["decodable"]) if "decodable" in z.files else None
                return cls(z["pts"], z["keyframe"], decodable)
        except (OSError, KeyError, ValueError, SystemError):
            return None

    def save(self, path: Path) -> None:
        """Store the index of ``path`` in the user cache (failure only costs a rebuild)."""
        file = self._cache_file(path)
        try:
            st = path.stat()
            file.parent.mkdir(parents=True, exist_ok=True)
            tmp = file.with_name(f"{file.stem}.{os.getpid()}.tmp.npz")
            stamp = np.array([_INDEX_VERSION, st.st_size, st.st_mtime_ns], np.int64)
            extra = {} if self.decodable is None else {"decodable": np.int64(self.decodable)}
            np.savez(tmp, stamp=stamp, pts=self.pts, keyframe=self.keyframe, **extra)
            os.replace(tmp, file)
        except OSError as exc:
            log.debug("cannot store the keyframe index of %s: %s", path, exc)


def _gray(frame: Any) -> NDArray[np.uint8]:
    """A decoded frame as 8-bit gray, the way `cv2.VideoCapture` would deliver it."""
    name = frame.format.name
    if name == "gray":
        return np.ascontiguousarray(frame.to_ndarray())
    if name.startswith("gray16"):
        return np.ascontiguousarray((frame.to_ndarray(format="gray16le") >> 8).astype(np.uint8))
    bgr = frame.to_ndarray(format="bgr24")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)


class AVReader:
    """Frames of one video file by index, through PyAV and a `KeyframeIndex`.

    Not thread-safe: `carapost.io.video.VideoSource` serialises the calls.

    Parameters
    ----------
    path : Path
        The video file.
    threads : int
        FFmpeg's decoding threads for this file (0: FFmpeg's choice, about one per
        core). The frame service decodes each camera on a thread of its own and passes
        1: the cameras already fill the cores, and more threads per decoder only add
        threads that compete with the GUI thread for them.

    Attributes
    ----------
    index : KeyframeIndex
    n_frames : int
    size : tuple of int
        (width, height) of the stream in pixels.
    fps : float
        Average frame rate of the stream (0.0 when unknown).
    seeks, decoded : int
        Counters (seeks made, frames decoded) for benchmarks and tests.

    Raises
    ------
    CaraFileError
        If the file cannot be opened or holds no video stream with timestamps.
    """

    def __init__(self, path: Path, *, threads: int = 0) -> None:
        import av

        self.path = Path(path)
        self._av = av
        self.threads = max(int(threads), 0)
        self.seeks = 0
        self.decoded = 0
        self._open()
        index = KeyframeIndex.load(self.path)
        if index is None:
            index = KeyframeIndex.build(self._container, self._stream)
            if index.n_frames:
                index.save(self.path)
            self._reopen()
        if index.n_frames == 0:
            self.close()
            raise CaraFileError(self.path, "no frame with a timestamp could be read")
        self.index = index
        self.n_frames = index.n_frames
        if index.decodable is not None:
            self.n_frames = max(min(index.decodable, index.n_frames), 1)
        rate = self._stream.average_rate or self._stream.guessed_rate
        self.fps = float(rate) if rate else 0.0
        self.size = self._size

    def verify(self) -> int:
        """Check that the last frame decodes, dropping trailing frames that do not.

        The result is kept in the stored index, so a file is checked once, not on
        every opening (the check decodes up to a keyframe interval). Returns
        ``n_frames``.
        """
        if self.index.decodable is not None:
            return self.n_frames
        while self.n_frames > 1:
            try:
                self.read(self.n_frames - 1)
                break
            except CaraFileError:
                self.n_frames -= 1
                log.warning("%s: the last frame does not decode; using %d frames",
                            self.path.name, self.n_frames)
        self.index.decodable = self.n_frames
        self.index.save(self.path)
        return self.n_frames

    def _open(self) -> None:
        try:
            self._container = self._av.open(str(self.path))
        except Exception as exc:
            raise CaraFileError(self.path, f"cannot be opened as a video ({exc})") from exc
        if not self._container.streams.video:
            self._container.close()
            raise CaraFileError(self.path, "holds no video stream")
        self._stream = self._container.streams.video[0]
        try:
            # A stream of a codec FFmpeg cannot decode has no codec context, so no size.
            self._size = (int(self._stream.width), int(self._stream.height))
        except (AttributeError, TypeError, ValueError) as exc:
            self._container.close()
            raise CaraFileError(self.path, "holds a video stream that cannot be decoded "
                                "(unknown codec or damaged header)") from exc
        if self.threads:
            # before the first decode, which opens the codec (and FFmpeg's threads)
            self._stream.codec_context.thread_count = self.threads
        # A fresh file is positioned at its start: the decode iterator yields frame 0.
        self._frames: Any = self._container.decode(self._stream)
        self._next = 0  # index the iterator yields next (-1: not positioned)

    def _reopen(self) -> None:
        self.close()
        self._open()

    def close(self) -> None:
        """Close the file (a later `read` reopens it)."""
        container = getattr(self, "_container", None)
        if container is not None:
            try:
                container.close()
            except Exception:  # closing a damaged file must not raise
                pass
            self._container = None
        self._frames = None
        self._next = -1

    def read(self, index: int) -> NDArray[np.uint8]:
        """Frame ``index`` (``0 <= index < n_frames``) as 8-bit gray ``[H, W]``.

        Raises
        ------
        CaraFileError
            If the frame cannot be decoded (damaged or truncated file).
        """
        if self._container is None:
            self._open()
        ahead = index - self._next
        # Decoding through is cheaper than a seek while the target is before the next
        # keyframe after the current position.
        if self._next < 0 or ahead < 0 or (
                ahead > 0 and self.index.keyframe_before(index) > self._next):
            self._seek(index)
        target = int(self.index.pts[index])
        try:
            while True:
                frame = next(self._frames)
                self.decoded += 1
                if frame.pts is None or frame.pts < target:
                    continue
                if frame.pts > target:
                    raise CaraFileError(self.path,
                                        f"frame {index} is missing from {self._stream_noun}")
                break
        except StopIteration:
            self._next = -1
            raise CaraFileError(self.path, f"frame {index} could not be decoded "
                                f"({self._file_noun} ends early)") from None
        except self._av.error.FFmpegError as exc:
            self._next = -1
            raise CaraFileError(self.path, f"frame {index} could not be decoded ({exc})") from exc
        except CaraFileError:
            self._next = -1
            raise
        self._next = index + 1
        return self._to_gray(frame)

    #: how the messages name what is read (a subclass reading another kind of file
    #: says so)
    _stream_noun = "the stream"
    _file_noun = "the file"

    def _to_gray(self, frame: Any) -> NDArray[np.uint8]:
        """The decoded frame as 8-bit gray ``[H, W]``."""
        return _gray(frame)

    def _seek(self, index: int) -> None:
        key = self.index.keyframe_before(index)
        try:
            self._container.seek(int(self.index.pts[key]), stream=self._stream,
                                 backward=True, any_frame=False)
        except self._av.error.FFmpegError as exc:
            raise CaraFileError(self.path, f"cannot seek to frame {index} ({exc})") from exc
        self.seeks += 1
        self._frames = self._container.decode(self._stream)
        self._next = key
