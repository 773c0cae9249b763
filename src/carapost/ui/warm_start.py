"""Background start of the blob detector's worker processes: their forkserver when the
window starts, the processes when a take opens.

Detect Blobs runs in the detector processes of :mod:`carapost.algorithms.blobs` (on
threads the detector would hold the GIL and stall the window's drawing). Starting them
costs a second or more (the forkserver imports the detector and loads its compiled
kernels once; on the first run after installation it compiles them), so the window
starts them while the artist looks at the take, not when Detect Blobs [Current Frame]
is first chosen. They stop after the pool's idle time like any batch's processes; the
next Detect Blobs starts them again from the forkserver in milliseconds.

The forkserver's start is the expensive part and is paid once per program, so the
window launches it when it is created, before a take is open: launched with the first
take instead, its second of imports took a core from the take's first jumps (150-420
ms instead of ~90; docs/benchmarks.md, fourteenth session).
"""

from __future__ import annotations

import logging
import threading

from carapost.io.launcher import launch

log = logging.getLogger("carapost.ui")

__all__ = ["start_detector_processes", "start_detector_server"]


def _in_background(name: str, what: str, work) -> threading.Thread:
    """Run ``work()`` on a daemon thread named ``name`` (returns the thread at once); a
    failure is only logged: the detector reports real problems when it is used."""
    def run() -> None:
        try:
            work()
        except Exception:
            log.debug("%s failed", what, exc_info=True)

    thread = threading.Thread(target=run, name=name, daemon=True)
    launch(thread)  # a take's opening does not wait for the thread to run
    return thread


def start_detector_processes(workers: int = 2) -> threading.Thread:
    """Import the detector and start its ``workers`` processes on a daemon thread.

    Returns at once (the thread, for tests); importing the detector takes ~0.1 s of
    Python work that would otherwise stall the GUI thread.
    """
    def work() -> None:
        from carapost.algorithms.blobs import start_workers

        start_workers(workers)

    return _in_background("carapost-detector-start",
                          "starting the blob detector processes", work)


def start_detector_server() -> threading.Thread:
    """Launch the detector processes' forkserver on a daemon thread (returns at once;
    the thread, for tests). Nothing of the detector is imported into the window's
    process: the forkserver imports it in its own."""
    def work() -> None:
        from carapost.algorithms.blobs import start_server

        start_server()

    return _in_background("carapost-detector-server",
                          "starting the blob detector's forkserver", work)
