"""Starting threads without waiting for them to run.

`threading.Thread.start` returns only once the new thread has run its first
instruction, so the caller waits for a scheduler slot: on the 2-core machines we
measure on, with the detector's processes or a proxy build beside the window, 4-5 ms
per thread (16-20 ms for a take's four decoder threads, docs/benchmarks.md, fifteenth
session). The GUI thread must not spend its frame budget on that. `launch` hands the
thread to one long-lived launcher thread and returns at once; `started` waits, where it
matters (before a `join`), until a launched thread has been started.

Example
-------
>>> import threading
>>> done = threading.Event()
>>> t = threading.Thread(target=done.set, daemon=True)
>>> launch(t)
>>> started(t) and done.wait(5.0)
True
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time

__all__ = ["launch", "lower_thread_priority", "start_launcher", "started"]

_lock = threading.Lock()
_queue: queue.SimpleQueue[threading.Thread] | None = None


def _run(q: queue.SimpleQueue[threading.Thread]) -> None:
    while True:
        thread = q.get()
        try:
            thread.start()
        except RuntimeError:  # started twice, or the interpreter is shutting down
            pass


def start_launcher() -> None:
    """Start the launcher thread now (once per process), so that the first `launch`
    does not pay for it (the window calls this when it is created)."""
    global _queue
    with _lock:
        if _queue is None:
            _queue = queue.SimpleQueue()
            threading.Thread(target=_run, args=(_queue,), name="carapost-launcher",
                             daemon=True).start()


def launch(thread: threading.Thread) -> None:
    """Start ``thread`` from the launcher thread; returns at once.

    The thread runs a moment later (the launcher's turn); work it should find must be
    queued where it looks for it first, under the same lock, as with a plain start.
    """
    start_launcher()
    assert _queue is not None
    _queue.put(thread)


def started(thread: threading.Thread, timeout: float = 5.0) -> bool:
    """Wait until a `launch`-ed ``thread`` has been started (at most ``timeout`` s):
    `threading.Thread.join` refuses a thread not yet started."""
    deadline = time.monotonic() + timeout
    while thread.ident is None:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    return True


def lower_thread_priority(increment: int) -> None:
    """Raise the calling thread's nice value by ``increment`` (at most 19), so that
    background work (decoding ahead, proxies, the autosave) leaves the cores to the GUI
    thread first. Linux only (a per-thread nice value); elsewhere PRIO_PROCESS would
    renice the whole program, so nothing changes. Not permitted: nothing changes."""
    if not sys.platform.startswith("linux"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid)
                                                 + increment, 19))
    except (AttributeError, OSError):
        pass
