"""Background writing of playback proxies, with its progress in the status bar.

`ProxyBuilder` writes the MJPEG proxy of every camera video of the open take
(`carapost.io.proxy.write_proxy`) on a low-priority background thread, one camera after
the other, and hands each finished one to the frame service. It runs outside the
JobRunner (which holds one processing job at a time): a proxy is a convenience, never
in the way of work. It stops when the take is closed or replaced, leaving no partial
file.
"""

from __future__ import annotations

import logging
import os
import threading
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, Qt, Signal

if TYPE_CHECKING:
    from carapost.ui.frames import FrameSource

log = logging.getLogger("carapost.ui")


class ProxyBuilder(QObject):
    """Writes the proxies of a frame source's videos in the background.

    Signals
    -------
    progressed(int, int, float)
        (cameras done, cameras to do, fraction of the current camera), queued to the
        GUI thread.
    finished(int)
        Number of cameras with a proxy once the run ends (also when stopped).
    """

    progressed = Signal(int, int, float)
    finished = Signal(int)
    _landed = Signal(bool)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._frames: Any = None
        self._landed.connect(self._attach, Qt.ConnectionType.QueuedConnection)

    @property
    def running(self) -> bool:
        """Whether proxies are being written."""
        return self._thread is not None and self._thread.is_alive()

    def start(self, frames: FrameSource) -> bool:
        """Write the missing proxies of ``frames``' videos; False when there are none
        to write (no videos, or all proxies exist)."""
        from carapost.io.proxy import existing_proxy

        self.stop()
        self._frames = None
        paths = getattr(frames, "video_paths", lambda: [])()
        # a missing video already says so in its view; there is nothing to copy
        todo = [p for p in paths if os.path.isfile(p) and existing_proxy(p) is None]
        self._frames = frames
        if not todo:
            if paths:
                frames.attach_proxies()
            return False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(todo, self._stop),
                                        name="carapost-proxies", daemon=True)
        self._thread.start()
        return True

    def stop(self) -> None:
        """Stop writing (the proxy in hand is discarded) and wait for the thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def _run(self, todo: list[str], stop: threading.Event) -> None:
        from carapost.io.errors import CaraFileError
        from carapost.io.launcher import lower_thread_priority
        from carapost.io.proxy import write_proxy

        lower_thread_priority(15)  # interactive decoding comes first
        total = len(todo)
        for k, path in enumerate(todo):

            def progress(done: int, n: int, k: int = k) -> bool:
                if done % 10 == 0 or done == n:
                    self.progressed.emit(k, total, done / max(n, 1))
                return not stop.is_set()

            try:
                if write_proxy(path, progress=progress) is None:
                    break
            except CaraFileError as exc:
                log.warning("No playback proxy for %s: %s", os.path.basename(path), exc)
                continue
            except Exception:  # a proxy is a convenience: never let it end the program
                log.exception("No playback proxy for %s", os.path.basename(path))
                continue
            if stop.is_set():
                break
            self._landed.emit(False)
        self.progressed.emit(total, total, 1.0)
        self._landed.emit(True)

    def _attach(self, last: bool) -> None:
        frames = self._frames
        if frames is None:
            return
        n = frames.attach_proxies()
        if last:
            self.finished.emit(n)
