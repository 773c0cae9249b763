"""Several target tracks advanced together, one frame at a time (lockstep).

A Target Tracker run follows a point in every camera where it has a 2D position, and
several points at once. Tracked one camera after the other, the run would sweep the
range once per camera (the views, the timeline and the progress bar jumping back to
the start each time, and the images of a frame requested once per camera, far apart in
time). :class:`LockstepTracker` advances every (marker, camera) track by one frame per
:meth:`~LockstepTracker.step`: the frame's images of all the cameras are wanted at
once, a track that stops (its score fell below the Break Threshold, it reached its
``stop``) drops out and the others go on.

Each track is exactly one :func:`carapost.algorithms.target_track.track_target` call,
run as a coroutine (a greenlet) that is suspended in its ``progress`` callback after
every frame and resumed for the next one. The tracking loop is therefore not written
twice: a lockstep track visits the same frames, reads the same images and returns the
very same :class:`~carapost.algorithms.target_track.TargetTrackResult` as the plain
call, and every change to the per-camera tracker applies here unchanged.

Example
-------
>>> import numpy as np, cv2
>>> yy, xx = np.mgrid[0:64, 0:96]
>>> bg = cv2.GaussianBlur(np.random.default_rng(1).normal(140, 20, (64, 96)), (0, 0), 1.5)
>>> def image(f, speed):
...     r = np.hypot(xx - (30 + speed * f), yy - 31.6)
...     return np.clip(bg - 90 / (1 + np.exp((r - 4) * 3)), 0, 255).astype(np.uint8)
>>> p = TargetTrackerParameters(search_size=41)
>>> runs = [TrackRun(lambda f, s=s: image(f, s), {0: (30.0, 31.6)}, start=0, stop=stop,
...                  direction=1, params=p) for s, stop in ((0.37, 20), (0.2, 5))]
>>> lock = LockstepTracker(runs)
>>> [lock.step() for _ in range(6)], lock.active
([1, 2, 3, 4, 5, 6], [0])
>>> results = lock.run()
>>> [(r.reason, len(r.frames)) for r in results]
[('end', 21), ('end', 6)]
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from greenlet import GreenletExit, getcurrent, greenlet
from numpy.typing import NDArray

from carapost.algorithms.target_track import (
    TargetTrackerParameters,
    TargetTrackResult,
    track_target,
)

__all__ = ["LockstepTracker", "TrackRun"]


@dataclass
class TrackRun:
    """The arguments of one :func:`~carapost.algorithms.target_track.track_target` call
    (one marker in one camera); see that function for their meaning."""

    get_image: Callable[[int], NDArray[Any]]
    keyframes: Mapping[int, Any]
    start: int
    stop: int
    direction: int
    params: TargetTrackerParameters | None = None
    start_xy: Any = None
    start_velocity: Any = None
    on_frame: Callable[[int, NDArray[np.float64], float], None] | None = None

    @property
    def length(self) -> int:
        """Frames this run may track at most (after its start frame)."""
        n = abs(int(self.stop) - int(self.start))
        p = self.params if self.params is not None else TargetTrackerParameters()
        return min(n, p.n_frames) if p.stop_after_n_frames else n


class LockstepTracker:
    """Track runs that share a start frame and a direction, one frame at a time.

    Parameters
    ----------
    runs : sequence of TrackRun
        Every run starts at the same frame and goes in the same direction.

    Attributes
    ----------
    results : list of TargetTrackResult or None
        Per run: its result once it has stopped (None while it tracks).
    done : int
        Frames stepped so far (the runs still active have tracked ``start + done *
        direction``).

    Notes
    -----
    The greenlets belong to the thread that calls :meth:`step` first; call every method
    from that thread (a worker's ``compute``).
    """

    def __init__(self, runs: Sequence[TrackRun]) -> None:
        self.runs = list(runs)
        if not self.runs:
            raise ValueError("lockstep tracking needs at least one track")
        starts = {int(r.start) for r in self.runs}
        dirs = {int(r.direction) for r in self.runs}
        if len(starts) != 1 or len(dirs) != 1:
            raise ValueError("lockstep tracks must share their start frame and direction "
                             f"(got starts {sorted(starts)}, directions {sorted(dirs)})")
        self.start, self.direction = starts.pop(), dirs.pop()
        self.results: list[TargetTrackResult | None] = [None] * len(self.runs)
        self.done = 0
        self._lets: list[greenlet | None] = [None] * len(self.runs)
        self._started = False

    @property
    def total(self) -> int:
        """Steps until the longest run reaches its end (a run may stop sooner)."""
        return max(r.length for r in self.runs)

    @property
    def active(self) -> list[int]:
        """Indices of the runs still tracking."""
        return [i for i, r in enumerate(self.results) if r is None]

    @property
    def next_frame(self) -> int | None:
        """The frame the next :meth:`step` tracks (None when every run has stopped)."""
        if self._started and not self.active:
            return None
        return self.start + (self.done + 1) * self.direction

    def _body(self, i: int) -> TargetTrackResult:
        r = self.runs[i]

        def progress(done: int, total: int) -> bool:
            # suspended here after every frame; the value resumed with is the verdict
            return bool(getcurrent().parent.switch((done, total)))

        return track_target(r.get_image, r.keyframes, start=r.start, stop=r.stop,
                            direction=r.direction, params=r.params, start_xy=r.start_xy,
                            start_velocity=r.start_velocity, progress=progress,
                            on_frame=r.on_frame)

    def _resume(self, i: int, go: bool) -> None:
        g = self._lets[i]
        if g is None:
            g = self._lets[i] = greenlet(lambda i=i: self._body(i))
            out = g.switch()
        else:
            g.parent = getcurrent()
            out = g.switch(go)
        if not g.dead and go and out[0] >= out[1]:
            out = g.switch(True)    # its last frame: let it return now, not next step
        if g.dead:
            self.results[i] = out
            self._lets[i] = None

    def _each(self, go: bool) -> None:
        try:
            for i in self.active:
                self._resume(i, go)
        except BaseException:
            self.close()
            raise

    def step(self) -> int | None:
        """Track the next frame in every active run; the frame, or None when every run
        had already stopped. A run that stops on this frame drops out."""
        frame = self.next_frame
        if frame is None:
            return None
        self._each(True)
        self._started = True
        self.done += 1
        return frame

    def cancel(self) -> list[TargetTrackResult | None]:
        """Stop every active run where it is (reason ``cancelled``, keeping what it
        tracked) and return the results (None for a run never stepped)."""
        if self._started:
            self._each(False)
        return self.results

    def run(self, progress: Callable[[int, int], bool | None] | None = None,
            before_step: Callable[[int, list[int]], None] | None = None
            ) -> list[TargetTrackResult | None]:
        """Step until every run has stopped.

        Parameters
        ----------
        progress : callable, optional
            ``progress(done, total)`` after each step; returning False cancels (the
            runs keep what they tracked).
        before_step : callable, optional
            ``before_step(frame, runs)`` before each step with the frame about to be
            tracked and the indices of the runs that track it (to ask for the frame's
            images of all their cameras at once).

        Returns
        -------
        list of TargetTrackResult
            Per run, in the order given.
        """
        total = max(self.total, 1)
        try:
            while (frame := self.next_frame) is not None:
                if before_step is not None:
                    before_step(frame, self.active)
                self.step()
                if (progress is not None
                        and progress(min(self.done, total), total) is False
                        and self.active):
                    return self.cancel()
        except BaseException:   # a callback failed: no track is left suspended
            self.close()
            raise
        return self.results

    def close(self) -> None:
        """End the runs still suspended (after an error); their results stay None."""
        for i, g in enumerate(self._lets):
            if g is not None and not g.dead:
                try:
                    g.throw(GreenletExit)
                except GreenletExit:
                    pass
            self._lets[i] = None
