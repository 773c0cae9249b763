"""A Target Tracker run drawn as it goes: Update Timeline Every Frame.

With the preference on, the Selected Point pane and every Continuity chart draw the
span a run has tracked so far, coloured by score, while the run is on the worker. The
job appends what it tracked to its ``live`` list; the GUI thread reads it on the
runner's progress signal, at most every :data:`INTERVAL` seconds, so a fast run does not
spend its time redrawing charts. With the preference off the charts change once, when
the run's result is applied. Either way the model is written only by the result (one
History entry); what was drawn live is replaced by the model's codes at the end.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from carapost.ui.context import ActionContext
from carapost.ui.settings import preference

__all__ = ["INTERVAL", "LIVE_TIMELINE", "live_timeline"]

#: the user preference (Tracker pane, this computer) that draws the run as it goes
LIVE_TIMELINE = "tracker_update_timeline_every_frame"
#: Shortest time between two live redraws of the charts (s).
INTERVAL = 0.25


def _charts(ctx: ActionContext) -> list[Any]:
    """The Continuity charts of the window: the Selected Point pane's and the views'."""
    charts = []
    shell = ctx.shell
    pane = getattr(shell, "pane", None)
    if pane is not None:
        try:
            chart = getattr(pane("Selected Point"), "chart", None)
        except KeyError:
            chart = None
        if chart is not None:
            charts.append(chart)
    for view in shell.all_views() if shell is not None else ():
        if getattr(view, "kind", "") == "continuity" and hasattr(view, "show_live"):
            charts.append(view)
    return charts


class _Live:
    """Feeds a job's ``live`` list to the charts (GUI thread)."""

    def __init__(self, ctx: ActionContext, job: Any) -> None:
        self.ctx, self.job = ctx, job
        self.read = 0
        self.last = 0.0
        self.tracks: dict[tuple[int, int], tuple[list[int], list[float]]] = {}
        self.redraws = 0

    def tick(self, _done: int = 0, _total: int = 0) -> None:
        now = time.monotonic()
        if now - self.last >= INTERVAL:
            self.last = now
            self.flush()

    def flush(self) -> None:
        new = self.job.live[self.read:]   # a slice: safe while the worker appends
        if not new:
            return
        self.read += len(new)
        for pid, cam, frame, score in new:
            frames, scores = self.tracks.setdefault((int(pid), int(cam)), ([], []))
            frames.append(frame)
            scores.append(score)
        project = self.ctx.project
        charts = _charts(self.ctx)
        for (pid, cam), (frames, scores) in self.tracks.items():
            try:
                col = int(project.points.index_of([pid])[0])
            except KeyError:
                continue
            # the whole span so far: a chart that rebuilt its codes meanwhile (a change
            # of selection) gets all of it back
            fr, sc = np.asarray(frames), np.asarray(scores)
            for chart in charts:
                chart.show_live(col, cam, fr, sc)
        self.redraws += 1

    def stop(self) -> None:
        for chart in _charts(self.ctx):
            chart.clear_live()


def live_timeline(ctx: ActionContext, job: Any) -> Callable[[], None]:
    """Draw ``job``'s tracked span in the charts as it runs, when Update Timeline Every
    Frame is on; returns the function that stops it (call it when the run ended, after
    its result was applied)."""
    if getattr(job, "live", None) is None or not preference(ctx.settings, LIVE_TIMELINE):
        return lambda: None
    live = _Live(ctx, job)
    ctx.runner.progressed.connect(live.tick)

    def stop() -> None:
        ctx.runner.progressed.disconnect(live.tick)
        live.stop()

    return stop
