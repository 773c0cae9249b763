"""Writing lossless camera videos: gray FFV1 in Matroska through FFmpeg's encoder (PyAV).

`FFV1Writer` writes what the synthetic take generator and the demo produce. By default
every frame is a keyframe (``g=1``, the archival setting of FFV1: a damaged frame
never spoils the frames after it) and frames are cut into 4 slices with a CRC each
(FFV1 version 3), so FFmpeg can decode one frame on several cores and tell a damaged
slice. A keyframe on every frame makes a random frame cost one decode instead of, on
average, half a keyframe interval (OpenCV's writer puts one every 12 frames): measured
on 1280x720 noisy frames, the file is 0.3 % larger and a frame decodes as fast
(docs/benchmarks.md, "Random access: decode path").

Pixels are stored exactly: reading the file back (`carapost.io.decode.AVReader`, or
OpenCV) gives the images written, bit for bit.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.io.errors import CaraFileError

__all__ = ["FFV1Writer"]


class FFV1Writer:
    """Write 8-bit gray images ``[H, W]`` to a lossless FFV1 ``.mkv``.

    Parameters
    ----------
    path : str or Path
        The video to write (replaced if it exists).
    size : (int, int)
        (width, height) in pixels; every image must have this size.
    fps : float
        Frame rate stored in the container.
    gop : int
        Keyframe interval in frames (1: every frame is a keyframe).
    slices : int
        Slices per frame (FFV1 version 3, each with a CRC); 1 writes version 1 without
        CRCs, the way OpenCV's writer does.

    Raises
    ------
    CaraFileError
        If the file cannot be created or the encoder refuses the settings.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from carapost.io.decode import AVReader
    >>> path = Path(tempfile.mkdtemp()) / "doc_cam0.mkv"
    >>> images = [np.full((16, 32), 10 * i, np.uint8) for i in range(5)]
    >>> with FFV1Writer(path, (32, 16), 60.0) as w:
    ...     for img in images:
    ...         w.write(img)
    >>> r = AVReader(path)
    >>> r.n_frames, int(r.index.keyframe.sum()), bool((r.read(3) == images[3]).all())
    (5, 5, True)
    """

    def __init__(self, path: str | Path, size: tuple[int, int], fps: float, *,
                 gop: int = 1, slices: int = 4) -> None:
        import av

        self.path = Path(path)
        self.size = (int(size[0]), int(size[1]))
        self.frames = 0
        self._av = av
        if gop < 1 or slices < 1:
            raise ValueError(f"gop and slices must be >= 1, got {gop}, {slices}")
        options = {"g": str(int(gop))}
        if slices > 1:
            options.update(level="3", slices=str(int(slices)), slicecrc="1")
        if not self.path.parent.is_dir():  # FFmpeg would only fail at the first frame
            raise CaraFileError(self.path, "cannot be written (no such folder)")
        try:
            self._out: Any = av.open(str(self.path), "w", format="matroska")
        except (OSError, av.error.FFmpegError) as exc:
            raise CaraFileError(self.path, f"cannot be written ({exc})") from exc
        try:
            rate = Fraction(float(fps)).limit_denominator(1001) if fps > 0 else Fraction(60)
            st = self._out.add_stream("ffv1", rate=rate)
            st.width, st.height = self.size
            st.pix_fmt = "gray"
            st.options = options
            self._stream = st
        except Exception as exc:
            self._out.close()
            raise CaraFileError(self.path, f"the FFV1 encoder refused the settings ({exc})"
                                ) from exc

    def write(self, image: NDArray[np.uint8]) -> None:
        """Append one image (uint8 ``[H, W]`` of the writer's size)."""
        img = np.ascontiguousarray(image)
        if img.dtype != np.uint8 or img.shape != (self.size[1], self.size[0]):
            raise ValueError(f"{self.path.name}: need uint8 images of shape "
                             f"{(self.size[1], self.size[0])}, got {img.dtype} {img.shape}")
        frame = self._av.VideoFrame.from_ndarray(img, format="gray")
        frame.pts = self.frames
        try:
            for packet in self._stream.encode(frame):
                self._out.mux(packet)
        except (OSError, self._av.error.FFmpegError) as exc:
            raise CaraFileError(self.path, f"cannot be written ({exc})") from exc
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file (the Matroska index is written here)."""
        out = getattr(self, "_out", None)
        if out is None:
            return
        self._out = None
        try:
            for packet in self._stream.encode():
                out.mux(packet)
        finally:
            out.close()

    def __enter__(self) -> FFV1Writer:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
