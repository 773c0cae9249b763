"""Where camera images come from: the take's videos, arrays in memory, or nothing.

Views ask :meth:`FrameSource.image` for a frame of a camera and get a 2-D uint8 array
(or None when there is no image). Video reading is done by :mod:`carapost.io.video`
when it is installed; until then, and for projects without videos, views draw an empty
grey background.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from carapost.model.project import Project

log = logging.getLogger("carapost.ui")


class FrameSource:
    """Base class: no images at all."""

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

    def prefetch(self, frames: range, cameras: list[int]) -> None:
        """Hint that these images will be wanted soon."""

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
    """Images decoded from the take's video files by :mod:`carapost.io.video`."""

    def __init__(self, project: Project,
                 on_ready: Callable[[int, int], None] | None = None) -> None:
        from carapost.io.video import TakeFrames

        self._project = project
        self._frames = TakeFrames(project.take, on_ready=on_ready)

    def _call(self, name: str, frame: int, camera: int) -> NDArray[np.uint8] | None:
        fn = getattr(self._frames, name, None)
        if fn is None:
            return None
        try:
            img = fn(frame, camera)
        except Exception as exc:  # a missing or broken video shows as no image, once
            log.warning("camera %d frame %d: no image (%s)", camera, frame, exc)
            return None
        if img is None:
            return None
        img = np.asarray(img)
        if img.ndim == 3:
            img = img[..., :3].mean(axis=-1).astype(np.uint8)
        return img

    def image(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        return self._call("get", frame, camera)

    def cached(self, frame: int, camera: int) -> NDArray[np.uint8] | None:
        return self._call("get_cached", frame, camera)

    def prefetch(self, frames: range, cameras: list[int]) -> None:
        fn = getattr(self._frames, "prefetch", None)
        if fn is not None:
            try:
                fn(frames, cameras)
            except Exception:  # prefetch is only a hint
                log.debug("prefetch failed", exc_info=True)

    def worker_copy(self) -> FrameSource:
        return VideoFrameSource(self._project)

    @property
    def has_images(self) -> bool:
        return True

    def close(self) -> None:
        fn = getattr(self._frames, "close", None)
        if fn is not None:
            fn()


def frame_source_for(project: Project,
                     on_ready: Callable[[int, int], None] | None = None) -> FrameSource:
    """The best source for a project: its videos when they can be read, else none.

    ``on_ready(frame, camera)`` is called (from a decoder thread) when a prefetched image
    lands in the cache.
    """
    if not any(cam.video_path for cam in project.take.cameras):
        return FrameSource()
    try:
        return VideoFrameSource(project, on_ready)
    except ImportError:
        log.info("video reading is not available yet; camera views show no image")
    except Exception as exc:
        log.warning("cannot read the take's videos: %s", exc)
    return FrameSource()
