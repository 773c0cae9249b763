"""A Target Tracker run drawn in the camera views as it goes: Update 2D View Every Frame.

With the preference on, the views follow the frame the run has reached
(`carapost.ui.handlers.process.follow_tracking`); this module draws, in each camera
view, where the run has just tracked the selected points on that frame (a broken blue
circle, as a tracked frame), so the artist sees a track drifting off its marker while
the run goes and can Pause it. The positions come from the job's ``live_xy`` (the latest
(frame, x, y) of each point and camera, written by the worker); the model is written
only by the result, which the views then draw from the model.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from carapost.ui.context import ActionContext
from carapost.ui.handlers.process import FOLLOW_TRACKING
from carapost.ui.settings import preference

__all__ = ["live_views"]


def _camera_views(ctx: ActionContext) -> list[Any]:
    shell = ctx.shell
    return [v for v in (shell.all_views() if shell is not None else ())
            if getattr(v, "kind", "") == "sensor" and hasattr(v, "targets")]


def live_views(ctx: ActionContext, job: Any) -> Callable[[], None]:
    """Draw ``job``'s tracked positions in the camera views while it runs, when Update
    2D View Every Frame is on, and give them to the Selected Point pane
    (``ViewContext.live_xy``); returns the function that stops it (call it when the run
    has ended)."""
    if getattr(job, "live_xy", None) is None:
        return lambda: None
    view_ctx = ctx.view
    start, stop = getattr(job, "start", 0), getattr(job, "stop", 0)
    view_ctx.live_direction = -1 if (stop or 0) < (start or 0) else 1

    def sample(_done: int = 0, _total: int = 0) -> None:
        # the Selected Point pane reads the frame the run has just tracked from here
        view_ctx.live_xy = dict(job.live_xy)   # a copy: the worker goes on writing
        view_ctx.live_changed.emit()

    def unsample() -> None:
        ctx.runner.progressed.disconnect(sample)
        view_ctx.live_xy = None
        view_ctx.live_changed.emit()

    ctx.runner.progressed.connect(sample)
    if not preference(ctx.settings, FOLLOW_TRACKING):
        return unsample
    from carapost.ui.views.target_overlay import track_sizes

    def tick(_done: int = 0, _total: int = 0) -> None:
        latest = dict(job.live_xy)          # a copy: the worker goes on writing
        frame = ctx.project.current_frame
        for view in _camera_views(ctx):
            cam = view.camera
            here = [(pid, x, y) for (pid, c), (f, x, y) in latest.items()
                    if c == cam and f == frame]
            if not here:
                view.targets.show_live(np.empty((0, 2)), np.empty(0))
                continue
            pts = ctx.project.points
            cols = pts.index_of([pid for pid, _, _ in here])
            size_p, _ = track_sizes(ctx.project, cam)
            view.targets.show_live(np.array([(x, y) for _, x, y in here]), size_p[cols])

    ctx.runner.progressed.connect(tick)

    def stop() -> None:
        ctx.runner.progressed.disconnect(tick)
        for view in _camera_views(ctx):
            view.targets.clear_live()
        unsample()

    return stop
