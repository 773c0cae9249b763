"""Where camera images come from: the take's videos, arrays in memory, or nothing.

Views ask :meth:`FrameSource.image` for a frame of a camera and get a 2-D uint8 array
(or None when there is no image). Video reading is done by the take's frame service
(:mod:`carapost.io.frameservice`) on decoder threads; projects without videos draw an
empty grey background.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from carapost.model.project import Project

if TYPE_CHECKING:
    from carapost.io.frameservice import FrameService

log = logging.getLogger("carapost.ui")


class FrameSource:
    """Base class: no images at all.

    ``asynchronous`` sources (the take's videos) decode on their own threads: a view
    shows `cached` images, asks for missing ones with `request` and redraws when the
    context's ``frame_ready`` signal says they have landed. Other sources are cheap and
    are read with `image` directly.
    """

    asynchronous = False

    def image(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        """The image of ``camera`` at take frame ``frame`` (None if there is none)."""
        return None

    def require(self, frame: int, camera: int) -> NDArray[np.uint8]:
        """The image of ``camera`` at ``frame``; ValueError when there is none (for work
        that cannot go on without it: detection, tracking)."""
        img = self.image(frame, camera)
        if img is None:
            raise ValueError(f"no image for frame {frame}, camera {camera}")
        return img

    def cached(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        """The image if it is available without decoding (None otherwise)."""
        return None

    def display(self, frame: int, camera: int) -> tuple[NDArray[np.uint8] | None, bool]:
        """`cached`, and whether the image is a playback proxy's (smaller than the
        original: a view stretches it over the original's pixel rectangle)."""
        return self.cached(frame, camera), False

    def set_view_scale(self, camera: int, scale: float | None, owner: object = None) -> None:
        """A view shows ``camera`` at ``scale`` screen pixels per image pixel (None:
        the view is gone); zoomed in beyond Actual Size, originals are shown."""

    def prefetch(self, frames: range, cameras: list[int]) -> None:
        """Hint that these images will be wanted soon."""

    def request(self, frame: int, camera: int | None = None, direction: int = 0) -> None:
        """Ask for an image without waiting (asynchronous sources; the newest wins).

        ``camera`` None asks for every camera; ``direction`` (+1/-1) is the direction
        of travel for read-ahead (0: unchanged)."""

    def message(self, frame: int, camera: int) -> str | None:
        """Why there is no image of ``camera`` at ``frame`` (None if there is one)."""
        return None

    def set_playing(self, fps: float | None) -> None:
        """Playback started at ``fps`` (more read-ahead) or stopped (None)."""

    def set_clock(self, frame: int) -> None:
        """While playing: the frame the playback clock is at (the decoders of every
        camera work through the same frames from there)."""

    def stats(self) -> dict[str, float]:
        """Counters for the status bar and benchmarks (cache use, dropped requests)."""
        return {}

    def worker_copy(self) -> FrameSource:
        """A source safe to read from a worker thread (a separate decoder)."""
        return self

    @property
    def has_images(self) -> bool:
        """Whether any image can ever come out of this source."""
        return False

    def close(self) -> None:
        """Release files and caches."""


class ArrayFrameSource(FrameSource):
    """Images from a function ``render(frame, camera) -> ndarray``, with an LRU cache.

    Used for synthetic takes, tests and benchmarks.
    """

    def __init__(self, render: Callable[[int, int], NDArray[np.uint8] | None],
                 cache_size: int = 512) -> None:
        self._render = render
        self._cache: OrderedDict[tuple[int, int], NDArray[np.uint8] | None] = OrderedDict()
        self._size = cache_size

    def image(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        key = (frame, camera)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        img = self._render(frame, camera)
        self._cache[key] = img
        if len(self._cache) > self._size:
            self._cache.popitem(last=False)
        return img

    def cached(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        return self._cache.get((frame, camera))

    def prefetch(self, frames: range, cameras: list[int]) -> None:
        for f in frames:
            for c in cameras:
                self.image(f, c)

    def worker_copy(self) -> FrameSource:
        return ArrayFrameSource(self._render, cache_size=8)

    @property
    def has_images(self) -> bool:
        return True

    def close(self) -> None:
        self._cache.clear()


class VideoFrameSource(FrameSource):
    """Images decoded from the take's video files by the take's frame service
    (:class:`carapost.io.frameservice.FrameService`): one decoder thread per camera,
    a shared LRU cache of ``cache_mb`` megabytes, read-ahead in the direction of travel.

    The window's views and its jobs share this one source (``worker_copy`` is the
    source itself: the service is thread-safe and a job's reads are queued on the same
    decoders, so Detect Blobs [Current Frame] gets the image the view already holds).
    """

    asynchronous = True

    def __init__(self, project: Project,
                 on_ready: Callable[[int, int], None] | None = None,
                 cache_mb: float | None = None) -> None:
        from carapost.io.frameservice import DEFAULT_CACHE_MB, FrameService

        self._project = project
        self._frames = FrameService(project.take, on_ready=on_ready,
                                    cache_mb=DEFAULT_CACHE_MB if cache_mb is None else cache_mb)

    @property
    def service(self) -> FrameService:
        """The frame service (for benchmarks and the status bar)."""
        return self._frames

    def _call(self, name: str, frame: int, camera: int) -> NDArray[np.uint8] | None:
        try:
            img = getattr(self._frames, name)(frame, camera)
        except Exception as exc:  # a missing or broken video shows as no image
            log.debug("camera %d frame %d: no image (%s)", camera, frame, exc)
            return None
        return None if img is None else np.asarray(img)

    def image(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        return self._call("get", frame, camera)

    def cached(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        return self._call("get_display", frame, camera)

    def require(self, frame: int, camera: int) -> NDArray[np.uint8]:
        """The image, or `CaraFileError` saying which video is missing or damaged."""
        return self._frames.get(frame, camera)

    def display(self, frame: int, camera: int) -> tuple[NDArray[np.uint8] | None, bool]:
        try:
            return self._frames.display(frame, camera)
        except Exception as exc:  # a missing or broken video shows as no image
            log.debug("camera %d frame %d: no image (%s)", camera, frame, exc)
            return None, False

    def set_view_scale(self, camera: int, scale: float | None, owner: object = None) -> None:
        self._frames.set_view_scale(camera, scale, owner)

    def request(self, frame: int, camera: int | None = None, direction: int = 0) -> None:
        self._frames.request(frame, None if camera is None else [camera], direction=direction)

    def message(self, frame: int, camera: int) -> str | None:
        return self._frames.message(frame, camera)

    def set_playing(self, fps: float | None) -> None:
        # two seconds of the take ahead while playing; a short run while stepping
        self._frames.set_read_ahead(int(2 * fps) if fps else 24, playing=bool(fps))

    def set_clock(self, frame: int) -> None:
        self._frames.set_clock(frame)

    def prefetch(self, frames: range, cameras: list[int]) -> None:
        frames = list(frames)
        if frames:
            self._frames.request(frames[0], cameras)

    def stats(self) -> dict[str, float]:
        f = self._frames
        return {"cache_mb": f.cache_used_bytes / 1e6, "cache_limit_mb": f.cache_bytes / 1e6,
                "dropped": float(f.dropped), "proxies": float(f.proxies),
                "showing_proxies": float(f.showing_proxies)}

    def attach_proxies(self) -> int:
        """Use the playback proxies written so far (see `carapost.io.proxy`)."""
        return self._frames.attach_proxies()

    def video_paths(self) -> list[str]:
        """The take's camera videos (for the proxy writer)."""
        return [cam.video_path for cam in self._project.take.cameras if cam.video_path]

    def worker_copy(self) -> FrameSource:
        return self

    @property
    def has_images(self) -> bool:
        return True

    def close(self) -> None:
        self._frames.close()


def frame_source_for(project: Project,
                     on_ready: Callable[[int, int], None] | None = None,
                     cache_mb: float | None = None) -> FrameSource:
    """The best source for a project: its videos when they can be read, else none.

    ``on_ready(frame, camera)`` is called (from a decoder thread) when an image lands in
    the cache; ``cache_mb`` bounds the image cache (default: the frame service's).
    """
    if not any(cam.video_path for cam in project.take.cameras):
        return FrameSource()
    try:
        return VideoFrameSource(project, on_ready, cache_mb)
    except ImportError:
        log.info("video reading is not available yet; camera views show no image")
    except Exception as exc:
        log.warning("cannot read the take's videos: %s", exc)
    return FrameSource()
