"""The frame service of an open take: one decoder thread per camera, newest request wins.

`FrameService` extends `carapost.io.video.TakeFrames` (its sources and its LRU cache of
decoded images, bounded in megabytes) with what a window and its jobs need:

- **One decoder thread per camera**, each the only reader of its camera's video, so a
  camera's frames are decoded in order and the four cameras of a take decode at once
  (FFmpeg releases the GIL while decoding).
- **Views ask, never wait**: `request(frame, direction)` records the frame the user is
  looking at and returns at once. Each camera's thread serves the newest request only:
  a request that was superseded before its decode began is dropped (counted in
  ``dropped``), and a decode heading for a superseded frame stops at the next frame.
  ``on_ready(frame, camera)`` is called from the thread when a requested image lands
  (the frame asked for, or the one the views show now; not for each frame read ahead,
  which the views find in the cache).
- **Read-ahead** in the direction of travel while a thread is idle: forward in decode
  order, backward a keyframe interval at a time (the frames from the keyframe before the
  wanted one are decoded in order and all kept), up to ``read_ahead`` frames from the
  current one and never more than half the cache; unless playing, the two nearest
  frames on both sides come first and a third of the run the other way last (a step
  back after a jump or a change of direction is a cache hit; `_ahead_order`).
- **Playback in lockstep**: while playing, every camera's thread decodes the frames of
  one shared schedule from the playback clock (`set_clock`; `carapost.io.lockstep`):
  when the decoders cannot keep up, whole frames are dropped and every frame decoded
  is complete (each camera chasing the clock on its own decoded different frames, few
  of them with the images of all cameras).
- **Jobs share the decoders**: `get` from any other thread (Detect Blobs, the Target
  Tracker, patch tracking) queues the frame on that camera's thread and waits for it;
  the other cameras of the same frame are queued too, so a frame of four cameras
  decodes on all cores. A cached image is returned at once.
- **Clear failures**: a missing, unreadable or short video yields blank images and
  `message(frame, camera)` says why. No Qt here: `carapost.ui.frames` adapts ``on_ready``.
"""

from __future__ import annotations

import logging
import os
import threading
from collections import deque
from concurrent.futures import Future
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.io.decode_slots import DecodeSlots, SlotWait
from carapost.io.errors import CaraFileError
from carapost.io.launcher import launch, lower_thread_priority, started
from carapost.io.lockstep import PlaySchedule
from carapost.io.video import ReadyCallback, TakeFrames, VideoSource

log = logging.getLogger("carapost.io")

__all__ = ["DEFAULT_CACHE_MB", "FrameService"]

#: Default size of the image cache (about 500 frames of four 1280x720 cameras).
DEFAULT_CACHE_MB = 1500.0

#: Nice increment of the decoder threads (Linux: per thread; FFmpeg's own decoding
#: threads inherit it). The GUI thread needs a core at once when a frame lands or the
#: user acts; busy decoders at the same priority would make it wait in the run queue
#: behind them for tens of milliseconds on a 2-core machine. At +10 the GUI thread
#: weighs 9.3x a decoder (+4, 2.4x, still left it 20-60 ms in the run queue behind
#: four decoders while stepping; docs/benchmarks.md "Playback and stepping: decoder
#: threads", tenth session), and the decoders still get every cycle the GUI does not use.
DECODER_NICE = 10

#: FFmpeg's decoding threads per camera decoder. Every camera decodes on a thread of
#: its own, so four cameras already fill the cores; FFmpeg's default (a thread per
#: core and one more, for each decoder) only added 8 threads that compete with the GUI
#: thread for 2 cores. All-intra proxy frames (MJPEG) decode on one thread anyway.
DECODER_THREADS = 1

#: Frames that decode at once in the process, every frame service together (0: as
#: many as the cores this process may use). A camera's thread beyond them waits for a
#: slot before each frame instead of making a third, fourth... runnable thread: a
#: decoder preempted while it holds the GIL (its Python between two frames) keeps the
#: GUI thread waiting until it gets a core back, and with more decoders than cores it
#: waits behind another decoder's time slice. A jump decodes all four cameras in two
#: rounds on two cores, and playback from the originals decodes as many frames per
#: second: the cores were the bound (docs/benchmarks.md, "GUI stalls behind the
#: decoders", eleventh session). On a machine loaded by other programs the process
#: gets a smaller share of the cores with fewer runnable threads.
DECODE_SLOTS = 0

#: Screen pixels per image pixel above which a view counts as zoomed in (playback then
#: shows that camera's original instead of its proxy).
ZOOMED_IN = 1.02

_Job = tuple[int, "Future[NDArray[np.uint8]] | None"]
_UNOPENED: Any = object()
# Proxy images share the cache under (frame, camera + _PROXY_KEY).
_PROXY_KEY = 1 << 20


class _Camera:
    """State of one camera's decoder thread (guarded by the service's condition)."""

    def __init__(self) -> None:
        self.wanted: int | None = None  # newest view request not yet started
        self.origin: int | None = None  # frame read-ahead starts from
        self.target: int | None = None  # frame being decoded for a view request
        self.jobs: deque[_Job] = deque()
        self.thread: threading.Thread | None = None
        self.slot_wait: SlotWait | None = None  # its read-ahead's wait for a slot

    @property
    def asked(self) -> bool:
        """A view request or a job waits: read-ahead gives way to it."""
        return self.wanted is not None or bool(self.jobs)


class FrameService(TakeFrames):
    """Images of every camera of a take for a window and its jobs.

    Parameters
    ----------
    take : Take
    cache_mb : float
        Upper bound of the decoded-image cache in megabytes (default 1500).
    on_ready : callable, optional
        ``on_ready(frame, camera)`` from a decoder thread when an image a view or a
        job may be waiting for lands in the cache (not for frames read ahead).
    read_ahead : int
        Frames decoded ahead of the current one in the direction of travel (while
        playing, set it to about two seconds of the take: `set_read_ahead`).

    Attributes
    ----------
    dropped : int
        View requests superseded by a newer one before (or while) they were decoded.
    """

    def __init__(self, take: Any, *, cache_mb: float = DEFAULT_CACHE_MB,
                 on_ready: ReadyCallback | None = None, read_ahead: int = 24) -> None:
        super().__init__(take, cache_mb=cache_mb, workers=1, on_ready=on_ready, strict=False)
        self._cond = threading.Condition()
        self._cams = [_Camera() for _ in range(take.n_cameras)]
        self._direction = 1
        self._read_ahead = max(int(read_ahead), 0)
        self._errors: dict[int, str] = {}  # camera -> why it has no images
        self._frame_errors: dict[tuple[int, int], str] = {}
        self._service_threads: set[int] = set()
        self._open_locks = [threading.Lock() for _ in range(take.n_cameras)]
        self._playing = False
        self._proxies: dict[int, Any] = {}  # camera -> ProxyReader
        # camera -> {view: screen pixels per original image pixel} (`set_view_scale`)
        self._view_scales: dict[int, dict[Any, float]] = {}
        # cameras whose last frame was never checked to decode (see `_verify`)
        self._unverified: set[int] = set()
        # while playing: the playback clock and the frames every camera decodes
        self._play = PlaySchedule(take.n_cameras)
        self._slots = shared_slots()
        self.dropped = 0

    # -- sources with their failure kept for the views --------------------------------
    def source(self, camera: int) -> VideoSource | None:
        """The camera's opened video (None, with `message` saying why, when unreadable).

        Opening (index, frame count check) happens under a lock of that camera only, so
        the GUI thread's `get_cached` never waits for a decoder opening a file.
        """
        src = self._sources.get(camera, _UNOPENED)
        if src is not _UNOPENED:
            return src
        with self._open_locks[camera]:
            src = self._sources.get(camera, _UNOPENED)
            if src is not _UNOPENED:
                return src
            cam = self.take.cameras[camera]
            try:
                if not cam.video_path:
                    raise CaraFileError(f"<{cam.name}>", "the camera has no video file")
                # Opened without decoding: the first frame wanted is decoded next.
                src = VideoSource(cam.video_path, probe=False,
                                  decoder_threads=DECODER_THREADS)
                reader = src._reader
                if reader is not None and reader.index.decodable is None:
                    # checked when the decoder is idle or nears the end (`_verify`):
                    # it costs up to a keyframe interval of decodes
                    self._unverified.add(camera)
                else:
                    src.verify_frame_count()  # known from the stored index: free
            except CaraFileError as exc:
                self._errors[camera] = str(exc)
                log.warning("Camera %s shows no images: %s", cam.name, exc)
                src = None
            with self._source_lock:
                self._sources[camera] = src
            return src

    def message(self, frame: int, camera: int) -> str | None:
        """Why ``camera`` has no image at ``frame`` (None when it has one or may have)."""
        if camera in self._errors:
            return self._errors[camera]
        err = self._frame_errors.get((frame, camera))
        if err is not None:
            return err
        src = self._sources.get(camera)
        if src is not None:
            index = frame + int(self.take.cameras[camera].frame_offset)
            if not 0 <= index < src.n_frames:
                return (f"{src.path.name} has frames 0-{src.n_frames - 1}; take frame "
                        f"{frame} is video frame {index}")
        return None

    # -- playback proxies (display only; processing reads the originals) --------------
    def attach_proxies(self) -> int:
        """Open the complete, current proxies of the take's videos (see
        `carapost.io.proxy`); returns how many cameras have one."""
        from carapost.io.proxy import ProxyReader, existing_proxy

        for c, cam in enumerate(self.take.cameras):
            if c in self._proxies or not cam.video_path:
                continue
            path = existing_proxy(cam.video_path)
            if path is None:
                continue
            try:
                # opens the container only: no decode on the GUI thread
                proxy = ProxyReader(path, threads=DECODER_THREADS)
            except CaraFileError as exc:
                log.warning("Camera %s: the playback proxy is unusable (%s)", cam.name, exc)
                continue
            # checked against the original on the camera's thread (`_decode_proxy`):
            # opening the original here would make the GUI thread wait
            self._proxies[c] = proxy
        return len(self._proxies)

    @property
    def proxies(self) -> int:
        """Number of cameras with an open proxy."""
        return len(self._proxies)

    def proxy_downscale(self, camera: int) -> float:
        """How many times smaller than the original the camera's proxy is (1.0 without
        a proxy or for a full-resolution one)."""
        proxy = self._proxies.get(camera)
        if proxy is None:
            return 1.0
        width = int(self.take.cameras[camera].image_size[0])
        return max(width / max(int(proxy.size[0]), 1), 1.0)

    def set_view_scale(self, camera: int, scale: float | None, owner: Any = None) -> None:
        """A view of ``camera`` shows its image at ``scale`` screen pixels per image
        pixel (None: the view is gone). While any view of the camera is zoomed in
        beyond Actual Size (``scale`` > `ZOOMED_IN`), playback reads the camera's
        original."""
        # copied, changed and swapped in: decoder threads read it without a lock
        scales = dict(self._view_scales.get(int(camera), {}))
        if scale is None:
            scales.pop(owner, None)
        else:
            scales[owner] = float(scale)
        self._view_scales[int(camera)] = scales

    def _use_proxy(self, camera: int) -> bool:
        if not self._playing or camera not in self._proxies:
            return False
        scales = self._view_scales.get(camera)
        # Zoomed in beyond Actual Size (1:1), the artist looks at pixels: the original.
        # Below it the proxy plays, stretched up to 2x when it is half size (a one- or
        # two-view layout), as video editors play their proxies; 2 % of slack so a view
        # fitted at 1:1 is not "zoomed in".
        return not scales or max(scales.values()) <= ZOOMED_IN

    @property
    def showing_proxies(self) -> bool:
        """Whether images come from proxies now (while playing, when there are some)."""
        return self._playing and bool(self._proxies)

    def get_display(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        """What a view shows without waiting: the original if cached, else while playing
        the proxy image if decoded, else (blank frames outside a video) `get_cached`."""
        return self.display(frame, camera)[0]

    def display(self, frame: int, camera: int) -> tuple[NDArray[np.uint8] | None, bool]:
        """`get_display` and whether the image is a proxy's (smaller than the original
        by `proxy_downscale`: a view stretches it over the original's pixels)."""
        img = self.get_cached(frame, camera)
        if img is None and self._use_proxy(camera):
            img = self._cache_get((int(frame), int(camera) + _PROXY_KEY))
            return img, img is not None
        return img, False

    def _decode_proxy(self, frame: int, camera: int, kind: str = "view") -> None:
        index = self._video_index(frame, camera)
        proxy = self._proxies.get(camera)
        src = self._sources.get(camera)
        if proxy is not None and src is not None and proxy.n_frames != src.n_frames:
            log.warning("Camera %s: the playback proxy has %d frames, the video %d; "
                        "playing the original", self.take.cameras[camera].name,
                        proxy.n_frames, src.n_frames)
            self._proxies.pop(camera, None)
            proxy = None
        if index is None or proxy is None:
            self._notify(frame, camera)
            return
        key = (frame, camera + _PROXY_KEY)
        if self._cache_get(key) is None:
            try:
                self._cache_put(key, proxy.read(index))
            except CaraFileError as exc:  # a damaged proxy: back to the original
                log.warning("Camera %s: %s; playing the original",
                            self.take.cameras[camera].name, exc)
                self._proxies.pop(camera, None)
                return
        self._landed(frame, camera, frame if kind == "view" else None)

    def reset_sources(self) -> None:
        """Reopen videos on next use (after a camera's video path changed)."""
        super().reset_sources()
        self._errors.clear()
        self._frame_errors.clear()

    # -- requests -------------------------------------------------------------------------
    def set_read_ahead(self, frames: int, *, playing: bool = False) -> None:
        """Frames to decode ahead of the current one (e.g. 2 s of the take while playing).

        While ``playing``, a decode on its way to a frame is finished even when a later
        frame is requested meanwhile (so playback shows frames, dropping the ones it
        cannot decode in time); while scrubbing, it stops for the newer request.
        """
        with self._cond:
            self._read_ahead = max(int(frames), 0)
            self._playing = bool(playing)
            self._play.reset()
            self._cond.notify_all()

    def request(self, frame: int, cameras: Any = None, *, direction: int = 0) -> None:
        """Ask for the images of ``frame`` without waiting (the GUI's call).

        Parameters
        ----------
        frame : int
            Take frame the user is looking at; supersedes earlier requests.
        cameras : iterable of int, optional
            Cameras shown (default: all).
        direction : int
            +1 or -1: the direction of travel for read-ahead (0 keeps the last one).
        """
        if self._closed:
            return
        frame = int(frame)
        cams = range(self.take.n_cameras) if cameras is None else [int(c) for c in cameras]
        with self._cond:
            if direction:
                self._direction = 1 if direction > 0 else -1
            for c in cams:
                state = self._cams[c]
                state.origin = frame
                if self.get_display(frame, c) is not None:
                    if state.wanted is not None:
                        self.dropped += 1
                    state.wanted = None
                else:
                    if state.wanted is not None and state.wanted != frame:
                        self.dropped += 1
                    state.wanted = frame
                    self._slots.cancel(state.slot_wait)  # no read-ahead in the way
                self._start(c)
            self._cond.notify_all()

    def set_clock(self, frame: int) -> None:
        """While playing: the frame the playback clock is at (the GUI's call, once per
        frame due). Every camera's decoder works through one schedule of frames from
        there (see the module docstring), so the frames decoded are complete."""
        if self._closed or not self._playing:
            return
        with self._cond:
            frame = int(frame)
            self._play.set_clock(frame)
            self._direction = 1
            for c in range(self.take.n_cameras):
                self._cams[c].origin = frame
                self._start(c)
            self._cond.notify_all()

    def get(self, frame: int, camera: int) -> NDArray[np.uint8]:
        """Image of ``camera`` at ``frame``, waiting for it (any thread but the GUI's).

        Decoded by the camera's thread, which also decodes the other cameras' images of
        the same frame alongside; a cached image returns at once.

        Raises
        ------
        CaraFileError
            The camera's video is missing or the frame cannot be decoded.
        """
        frame, camera = int(frame), int(camera)
        self._check(frame, camera)
        img = self._cache_get((frame, camera))
        if img is not None:
            return img
        if self._closed or threading.get_ident() in self._service_threads:
            return super().get(frame, camera)
        fut: Future[NDArray[np.uint8]] = Future()
        with self._cond:
            for c in range(self.take.n_cameras):
                if c == camera:
                    self._cams[c].jobs.append((frame, fut))
                elif self._cache_get((frame, c)) is None and not any(
                        f == frame for f, _ in self._cams[c].jobs):
                    self._cams[c].jobs.append((frame, None))
                else:
                    continue
                self._slots.cancel(self._cams[c].slot_wait)
                self._start(c)
            self._cond.notify_all()
        return fut.result()

    # -- decoder threads ------------------------------------------------------------------
    def _start(self, camera: int) -> None:
        state = self._cams[camera]
        if state.thread is None:
            name = f"carapost-decode-{self.take.cameras[camera].name}"
            state.thread = threading.Thread(target=self._run, args=(camera,), name=name,
                                            daemon=True)
            launch(state.thread)  # Thread.start would wait for it to run (4-5 ms when busy)

    def _ahead_frame(self, camera: int) -> int | None:
        """Next frame to read ahead for ``camera`` (condition held), None when done."""
        state = self._cams[camera]
        if state.origin is None or self._read_ahead == 0:
            return None
        if self._sources.get(camera, _UNOPENED) is None:
            return None  # no video: nothing to read ahead (and no busy loop)
        for f in _ahead_order(state.origin, self._direction, self._ahead_limit(),
                              self._playing):
            if 0 <= f < self.take.n_frames and not self._done(f, camera):
                return f
        return None

    def _ahead_limit(self) -> int:
        """Frames read ahead at most: the setting, within half the cache."""
        frame_bytes = max(sum(int(w) * int(h) for w, h in
                              (c.image_size for c in self.take.cameras)), 1)
        return min(self._read_ahead, int(self.cache_bytes / 2 / frame_bytes))

    def _done(self, frame: int, camera: int) -> bool:
        """Whether ``camera`` has nothing to decode at ``frame`` (read ahead, or while
        playing): its image (or the proxy's) is cached, it cannot be decoded, or there
        is no video there (a missing video, a frame outside a short one: shown blank)."""
        src = self._sources.get(camera, _UNOPENED)
        if src is None:
            return True
        if src is not _UNOPENED and not 0 <= frame + int(
                self.take.cameras[camera].frame_offset) < src.n_frames:
            return True
        return (self._cache_get((frame, camera)) is not None
                or (self._use_proxy(camera)
                    and self._cache_get((frame, camera + _PROXY_KEY)) is not None)
                or (frame, camera) in self._frame_errors)

    def _started(self, frame: int) -> bool:
        """Whether any camera decodes or has decoded ``frame`` (condition held)."""
        for c, state in enumerate(self._cams):
            if (state.target == frame or self._cache_get((frame, c)) is not None
                    or self._cache_get((frame, c + _PROXY_KEY)) is not None):
                return True
        return False

    def _play_target(self, camera: int) -> int | None:
        """While playing: the next frame of the shared schedule ``camera`` decodes,
        None to wait (condition held; `carapost.io.lockstep.PlaySchedule`)."""
        due = self._play.clock
        if due is None:
            return None
        end = min(due + max(self._ahead_limit(), 1), self.take.n_frames)
        return self._play.next(camera, self._done, self._started, end)

    def _played(self, camera: int) -> None:
        """A scheduled frame was decoded: cameras waiting for the slowest may go on."""
        with self._cond:
            self._cond.notify_all()

    def _run(self, camera: int) -> None:
        self._service_threads.add(threading.get_ident())
        lower_thread_priority(DECODER_NICE)
        state = self._cams[camera]
        while True:
            with self._cond:
                while True:
                    if self._closed:
                        self._fail_jobs(state)
                        return
                    if self._playing and self._play.clock is not None:
                        # the shared schedule, not this camera's own chase of the clock
                        state.wanted = None
                        if state.jobs:
                            frame, fut = state.jobs.popleft()
                            kind = "job"
                            break
                        play = self._play_target(camera)
                        if play is not None:
                            frame, kind, fut = play, "play", None
                            state.target = frame  # started: the others will finish it
                            break
                        self._cond.wait()
                        continue
                    if state.wanted is not None:
                        frame, kind, fut = state.wanted, "view", None
                        state.wanted = None
                        state.target = frame
                        break
                    if state.jobs:
                        frame, fut = state.jobs.popleft()
                        kind = "job"
                        break
                    if camera in self._unverified:
                        frame, kind, fut = -1, "verify", None
                        break
                    ahead = self._ahead_frame(camera)
                    if ahead is not None:
                        frame, kind, fut = ahead, "ahead", None
                        break
                    self._cond.wait()
            if kind == "verify":
                self._verify(camera)
                continue
            if kind != "job" and self._use_proxy(camera):
                try:
                    self._decode_proxy(frame, camera, kind)
                finally:
                    state.target = None
                if kind == "play":
                    self._played(camera)
                continue
            try:
                img = self._decode_to(frame, camera, kind)
            except Exception as exc:  # the waiting job gets the error; the view a message
                if fut is not None:
                    fut.set_exception(exc)
                continue
            finally:
                state.target = None
                if kind == "play":
                    self._played(camera)
            if fut is not None:
                if img is None:
                    fut.set_exception(CaraFileError(str(self.take.cameras[camera].name),
                                                    self.message(frame, camera) or
                                                    f"no image at frame {frame}"))
                else:
                    fut.set_result(img)

    def _fail_jobs(self, state: _Camera) -> None:
        while state.jobs:
            _, fut = state.jobs.popleft()
            if fut is not None and not fut.done():
                fut.set_exception(CaraFileError("<frames>", "the take's videos were closed"))

    def _next_step(self, camera: int, kind: str, i: int, index: int,
                   reader: Any) -> str | tuple[int, int]:
        """Before decoding video frame ``i`` on the way to ``index``: ``"go"``,
        ``"stop"`` (give way to newer work), or a new (frame, index) target reached by
        decoding on (a newer view request beyond ``i`` before the next keyframe)."""
        state = self._cams[camera]
        with self._cond:
            if self._closed:
                return "stop"
            if kind == "job":
                return "go"
            if kind == "ahead":
                return "stop" if state.asked else "go"
            if kind == "play":
                return "stop" if state.jobs else "go"
            wanted = state.wanted
            if wanted is None:
                return "go"
            w_index = wanted + int(self.take.cameras[camera].frame_offset)
            on_the_way = w_index >= i and (
                reader is None or reader.index.keyframe_before(w_index) <= i)
            if on_the_way or not self._playing:
                self.dropped += 1  # the older target is given up
                if on_the_way:
                    state.wanted = None
                    state.target = wanted
                    return wanted, w_index
                return "stop"
            return "go"

    def _verify(self, camera: int) -> None:
        """Check once that the camera's last frame decodes (its own thread only; the
        stored index keeps the answer, so a file is checked once, not per opening)."""
        self._unverified.discard(camera)
        src = self._sources.get(camera)
        if src is None:
            return
        try:
            src.verify_frame_count()
        except CaraFileError as exc:
            log.warning("Camera %s: %s", self.take.cameras[camera].name, exc)

    def _decode_to(self, frame: int, camera: int, kind: str) -> NDArray[np.uint8] | None:
        """Decode ``frame`` of ``camera`` into the cache, with every frame decoded on
        the way (from the keyframe before it, or from the decoder's position)."""
        index = self._video_index(frame, camera)
        if camera in self._unverified and index is not None:
            reader = getattr(self._sources.get(camera), "_reader", None)
            if reader is not None and index >= reader.index.keyframe_before(
                    reader.n_frames - 1):
                self._verify(camera)  # near the end: the frame count must be right
                index = self._video_index(frame, camera)
        if index is None:
            self._notify(frame, camera)
            return self._blank_image(camera) if camera not in self._errors else None
        img = self._cache_get((frame, camera))
        if img is not None:
            self._notify(frame, camera)
            return img
        src = self.source(camera)
        assert src is not None
        start = index
        reader = getattr(src, "_reader", None)
        if reader is not None:
            key = reader.index.keyframe_before(index)
            start = reader._next if key <= reader._next <= index else key
        offset = int(self.take.cameras[camera].frame_offset)
        if (kind == "view" and self._playing and reader is not None
                and 0 <= reader._next < index
                and index - reader._next <= 2 * reader.index.max_interval):
            # Playing and a little behind the clock: the next frame in decode order
            # costs one decode and is shown if it is still due; a seek would cost a
            # keyframe interval. The clock's frame stays wanted.
            with self._cond:
                if self._cams[camera].wanted is None:
                    self._cams[camera].wanted = frame
            index = start = reader._next
            frame = index - offset
            img = self._cache_get((frame, camera))
            if img is not None:
                # cached already (a job read it): step the decoder past it all the same
                src.read(index)
                self._notify(frame, camera)
                return img
        i = start
        while i <= index:
            step = self._next_step(camera, kind, i, index, reader)
            if step == "stop":
                return None
            if isinstance(step, tuple):
                frame, index = step
            f = i - offset
            try:
                img = self._read(src, i, camera, urgent=kind != "ahead")
            except CaraFileError as exc:
                self._frame_errors[(f, camera)] = str(exc)
                # the target cannot be reached either (read-ahead must not retry it)
                self._frame_errors.setdefault((frame, camera), str(exc))
                log.warning("Camera %s: %s", self.take.cameras[camera].name, exc)
                self._notify(frame, camera)
                raise
            if img is None:
                return None  # read-ahead superseded while it waited for its slot
            if 0 <= f < self.take.n_frames and self._cache_get((f, camera)) is None:
                self._cache_put((f, camera), img)
                self._landed(f, camera, None if kind == "ahead" else frame)
            i += 1
        return img

    def _read(self, src: VideoSource, index: int, camera: int, *,
              urgent: bool) -> NDArray[np.uint8] | None:
        """One frame of ``src`` in a decode slot (`DecodeSlots`: read-ahead waits behind
        a view's, a job's or playback's frames); None, without decoding, for read-ahead
        superseded before it got its slot (`request` and `get` call its wait off), which
        a jump would otherwise wait for (docs/benchmarks.md, fourteenth session)."""
        state = self._cams[camera]
        wait = None
        if not urgent:
            with self._cond:  # where `request` and `get` look for the wait to call off
                if self._closed or state.asked:
                    return None
                wait = state.slot_wait = SlotWait()
        try:
            if not self._slots.acquire(urgent, wait):
                return None
        finally:
            state.slot_wait = None
        try:
            if wait is not None:
                with self._cond:
                    if self._closed or state.asked:
                        return None
            return src.read(index)
        finally:
            self._slots.release()

    def _landed(self, frame: int, camera: int, target: int | None) -> None:
        """An image landed in the cache: tell the views if one may be waiting for it
        (the ``target`` of a view request or job, or the frame the views show now).

        Read-ahead fills the cache with frames the views will find there when they get
        to them; a signal for each would wake the GUI thread four times per decoded
        frame for nothing (during playback hundreds of times a second)."""
        if frame == target or frame == self._cams[camera].origin:
            self._notify(frame, camera)

    def _notify(self, frame: int, camera: int) -> None:
        callback = self.on_ready
        if callback is not None:
            try:
                callback(frame, camera)
            except Exception:  # a broken listener must not stop decoding
                log.exception("on_ready callback failed")

    def close(self) -> None:
        """Stop the decoder threads (they finish the frame in hand) and close the videos."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
            for state in self._cams:  # a read-ahead queued for a slot ends at once
                self._slots.cancel(state.slot_wait)
        for state in self._cams:
            if state.thread is not None and state.thread is not threading.current_thread():
                if started(state.thread):  # launched: join refuses one not yet started
                    state.thread.join(timeout=5.0)
        self._closed = False  # let TakeFrames.close run its own shutdown
        super().close()
        for proxy in self._proxies.values():
            proxy.close()
        self._proxies.clear()


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity; `os.cpu_count` elsewhere)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def decode_slots() -> int:
    """How many decoders may decode at once: `DECODE_SLOTS`, by default the cores."""
    return max(int(DECODE_SLOTS) or available_cores(), 1)


_SHARED_SLOTS: dict[int, DecodeSlots] = {}
_SHARED_LOCK = threading.Lock()


def shared_slots() -> DecodeSlots:
    """The process's decode slots (`decode_slots` of them), shared by every frame
    service: while a take opens, the previous take's decoders finish their frames and
    the new take's start, and together they stay within the cores."""
    limit = decode_slots()
    with _SHARED_LOCK:
        slots = _SHARED_SLOTS.get(limit)
        if slots is None:
            slots = _SHARED_SLOTS[limit] = DecodeSlots(limit)
        return slots


#: Frames read ahead on each side of the current one before the rest (not playing).
NEAREST_FIRST = 2


def _ahead_order(origin: int, step: int, limit: int, playing: bool) -> list[int]:
    """Frames to read ahead from ``origin``, in order (the caller skips those cached or
    outside the take).

    Playing: ``limit`` frames in the direction of travel. Otherwise the `NEAREST_FIRST`
    frames on both sides first (after a jump the user may step either way, and those
    frames cost a decode each in an all-intra video), then the rest of ``limit`` in the
    direction of travel, then a third as far the other way, so a step back after
    stepping forwards is a cache hit too.

    Examples
    --------
    >>> _ahead_order(10, 1, 6, playing=False)
    [11, 12, 9, 8, 13, 14, 15, 16]
    >>> _ahead_order(10, -1, 3, playing=True)
    [9, 8, 7]
    """
    if playing:
        return [origin + step * k for k in range(1, limit + 1)]
    back = limit // 3
    near = min(NEAREST_FIRST, limit)
    order = [origin + step * k for k in range(1, near + 1)]
    order += [origin - step * k for k in range(1, min(near, back) + 1)]
    order += [origin + step * k for k in range(near + 1, limit + 1)]
    order += [origin - step * k for k in range(min(near, back) + 1, back + 1)]
    return order

