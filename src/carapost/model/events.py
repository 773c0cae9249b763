"""Change events of the project model: plain callbacks, no Qt.

The model calls :meth:`EventHub.emit` after a validated, real change; views and the
Qt adapter subscribe and redraw only what the event names.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("carapost.model")

#: The parts of a project that can change.
PARTS = frozenset(
    {
        "points",  # 3D positions, observations, reconstruction kinds
        "point_list",  # points added, removed or reordered
        "detections",
        "frames_range",  # frame count / take length
        "cameras",  # camera channels, intrinsics, extrinsics
        "labels",
        "sticks",
        "properties",
        "selection",
        "ranges",  # active range, view range
        "current_frame",
        "rom",
        "file",  # project path / saved state
        "stabilization",  # Stabilize Data, Align Data, Show Stabilized (no raw change)
    }
)


@dataclass(frozen=True)
class Change:
    """What changed.

    Attributes
    ----------
    parts : frozenset of str
        Names from :data:`PARTS`.
    frames : tuple of (int, int) or None
        Inclusive frame range affected, None for all / not frame-specific.
    points : ndarray or None
        Point columns (indices into the point arrays at the time of the change) whose
        per-point arrays changed; None for all or not known more precisely (always None
        when ``point_list`` changed, as columns then shift).
    cameras : ndarray or None
        Camera indices affected (detections of those cameras' images), None for all.

    Commands fill these from what their journal saved
    (:meth:`carapost.commands.stack.Journal.extent`), so a view can redraw only the
    frames and points named.
    """

    parts: frozenset[str]
    frames: tuple[int, int] | None = None
    points: np.ndarray | None = field(default=None, compare=False)
    cameras: np.ndarray | None = field(default=None, compare=False)


Listener = Callable[[Change], None]


def merge_changes(changes: list[Change]) -> Change:
    """One change covering several: the union of parts, frames, points and cameras.

    ``frames`` becomes the range spanning every change's frames; ``points`` and
    ``cameras`` the union of the indices. Any change with None on an axis (all, or
    not known more precisely) makes the merged axis None.
    """
    parts = frozenset().union(*(c.parts for c in changes))
    frames = None
    if changes and all(c.frames is not None for c in changes):
        frames = (min(c.frames[0] for c in changes), max(c.frames[1] for c in changes))

    def union(axis: str) -> np.ndarray | None:
        values = [getattr(c, axis) for c in changes]
        if not values or any(v is None for v in values):
            return None
        return np.unique(np.concatenate([np.atleast_1d(v) for v in values])).astype(np.intp)

    return Change(parts, frames, union("points"), union("cameras"))


class EventHub:
    """Publish/subscribe for :class:`Change` events, with batching."""

    def __init__(self) -> None:
        self._listeners: list[Listener] = []
        self._batch_depth = 0
        self._pending: list[Change] = []

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Add a listener; returns a function that removes it."""
        self._listeners.append(listener)

        def unsubscribe() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return unsubscribe

    def emit(
        self,
        *parts: str,
        frames: tuple[int, int] | None = None,
        points: np.ndarray | None = None,
        cameras: np.ndarray | None = None,
    ) -> None:
        """Tell listeners that ``parts`` changed (deferred while a batch is open)."""
        unknown = set(parts) - PARTS
        if unknown:
            raise ValueError(f"unknown change parts: {sorted(unknown)}")
        change = Change(frozenset(parts), frames, points, cameras)
        if self._batch_depth:
            self._pending.append(change)
            return
        self._dispatch(change)

    def _dispatch(self, change: Change) -> None:
        for listener in list(self._listeners):
            try:
                listener(change)
            except Exception:  # a broken view must not break the edit
                log.exception("change listener %r failed", listener)

    def batch(self) -> _Batch:
        """Context manager: merge every change emitted inside into one event."""
        return _Batch(self)


class _Batch:
    def __init__(self, hub: EventHub) -> None:
        self.hub = hub

    def __enter__(self) -> EventHub:
        self.hub._batch_depth += 1
        return self.hub

    def __exit__(self, *exc: object) -> None:
        hub = self.hub
        hub._batch_depth -= 1
        if hub._batch_depth or not hub._pending:
            return
        pending, hub._pending = hub._pending, []
        hub._dispatch(merge_changes(pending))
