"""A counting gate around each frame's decode, urgent decodes first.

Used by `carapost.io.frameservice` (`DECODE_SLOTS`, `shared_slots`): at most as many
frames decode at once as the process has cores, so no decoder preempted while it holds
the GIL keeps the GUI thread waiting behind another decoder's time slice.
"""

from __future__ import annotations

import threading
from collections import deque


class DecodeSlots:
    """A counting gate around each frame's decode (`DECODE_SLOTS`), first come first
    served, urgent decodes (a view's or a job's frame, playback) before read-ahead.

    A slot given up goes straight to the next waiter: a decoder reading ahead that
    gives up its slot and asks again at once cannot take it back before a camera
    whose frame the views wait for (with a plain semaphore it did, and a jump waited
    behind read-ahead for seconds on a loaded machine).

    Parameters
    ----------
    limit : int
        Decodes running at once (at least 1).

    Attributes
    ----------
    peak : int
        Most decodes that ran at once so far (tests, benchmarks).
    """

    def __init__(self, limit: int) -> None:
        self._lock = threading.Lock()
        self._limit = max(int(limit), 1)
        self._busy = 0
        # waiters, each a lock held until a slot is handed to it: urgent, read-ahead
        self._queues: tuple[deque[threading.Lock], deque[threading.Lock]] = (deque(), deque())
        self.peak = 0

    @property
    def limit(self) -> int:
        """Decodes allowed at once."""
        return self._limit

    def acquire(self, urgent: bool = True) -> None:
        """Wait for a slot (``urgent``: ahead of every read-ahead waiter)."""
        with self._lock:
            if self._busy < self._limit and not (self._queues[0] or self._queues[1]):
                self._busy += 1
                self.peak = max(self.peak, self._busy)
                return
            gate = threading.Lock()
            gate.acquire()
            self._queues[0 if urgent else 1].append(gate)
        gate.acquire()  # released by `release`: the slot is this thread's now

    def release(self) -> None:
        """Give the slot up: to the first urgent waiter, else the first other one."""
        with self._lock:
            for queue in self._queues:
                if queue:
                    queue.popleft().release()  # still busy: the slot changes hands
                    return
            self._busy -= 1

    def __enter__(self) -> DecodeSlots:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
