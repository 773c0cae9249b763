"""Playback in lockstep: the frames every camera's decoder works through while playing.

Each camera chasing the playback clock on its own decodes whichever frame is due when
its decoder comes free; four decoders that cannot keep up then decode four different
sets of frames, and few frames have the images of all cameras (only those can be
shown). `PlaySchedule` is one list of frames for every camera instead:

- a camera takes the first scheduled frame it has not done (`next`);
- a camera that has done them all schedules the next frame at or after the clock, for
  every camera, unless another camera still has `LOCKSTEP_SLACK` scheduled frames to
  do while it is behind the clock (`AHEAD_SLACK` while it is not): then it waits, and
  the slowest camera gets the cores;
- scheduled frames the clock has passed are dropped by every camera, unless a camera
  started or decoded one already: that frame is finished by all, and shown if nothing
  newer is complete by then.

So when the decoders cannot keep up, whole frames are dropped and every frame decoded
is complete; when they can, the schedule runs ahead of the clock up to the read-ahead
limit and every camera reads the same frames ahead. The schedule is plain data guarded
by the frame service's lock (`carapost.io.frameservice.FrameService`); each camera
keeps a cursor into it, so finding its next frame costs O(1) amortised.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["AHEAD_SLACK", "LOCKSTEP_SLACK", "PlaySchedule"]

#: How many scheduled frames a camera may still have to decode before the others wait
#: for it. 1 would hold the decoders on the same frame; 2 lets a camera whose decode
#: ended start the next scheduled frame while the slowest finishes, so no core idles.
LOCKSTEP_SLACK = 2
#: The same while every camera is at or ahead of the clock (reading ahead): a camera
#: that a loaded machine leaves without a core for a moment does not hold the others
#: back, and it catches up later (so cheap proxy frames play as fast as each camera
#: can decode them). Also bounds how far a camera can be behind when the decoders
#: fall behind the clock.
AHEAD_SLACK = 4

#: ``done(frame, camera)``: the camera has nothing to decode there (cached, blank or
#: failed). ``started(frame)``: some camera decodes or has decoded the frame.
Done = Callable[[int, int], bool]
Started = Callable[[int], bool]


class PlaySchedule:
    """The frames every camera decodes while playing (see the module docstring).

    Parameters
    ----------
    n_cameras : int
    slack, ahead_slack : int
        `LOCKSTEP_SLACK` and `AHEAD_SLACK` unless a test says otherwise.

    Attributes
    ----------
    clock : int or None
        The frame the playback clock is at (None: not playing).
    frames : list of int
        The scheduled frames not yet forgotten, increasing.
    """

    def __init__(self, n_cameras: int, slack: int = LOCKSTEP_SLACK,
                 ahead_slack: int = AHEAD_SLACK) -> None:
        self.n_cameras = int(n_cameras)
        self.slack = max(int(slack), 1)
        self.ahead_slack = max(int(ahead_slack), self.slack)
        self.clock: int | None = None
        self.frames: list[int] = []
        self._base = 0  # schedule index of frames[0] (frames forgotten before it)
        self._cursor = [0] * self.n_cameras  # per camera: schedule index to look at next

    def reset(self) -> None:
        """Forget the schedule and the clock (playback stopped)."""
        self.clock = None
        self._forget_all()

    def set_clock(self, frame: int) -> None:
        """The playback clock is at ``frame`` (going back forgets the schedule)."""
        frame = int(frame)
        if self.clock is not None and frame < self.clock:
            self._forget_all()
        self.clock = frame

    def next(self, camera: int, done: Done, started: Started, end: int) -> int | None:
        """The next frame ``camera`` decodes, or None: wait (for the clock, or for
        the slowest camera). New frames are scheduled before ``end`` only (the take's
        end or the read-ahead limit)."""
        due = self.clock
        if due is None:
            return None
        self._prune(due, done, started)
        frame = self._first_undone(camera, done)
        if frame is not None:
            return frame
        others = [c for c in range(self.n_cameras) if c != camera]
        # behind the clock, a camera's next scheduled frame is one the clock passed
        behind = any((f := self._first_undone(c, done)) is not None and f < due
                     for c in others)
        slack = self.slack if behind else self.ahead_slack
        if any(self._undone(c, done, slack) >= slack for c in others):
            return None  # the slowest camera gets the cores
        f = max(self.frames[-1] + 1 if self.frames else due, due)
        while f < end:
            self.frames.append(f)
            if not done(f, camera):
                self._cursor[camera] = self._base + len(self.frames) - 1
                return f
            f += 1
        self._cursor[camera] = self._base + len(self.frames)
        return None

    # -- helpers -----------------------------------------------------------------------------
    def _forget_all(self) -> None:
        self._base += len(self.frames)
        self.frames = []

    def _complete(self, frame: int, done: Done) -> bool:
        return all(done(frame, c) for c in range(self.n_cameras))

    def _prune(self, due: int, done: Done, started: Started) -> None:
        frames = self.frames
        drop = 0
        # passed by the clock: complete (nothing left to do) or not started by anyone
        while drop < len(frames) and frames[drop] < due and (
                not started(frames[drop]) or self._complete(frames[drop], done)):
            drop += 1
        if drop:
            del frames[:drop]
            self._base += drop
        if frames and frames[0] < due:
            # behind the clock, a started frame waits to be finished: the unstarted ones
            # passed after it are dropped too (the schedule is short here)
            keep = [f for f in frames if f >= due
                    or (started(f) and not self._complete(f, done))]
            if len(keep) != len(frames):
                self.frames = keep
                self._cursor = [self._base] * self.n_cameras

    def _first_undone(self, camera: int, done: Done) -> int | None:
        i = max(self._cursor[camera], self._base)
        end = self._base + len(self.frames)
        while i < end:
            f = self.frames[i - self._base]
            if not done(f, camera):
                self._cursor[camera] = i
                return f
            i += 1
        self._cursor[camera] = end
        return None

    def _undone(self, camera: int, done: Done, at_most: int) -> int:
        """Scheduled frames ``camera`` still has to do (counted up to ``at_most``)."""
        i = max(self._cursor[camera], self._base) - self._base
        count = 0
        while i < len(self.frames) and count < at_most:
            if not done(self.frames[i], camera):
                count += 1
            i += 1
        return count
