"""Background start of the blob detector's worker processes when a take opens.

Detect Blobs runs in the detector processes of :mod:`carapost.algorithms.blobs` (on
threads the detector would hold the GIL and stall the window's drawing). Starting them
costs a second or more (the forkserver imports the detector and loads its compiled
kernels once; on the first run after installation it compiles them), so the window
starts them while the artist looks at the take, not when Detect Blobs [Current Frame]
is first chosen. They stop after the pool's idle time like any batch's processes; the
next Detect Blobs starts them again from the forkserver in milliseconds.
"""

from __future__ import annotations

import logging
import threading

log = logging.getLogger("carapost.ui")

__all__ = ["start_detector_processes"]


def start_detector_processes(workers: int = 2) -> threading.Thread:
    """Import the detector and start its ``workers`` processes on a daemon thread.

    Returns at once (the thread, for tests); importing the detector takes ~0.1 s of
    Python work that would otherwise stall the GUI thread.
    """
    def work() -> None:
        try:
            from carapost.algorithms.blobs import start_workers

            start_workers(workers)
        except Exception:  # the detector reports real problems when it is used
            log.debug("starting the blob detector processes failed", exc_info=True)

    thread = threading.Thread(target=work, name="carapost-detector-start", daemon=True)
    thread.start()
    return thread
