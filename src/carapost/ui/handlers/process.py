"""Process menu: every item is a :class:`~carapost.session.Session` Process action.

The long ones follow the recipe in the window's threads: ``session.prepare(action,
...)`` validates and snapshots on the GUI thread, ``job.compute(progress)`` runs on the
worker (with its own image decoder), and ``ctx.apply(result)`` pushes the one History
entry on the GUI thread. Default brims and Load ROM change the project at once.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from carapost.commands.recipe import Job
from carapost.commands.stack import CommandError
from carapost.ui.context import ActionContext
from carapost.ui.handlers.file import CARA_FILTER
from carapost.ui.settings import preference

log = logging.getLogger("carapost.ui")

#: the user preference (Tracker pane, this computer) that makes the views follow tracking
FOLLOW_TRACKING = "tracker_update_2d_view_every_frame"


def follow_tracking(ctx: ActionContext, job: Job) -> Callable[[], None]:
    """With Update 2D View Every Frame on, the views show each frame as it is tracked
    (the current frame follows the job's progress); returns the function that stops it.

    Slower, as the guide says: every frame's images are decoded for the views too.
    A Target Tracker run tracks every camera in lockstep, so its progress is the frame
    all its cameras have reached, like any other job's.
    """
    start, stop = getattr(job, "start", None), getattr(job, "stop", None)
    if start is None or stop is None or not preference(ctx.settings, FOLLOW_TRACKING):
        return lambda: None
    step, span = (1 if stop >= start else -1), abs(stop - start)

    def show(done: int, total: int) -> None:
        ctx.set_frame(start + step * min(int(done), span))

    ctx.runner.progressed.connect(show)
    return lambda: ctx.runner.progressed.disconnect(show)


def run(ctx: ActionContext, action: str, title: str, images: bool = False,
        **options: Any) -> bool:
    """Run the Session Process ``action`` (one of `carapost.session.PROCESS_ACTIONS`) on
    the worker and push its result as one History entry.

    Parameters
    ----------
    ctx : ActionContext
    action : str
        ``"detect_blobs"``, ``"track"``, ... (``ctx.session.prepare(action, **options)``).
    title : str
        Menu title (progress bar, log and refusals).
    images : bool
        The action reads camera images: the job gets a worker copy of the window's frame
        source (tracking without images skips patch tracking; detection refuses).
    """
    if ctx.refuse_busy(title):
        return False
    frames = ctx.frames
    source = frames.worker_copy() if images and frames.has_images else None

    def close(*_: Any) -> None:
        if source is not None and source is not frames:
            source.close()

    if images and source is None:
        if action == "detect_blobs":
            ctx.report_error(title, f"{title}: the take has no images to search")
            return False
        options["use_images"] = False
    elif source is not None:
        options["get_image"] = source.require
    try:
        job = ctx.session.prepare(action, **options)
    except CommandError as exc:
        close()
        ctx.report_error(title, str(exc), show=False)
        return False
    unfollow = follow_tracking(ctx, job) if action == "track" else (lambda: None)

    def finished(*_: Any) -> None:
        unfollow()
        close()

    started = ctx.runner.start_job(job, ctx.apply, title=title, finished=finished)
    if not started:
        finished()
    return started


def default_brim(ctx: ActionContext, version: str) -> None:
    """Initialize Default Calibration Brim [v2.0 / v1.1 / v1.0]."""
    ctx.act(f"Initialize Default Calibration Brim [v{version}]",
            ctx.session.initialize_default_brim, version)


def load_rom(ctx: ActionContext) -> None:
    """Process > Load ROM (the ROM project is read and checked by ``session.load_rom``)."""
    from carapost.commands.stack import CommandError
    from carapost.io.errors import CaraFileError

    def load(path: str) -> object:
        try:
            return ctx.session.load_rom(path)
        except CommandError as exc:
            if isinstance(exc.__cause__, CaraFileError):
                raise exc.__cause__ from None  # a damaged file: shown in a box, as for Open
            raise

    path = ctx.dialogs.open_file("Load ROM", CARA_FILTER)
    if path:
        ctx.act("Load ROM", load, path)


def align_data(ctx: ActionContext) -> bool:
    """Process > Align Data: the three selected points, in the order they were selected
    (origin, direction, plane), define the coordinate frame; the dialog asks which axes
    they give."""
    p = ctx.project
    present = set(p.points.ids.tolist())
    ordered = [i for i in p.selection.ordered_points() if i in present]
    cols = p.points.index_of(ordered) if ordered else []
    if len(cols) != 3:
        ctx.report_error("Align Data", f"Align Data: select exactly 3 points (got {len(cols)})",
                         show=False)
        return False
    names = [p.point_label(int(c)) or f"point {int(p.points.ids[c])}" for c in cols]
    axes = ctx.dialogs.get_text(
        "Align Data",
        f"Origin at {names[0]}; the first axis points towards {names[1]}; {names[2]} lies "
        "in the plane of the two axes, on the positive side of the second.\n"
        "Axes (two of x, y, z, '-' flips one; e.g. xy, zx, x-z):", "xy")
    if axes is None:
        return False
    return ctx.act("Align Data", ctx.session.align, ordered, axes.strip() or "xy") is not None


def remove_stabilization(ctx: ActionContext) -> bool:
    """Process > Remove Stabilization: raw positions again (one History entry)."""
    return ctx.act("Remove Stabilization", ctx.session.remove_stabilization) is not None
