"""Playback of the view range at the take's frame rate (View > Play, Space).

The frame shown follows the wall clock: frame = start + elapsed x fps. When the images
of a frame are not decoded by the time the next one is due, that frame is dropped (the
views show the newest frame whose images have all arrived) and the status bar says how
many frames per second are really shown, so a take that plays slowly is never mistaken
for slow motion.

Frames are dropped by the schedule, not by the timer's jitter: the timer is set for
the moment the next frame is due (not a fixed period, which shows each frame up to
one period late), and a frame that comes less than `LATE_FRAMES` frame times late (a
tick delayed by a paint, a pane's refresh or the machine's load) is still shown, with
the next one following as soon as it is painted; only a frame later than that is
skipped, so playback catches the clock up within a few frames and never drifts into
slow motion.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

from PySide6.QtCore import QObject, Qt, QTimer, Signal

if TYPE_CHECKING:
    from carapost.ui.context import ActionContext

#: Seconds between two reports of the playback rate in the status bar.
REPORT_EVERY_S = 1.0
#: A frame later than this (in frame times) is skipped; an earlier one is shown late.
LATE_FRAMES = 2.0
#: Milliseconds before looking again when playback is behind the clock or waiting for
#: the images of the next frame (the frame just set is painted in between).
RETRY_MS = 2


class Playback(QObject):
    """Steps the current frame through the view range and stops at its end.

    Signals
    -------
    playing_changed(bool)
        Playback started or stopped (the timebar button and View > Play follow).
    rate_changed(float, float)
        Once a second while playing: frames per second shown and the take's rate.

    Attributes
    ----------
    shown, dropped : int
        Frames shown with all their images, and frames skipped (more than
        `LATE_FRAMES` late), since playback started.
    late : int
        Frames shown late (behind the clock, by less than `LATE_FRAMES`).
    """

    playing_changed = Signal(bool)
    rate_changed = Signal(float, float)

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__(ctx)
        self.ctx = ctx
        # single shot, set for the next frame's due time after every tick
        self.timer = QTimer(self)
        self.timer.setSingleShot(True)
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.timeout.connect(self._tick)
        self._playing = False
        self.clock = time.perf_counter  # seconds; replaced by tests
        self._t0 = 0.0
        self._f0 = 0
        self._fps = 0.0
        self.shown = 0
        self.dropped = 0
        self.late = 0
        self._window: list[int] = [0, 0]  # shown, dropped since the last report
        self._last_report = 0.0
        self._requested = -1  # frame the decoders were last sent to

    @property
    def playing(self) -> bool:
        """Whether playback runs."""
        return self._playing

    @property
    def fps(self) -> float:
        """Frame rate playback follows (the take's; 30 when the take does not say)."""
        rate = float(self.ctx.project.take.fps or 0.0)
        return rate if rate > 0 else 30.0

    def toggle(self, on: bool) -> None:
        """Play (from the view range's start when at its end) or stop."""
        p = self.ctx.project
        if on and p.n_frames:
            if p.current_frame >= p.view_range[1]:
                self.ctx.set_frame(p.view_range[0])
            self._fps = self.fps
            self._t0 = self.clock()
            self._f0 = p.current_frame
            self.shown = self.dropped = self.late = 0
            self._window = [0, 0]
            self._last_report = self._t0
            self._requested = -1
            self.ctx.frames.set_playing(self._fps)
            self.ctx.view.playing = True
            self._playing = True
            self._schedule()
        else:
            self._playing = False
            self.timer.stop()
            self.ctx.view.playing = False
            self.ctx.frames.set_playing(None)
            # back to the original images where a view shows a proxy frame (or not the
            # current frame's image yet); one that already shows the original is left
            # alone: redrawing four 1280x720 images at once was a 50-75 ms stall
            shell = self.ctx.shell
            current = self.ctx.project.current_frame
            for view in shell.all_views() if shell is not None else ():
                if view.kind == "sensor" and (
                        getattr(view, "showing_proxy", True)
                        or getattr(view, "image_frame", None) != current):
                    view.refresh(None)
            if self.shown or self.dropped:
                self._report(final=True)
        self.playing_changed.emit(self.playing)

    def stop(self) -> None:
        """Stop playback (nothing happens when it is not running)."""
        if self.playing:
            self.toggle(False)

    def _ready(self, frame: int) -> bool:
        frames = self.ctx.frames
        if not frames.asynchronous:  # images made on demand (synthetic takes, tests)
            return True
        return all(frames.cached(frame, c) is not None
                   for c in range(self.ctx.project.n_cameras))

    def _due_time(self, frame: int) -> float:
        """Clock time (s) at which ``frame`` is due."""
        return self._t0 + (frame - self._f0) / self._fps

    def _schedule(self) -> None:
        """Set the timer for the next frame's due time (at once when behind)."""
        if not self._playing:
            return
        wait_s = self._due_time(self.ctx.project.current_frame + 1) - self.clock()
        # rounded up: a tick a little early would only find nothing due yet
        self.timer.start(max(math.ceil(wait_s * 1e3), 0) if wait_s > 0 else RETRY_MS)

    def target(self, now: float) -> tuple[int, int]:
        """(frame due by the clock at ``now``, newest frame to show now).

        The frame after the one on screen is shown while it is less than
        `LATE_FRAMES` frame times late, even when the clock has moved past it; later
        than that, playback jumps to the clock (the frames in between are dropped).
        """
        p = self.ctx.project
        end = p.view_range[1]
        due = min(self._f0 + int((now - self._t0) * self._fps), end)
        following = p.current_frame + 1
        if due > following and (now - self._due_time(following)) * self._fps < LATE_FRAMES:
            return due, following
        return due, due

    def _tick(self) -> None:
        if not self._playing:
            return
        p = self.ctx.project
        now = self.clock()
        end = p.view_range[1]
        due, target = self.target(now)
        if due <= p.current_frame:
            if p.current_frame >= end:
                self._finish()
            else:
                self._schedule()
            return
        # Show the newest frame up to the target whose images of every camera have
        # arrived (the cameras stay in step); the frames passed over are dropped.
        show = next((f for f in range(target, p.current_frame, -1) if self._ready(f)), None)
        if show is not None:
            skipped = show - p.current_frame - 1
            self.shown += 1
            self._window[0] += 1
            self.dropped += skipped
            self._window[1] += skipped
            self.late += show < due
            self.ctx.set_frame(show)
        # the decoders head for the clock, not for the frame on screen, all cameras
        # through the same frames (lockstep: FrameService.set_clock); once per frame
        # due (every call wakes every decoder)
        if due != self._requested:
            self._requested = due
            self.ctx.frames.set_clock(due)
        if now - self._last_report >= REPORT_EVERY_S:
            self._report()
            self._last_report = now
        if p.current_frame >= end:
            self._finish()
        else:
            self._schedule()

    def _finish(self) -> None:
        self.stop()

    def _report(self, final: bool = False) -> None:
        shown, dropped = (self.shown, self.dropped) if final else self._window
        total = shown + dropped
        if total == 0:
            return
        elapsed = max(self.clock() - self._t0, 1e-6) if final else REPORT_EVERY_S
        rate = shown / elapsed
        self.rate_changed.emit(rate, self._fps)
        if dropped:
            self.ctx.status(f"Playing {rate:.0f} of {self._fps:.0f} frames/s: "
                            f"{dropped} of {total} frames dropped (decoding cannot keep up)",
                            2500)
        self._window = [0, 0]
