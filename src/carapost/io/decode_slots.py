"""A counting gate around each frame's decode, urgent decodes first.

Used by `carapost.io.frameservice` (`DECODE_SLOTS`, `shared_slots`): at most as many
frames decode at once as the process has cores, so no decoder preempted while it holds
the GIL keeps the GUI thread waiting behind another decoder's time slice.
"""

from __future__ import annotations

import threading
from collections import deque


class SlotWait:
    """A read-ahead decoder's wait for a slot, which another thread may call off
    (`DecodeSlots.cancel`): the camera's frame was asked for meanwhile, and waiting on
    behind every urgent decode for a frame nobody needs now would hold up the one that
    is needed (a jump waited up to 150 ms for it in the window)."""

    __slots__ = ("cancelled", "gate")

    def __init__(self) -> None:
        self.cancelled = False
        self.gate: threading.Lock | None = None


class DecodeSlots:
    """A counting gate around each frame's decode (`DECODE_SLOTS`), first come first
    served, urgent decodes (a view's or a job's frame, playback) before read-ahead.

    A slot given up goes straight to the next waiter: a decoder reading ahead that
    gives up its slot and asks again at once cannot take it back before a camera
    whose frame the views wait for (with a plain semaphore it did, and a jump waited
    behind read-ahead for seconds on a loaded machine). A read-ahead wait can be called
    off (`SlotWait`, `cancel`).

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

    def acquire(self, urgent: bool = True, wait: SlotWait | None = None) -> bool:
        """Wait for a slot (``urgent``: ahead of every read-ahead waiter).

        Returns False, holding no slot, when ``wait`` was cancelled before a slot was
        handed to this thread; True when the slot is this thread's."""
        with self._lock:
            if wait is not None and wait.cancelled:
                return False
            if self._busy < self._limit and not (self._queues[0] or self._queues[1]):
                self._busy += 1
                self.peak = max(self.peak, self._busy)
                return True
            gate = threading.Lock()
            gate.acquire()
            self._queues[0 if urgent else 1].append(gate)
            if wait is not None:
                wait.gate = gate
        gate.acquire()  # released by `release` (the slot is this thread's) or `cancel`
        return wait is None or not wait.cancelled

    def cancel(self, wait: SlotWait | None) -> None:
        """Call off ``wait``: its thread returns from `acquire` without a slot, at once
        if it is queued, or at its next `acquire` with that ``wait``. A slot already
        handed to it stays its own (it releases it as usual)."""
        if wait is None:
            return
        with self._lock:
            if wait.cancelled:
                return
            gate = wait.gate
            if gate is None:  # not queued (yet): its acquire sees the flag
                wait.cancelled = True
                return
            for queue in self._queues:
                if gate in queue:
                    queue.remove(gate)
                    wait.cancelled = True
                    gate.release()
                    return
            # handed a slot already: nothing to call off

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
