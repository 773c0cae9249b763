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

    Read-ahead decodes only start while fewer than ``ahead_limit`` decodes run: by
    default one core fewer than ``limit``, so the GUI thread always finds a core free
    while the decoders fill the cache. A lower nice value is not enough: a thread at
    nice 0 that wakes while every core runs a nice +10 thread waited up to 80 ms for
    one on this machine's scheduler (docs/benchmarks.md, eighteenth session), against
    at most 4 ms with a core left free.

    Parameters
    ----------
    limit : int
        Decodes running at once (at least 1).
    ahead_limit : int, optional
        Decodes running at once when a read-ahead one may start (default ``limit - 1``,
        at least 1).

    Attributes
    ----------
    peak : int
        Most decodes that ran at once so far (tests, benchmarks).
    """

    def __init__(self, limit: int, ahead_limit: int | None = None) -> None:
        self._lock = threading.Lock()
        self._limit = max(int(limit), 1)
        self._ahead = max(min(self._limit - 1 if ahead_limit is None else int(ahead_limit),
                              self._limit), 1)
        self._busy = 0
        # waiters, each a lock held until a slot is handed to it: urgent, read-ahead
        self._queues: tuple[deque[threading.Lock], deque[threading.Lock]] = (deque(), deque())
        self.peak = 0

    @property
    def limit(self) -> int:
        """Decodes allowed at once."""
        return self._limit

    @property
    def ahead_limit(self) -> int:
        """Decodes running at once below which a read-ahead one may start."""
        return self._ahead

    def acquire(self, urgent: bool = True, wait: SlotWait | None = None) -> bool:
        """Wait for a slot (``urgent``: ahead of every read-ahead waiter).

        Returns False, holding no slot, when ``wait`` was cancelled before a slot was
        handed to this thread; True when the slot is this thread's."""
        with self._lock:
            if wait is not None and wait.cancelled:
                return False
            # first come first served within a class; an urgent decode does not queue
            # behind read-ahead that waits only for its own cap
            cap = self._limit if urgent else self._ahead
            if self._busy < cap and not self._queues[0] and (urgent or not self._queues[1]):
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
        """Give the slot up: to the first urgent waiter, else to the first read-ahead
        one if fewer than `ahead_limit` others decode."""
        with self._lock:
            urgent, ahead = self._queues
            if urgent or (ahead and self._busy - 1 < self._ahead):
                (urgent or ahead).popleft().release()  # still busy: it changes hands
                return
            self._busy -= 1

    def __enter__(self) -> DecodeSlots:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
