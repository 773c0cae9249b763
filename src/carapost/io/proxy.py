"""Playback proxies: an all-intra MJPEG copy of a camera video that decodes fast.

The lossless FFV1 originals decode at ~26 ms per 1280x720 frame on one core and only
from a keyframe on; an MJPEG copy decodes in ~2.5 ms at full resolution and every frame
is a keyframe (measured, docs/benchmarks.md "Frame access"; FFV1 with a keyframe on
every frame is no faster than the original). Proxies of videos at least
`MIN_DOWNSCALED_WIDTH` pixels wide are written at half width and height
(`PROXY_DOWNSCALE`): a quarter of the pixels decodes ~3x faster again and takes a
quarter of the cache, and a camera view in a four-view layout shows a 1280x720 image at
about half size anyway. The views draw a proxy image stretched over the original's
pixel rectangle (image coordinates are unchanged) and read the original instead when
zoomed in beyond Actual Size (1:1), and when playback stops.

Proxies are for display only: processing always reads the originals. They live in the
user cache (`carapost.io.decode.cache_dir`, subfolder ``proxies``), named after the
original's path, size and modification time and the proxy format, so a changed video
never plays a stale proxy; deleting them loses nothing. A proxy is written to a
temporary file and renamed when complete, so an interrupted write leaves no half proxy.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.io.decode import AVReader, _gray, cache_dir
from carapost.io.errors import CaraFileError

log = logging.getLogger("carapost.io")

__all__ = ["MIN_DOWNSCALED_WIDTH", "PROXY_DOWNSCALE", "PROXY_QUALITY", "ProxyReader",
           "proxy_downscale", "proxy_path", "write_proxy"]

#: MJPEG quantiser (2 best - 31 worst): grey levels within a few units of the original.
PROXY_QUALITY = 4
#: Proxies of videos at least `MIN_DOWNSCALED_WIDTH` wide are this many times smaller
#: in width and height than the original.
PROXY_DOWNSCALE = 2
MIN_DOWNSCALED_WIDTH = 640
# Part of a proxy's file name: proxies written by another version of this scheme (full
# resolution) are not reused, they are written again.
_FORMAT = "h2"


def proxy_downscale(width: int, height: int) -> int:
    """How many times smaller than a ``width`` x ``height`` original its proxy is.

    Examples
    --------
    >>> proxy_downscale(1280, 720), proxy_downscale(320, 240)
    (2, 1)
    """
    return PROXY_DOWNSCALE if width >= MIN_DOWNSCALED_WIDTH and height >= 32 else 1


def _proxy_size(width: int, height: int, downscale: int) -> tuple[int, int]:
    """(width, height) of a proxy: the original's divided by ``downscale``, rounded to
    even numbers (4:2:0 JPEG)."""
    if downscale <= 1:
        return width, height
    return (max(2 * round(width / downscale / 2), 2), max(2 * round(height / downscale / 2), 2))


class ProxyReader(AVReader):
    """Frames of a proxy by index, as 8-bit gray straight from the JPEG luma plane.

    A proxy is written from gray images, so its luma plane *is* the image (full-range
    YUV, chroma flat): reading it as gray skips the YUV -> BGR -> gray round trip that
    a colour video needs, which halves the cost of a proxy frame (decode 1.4 ms + copy
    instead of 2.6 ms per 1280x720 frame, same pixels; docs/benchmarks.md "Playback
    and GUI responsiveness"). Every frame is a keyframe, so any frame is one seek and
    one decode away.

    Not thread-safe: each camera's proxy is read by that camera's decoder thread only.
    """

    def read(self, index: int) -> NDArray[np.uint8]:
        """Frame ``index`` of the proxy as gray ``[H, W]`` uint8.

        Raises
        ------
        CaraFileError
            If the frame cannot be decoded (damaged or truncated proxy).
        """
        if not 0 <= index < self.n_frames:
            raise CaraFileError(self.path, f"frame {index} is missing from the proxy "
                                f"(it has frames 0-{self.n_frames - 1})")
        return super().read(index)

    _stream_noun = _file_noun = "the proxy"

    def _to_gray(self, frame: Any) -> NDArray[np.uint8]:
        """The JPEG luma plane as it is (a proxy of another pixel format: converted)."""
        if frame.format.name in ("yuvj420p", "yuvj422p", "yuvj444p", "gray"):
            return frame.to_ndarray(format="gray")  # the luma plane, copied
        return _gray(frame)


def proxy_path(video: str | Path) -> Path | None:
    """Where the proxy of ``video`` is (or would be) stored; None if the video is gone."""
    video = Path(video)
    try:
        st = video.stat()
    except OSError:
        return None
    digest = hashlib.sha1(str(video.absolute()).encode("utf-8")).hexdigest()[:16]
    return cache_dir() / "proxies" / (f"{video.stem}-{digest}-{st.st_size}-{st.st_mtime_ns}"
                                      f"-{_FORMAT}.avi")


def existing_proxy(video: str | Path) -> Path | None:
    """The proxy of ``video`` if one is complete and current, else None."""
    path = proxy_path(video)
    return path if path is not None and path.is_file() else None


def write_proxy(video: str | Path, *, progress: Callable[[int, int], bool] | None = None,
                downscale: int | None = None) -> Path | None:
    """Write the MJPEG proxy of ``video`` (or return the existing one).

    Parameters
    ----------
    video : path
        An original camera video.
    progress : callable (done, total) -> bool, optional
        Called after each frame; returning False cancels (no file is left).
    downscale : int, optional
        Times smaller than the original in width and height (default: `proxy_downscale`
        of the original's size). Images are shrunk by pixel-area averaging. The file
        name does not carry the scale: another scale is for measurements only (it is
        the video's proxy afterwards, and an existing proxy is returned whatever its
        scale).

    Returns
    -------
    Path or None
        The proxy, or None when cancelled.

    Raises
    ------
    CaraFileError
        If the original cannot be read or the proxy cannot be written.
    """
    import av

    video = Path(video)
    target = proxy_path(video)
    if target is None:
        raise CaraFileError(video, "no such file")
    if target.is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    # unique per writer: two windows of one program may copy the same video at once
    tmp = target.with_name(f"{target.stem}.{os.getpid()}-{threading.get_ident()}.partial.avi")
    reader = AVReader(video)
    done = False
    try:
        out = av.open(str(tmp), "w")
        try:
            first = reader.read(0)
            height, width = first.shape
            scale = proxy_downscale(width, height) if downscale is None else int(downscale)
            size = _proxy_size(width, height, scale)

            def shrink(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
                if size == (width, height):
                    return img
                return cv2.resize(img, size, interpolation=cv2.INTER_AREA)

            stream = out.add_stream("mjpeg", rate=int(round(reader.fps or 60)))
            stream.width, stream.height = size
            stream.pix_fmt = "yuvj420p"
            stream.options = {"q:v": str(PROXY_QUALITY)}
            stream.codec_context.qmin = stream.codec_context.qmax = PROXY_QUALITY
            for i in range(reader.n_frames):
                img = shrink(first if i == 0 else reader.read(i))
                frame = av.VideoFrame.from_ndarray(img, format="gray")
                frame.pts = i
                for packet in stream.encode(frame):
                    out.mux(packet)
                if progress is not None and progress(i + 1, reader.n_frames) is False:
                    return None
            for packet in stream.encode():
                out.mux(packet)
        finally:
            out.close()
        os.replace(tmp, target)
        done = True
        return target
    except av.error.FFmpegError as exc:
        raise CaraFileError(tmp, f"the proxy cannot be written ({exc})") from exc
    except OSError as exc:  # disk full, cache folder removed meanwhile
        raise CaraFileError(tmp, f"the proxy cannot be written ({exc})") from exc
    finally:
        reader.close()
        if not done:
            tmp.unlink(missing_ok=True)
