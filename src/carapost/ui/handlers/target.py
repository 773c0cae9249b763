"""Target Tracker: Add/Edit Target Track clicks, the Tracker pane's buttons, nudging.

Every item calls a :class:`~carapost.session.Session` Target Tracker method. A tracking
run is prepared on the GUI thread (``session.prepare_target_track``), computed on the
worker with a worker copy of the window's frame source, and applied as one History
entry; pressing the running track button again (it reads Pause) cancels, which keeps
what was tracked. Every camera is tracked in lockstep (one frame at a time, all cameras):
with Update 2D View Every Frame the views follow the tracked frame once through the
range; with Update Timeline Every Frame the charts draw the tracked span as it grows
(:mod:`carapost.ui.handlers.target_live`).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from PySide6.QtCore import Qt, QTimer

from carapost.algorithms.codes import SOURCE_KEYFRAME, SOURCE_TARGET
from carapost.commands.stack import CommandError
from carapost.ui.context import ActionContext
from carapost.ui.handlers.process import follow_tracking
from carapost.ui.handlers.target_live import live_timeline
from carapost.ui.handlers.target_live_view import live_views

log = logging.getLogger("carapost.ui")

#: Title of each Tracker pane run: (direction, single frame) -> text.
TITLES = {(1, True): "Track forward one frame", (-1, True): "Track back one frame",
          (1, False): "Track forward to end", (-1, False): "Track back to start"}


def tracking_title(ctx: ActionContext) -> str:
    """The title of the running Target Tracker run, or "" if none is running."""
    t = ctx.runner.title if ctx.runner.busy else ""
    return t if t in TITLES.values() else ""


def track(ctx: ActionContext, direction: int, single_frame: bool = False,
          to: int | None = None) -> bool:
    """Tracker pane: track the selected points (or Pause the run in progress)."""
    title = TITLES[(direction, single_frame)]
    if tracking_title(ctx):
        ctx.runner.cancel()               # Pause: keeps what was tracked
        ctx.status("Target Tracker paused", 3000)
        return False
    if ctx.refuse_busy(title):
        return False
    frames = ctx.frames
    if not frames.has_images:
        ctx.report_error(title, f"{title}: the take has no images to track in")
        return False
    source = frames.worker_copy()
    try:
        job = ctx.session.prepare_target_track(direction, single_frame, to,
                                               get_image=source.require)
    except CommandError as exc:
        if source is not frames:
            source.close()
        ctx.report_error(title, str(exc), show=False)
        return False

    def request(frame: int, cameras: list[int], direction: int) -> None:
        for c in cameras:   # the frame's images of every tracked camera decode at once
            source.request(frame, c, direction)

    job.request = request
    unfollow = follow_tracking(ctx, job)
    unlive = live_timeline(ctx, job)
    unviews = live_views(ctx, job)

    def finished(*_: Any) -> None:
        unfollow()
        unlive()
        unviews()
        if source is not frames:
            source.close()

    def applied(result: Any) -> None:
        if result.changes_nothing() and not result.cancelled:   # lost on the first frame
            text = f"{result.message}; nothing changed"
            ctx.report_error(title, text, show=False)
            # after the runner's own "finished" message, which would replace it
            QTimer.singleShot(0, lambda: ctx.status(text, 8000))
            return
        if ctx.apply(result):
            QTimer.singleShot(0, lambda: ctx.status(result.message, 8000))
            # show where the run stopped: the next click of a one-frame button goes on
            # from there, and a lost marker is keyed on its last good frame
            if result.last_frame is not None:
                ctx.set_frame(int(result.last_frame))

    started = ctx.runner.start_job(job, applied, title=title, finished=finished)
    if not started:
        finished()
    return started


def add_keyframe(ctx: ActionContext) -> None:
    """Tracker pane > Add Keyframe To Current Frame."""
    ctx.act("Add Keyframe To Current Frame", ctx.session.add_keyframe)


def clear_tracked_points(ctx: ActionContext) -> None:
    """Tracker pane > Clear Tracked Points (the selected points)."""
    ctx.act("Clear Tracked Points", ctx.session.clear_tracked_points)


def gaps_to_keys(ctx: ActionContext) -> None:
    """Edit > Gaps To Keys (the selected points)."""
    ctx.act("Gaps To Keys", ctx.session.gaps_to_keys)


def set_mode(ctx: ActionContext, mode: str) -> None:
    """Edit > Add Target Track (Shift+A) / Edit Target Track (Shift+E); "" stops."""
    ctx.point_mode = mode
    ctx.view.point_mode = mode
    ctx.view.options_changed.emit()
    text = {"add": "Add Target Track", "edit": "Edit Target Track"}.get(mode, "")
    ctx.status(f"{text}: click in a camera view" if text else "Point edit mode stopped",
               3000)


def clicked(ctx: ActionContext, camera: int, x: float, y: float) -> bool:
    """A click at image (x, y) of ``camera`` in Add / Edit Target Track mode."""
    mode = ctx.point_mode
    f = ctx.project.current_frame
    if mode == "add":
        return ctx.act("Add Target Track", ctx.session.add_target_track, camera, f,
                       (x, y)) is not None
    if mode == "edit":
        sel = sorted(ctx.project.selection.points)
        if len(sel) != 1:
            ctx.report_error("Edit Target Track", "Edit Target Track: select one point "
                             "first", show=False)
            return False
        return ctx.act("Edit Target Track", ctx.session.edit_target_track, sel[0], camera,
                       f, (x, y)) is not None
    return False


def nudge(ctx: ActionContext, dx: int, dy: int) -> None:
    """Ctrl+Shift+arrows: move the selected point's target track in the active camera
    view by a fraction of a pixel (finer the more the view is zoomed in)."""
    p = ctx.project
    sel = sorted(p.selection.points)
    cam = ctx.view.active_camera
    if len(sel) != 1 or cam is None:
        ctx.status("Nudge: select one target-tracked point in a camera view", 3000)
        return
    col = int(p.points.index_of(sel)[0])
    f = p.current_frame
    if p.points.source[f, col, cam] not in (SOURCE_KEYFRAME, SOURCE_TARGET):
        ctx.status("Nudge: the selected point has no target track in this view", 3000)
        return
    scale = getattr(ctx.view, "zoom_scale", None)
    step = 0.1 if scale is None else float(np.clip(1.0 / max(scale(cam), 1e-3), 0.05, 1.0))
    xy = p.points.obs[f, col, cam].astype(np.float64) + step * np.array([dx, dy])
    ctx.act("Nudge Target Track", ctx.session.edit_target_track, sel[0], cam, f, xy)


#: Tracker pane button name -> (direction, single frame).
RUNS = {"back_to_start": (-1, False), "back_one": (-1, True), "forward_one": (1, True),
        "forward_to_end": (1, False)}


def wire_tracker_pane(pane: Any, ctx: ActionContext) -> None:
    """Connect the Tracker pane's buttons; the running track button reads Pause; the
    nudge shortcuts (Ctrl+Shift+arrows) of the window."""
    from functools import partial

    from PySide6.QtGui import QKeySequence, QShortcut

    texts = {name: b.text() for name, b in pane.buttons.items()}
    for name, (d, single) in RUNS.items():
        pane.buttons[name].clicked.connect(partial(track, ctx, d, single))
    pane.buttons["clear"].clicked.connect(partial(clear_tracked_points, ctx))
    pane.buttons["add_keyframe"].clicked.connect(partial(add_keyframe, ctx))

    def started(title: str) -> None:
        for name, (d, single) in RUNS.items():
            if TITLES[(d, single)] == title:
                pane.buttons[name].setText("Pause")
                pane.buttons[name].setToolTip("Pause tracking (keeps what was tracked)")

    def finished(*_: Any) -> None:
        for name, b in pane.buttons.items():
            b.setText(texts[name])

    ctx.runner.started.connect(started)
    ctx.runner.finished.connect(finished)
    ctx.runner.failed.connect(finished)
    pane.nudge_shortcuts = []
    for key, (dx, dy) in {"Ctrl+Shift+Left": (-1, 0), "Ctrl+Shift+Right": (1, 0),
                          "Ctrl+Shift+Up": (0, -1), "Ctrl+Shift+Down": (0, 1)}.items():
        sc = QShortcut(QKeySequence(key), pane.window() if pane.window() is not pane
                       else pane)
        sc.setContext(Qt.ShortcutContext.ApplicationShortcut)
        sc.activated.connect(partial(nudge, ctx, dx, dy))
        pane.nudge_shortcuts.append(sc)
