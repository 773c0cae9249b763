"""Process menu: Detect Blobs, Load ROM and the ``carapost.commands.menu`` entry points.

Each Process item runs on the worker thread and becomes one undo entry: the job
returns a :class:`~carapost.commands.stack.Command` and ``done`` pushes it on the GUI
thread through ``ctx.push``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from carapost.commands.stack import Command
from carapost.model.project import Project
from carapost.ui.context import ActionContext
from carapost.ui.handlers.file import CARA_FILTER

log = logging.getLogger("carapost.ui")

#: ``hook(project, progress=..., [get_image=...]) -> Command | None`` of commands.menu.
ProcessHook = Callable[..., Command | None]
DETECT_TITLES = {"current": "Detect Blobs [Current Frame]", "range": "Detect Blobs [Active Range]"}


def detect_blobs(ctx: ActionContext, which: str) -> bool:
    """Detect Blobs [Current Frame] (``"current"``) / [Active Range] (``"range"``)."""
    from carapost.algorithms.blobs import detect_blobs_batch
    from carapost.commands.edit import ReplaceDetections

    p = ctx.project
    title = DETECT_TITLES[which]
    if p.n_frames == 0 or not ctx.frames.has_images:
        ctx.report_error(title, f"{title}: the take has no images to search")
        return False
    try:
        params = ctx.view.blob_parameters()
    except ValueError as exc:
        ctx.report_error(title, f"{title}: {exc}")
        return False
    frames = [p.current_frame] if which == "current" else \
        list(range(p.active_range[0], p.active_range[1] + 1))
    cams = [int(c) for c in p.processing_cameras()]
    keys = [(f, c) for f in frames for c in cams]
    source = ctx.frames.worker_copy()

    def job(progress: Callable[[int, int], bool]) -> Any:
        return detect_blobs_batch(lambda key: source.require(*key), keys, params,
                                  workers=2, progress=progress)

    def done(result: Any, cancelled: bool) -> None:
        if source is not ctx.frames:
            source.close()
        if not result:
            return
        images = sorted(result)
        tables = [{"centre": result[k].centre, "axes": result[k].axes,
                   "angle": result[k].angle, "colour": result[k].colour,
                   "score": result[k].score} for k in images]
        label = title + (" (cancelled: partial)" if cancelled else "")
        ctx.push(ReplaceDetections(images, tables, label))
        n = sum(len(t["centre"]) for t in tables)
        log.info("%s: %d detections in %d images%s", title, n, len(images),
                 " (cancelled)" if cancelled else "")

    return ctx.run_job(title, job, done)


def run_process(hook: ProcessHook, title: str, images: bool, ctx: ActionContext) -> bool:
    """Run a ``carapost.commands.menu`` entry point on the worker and push its command.

    Parameters
    ----------
    hook : callable
        ``hook(project, progress=progress)`` returning a Command (or None).
    title : str
        Menu title (progress bar and log).
    images : bool
        The hook takes ``get_image(frame, camera)`` (tracking: patch tracking and the
        detection of frames that have none); passed when the take has images.
    ctx : ActionContext
    """
    project: Project = ctx.project
    source = ctx.frames.worker_copy() if images and ctx.frames.has_images else None

    def job(progress: Callable[[int, int], bool]) -> Any:
        if source is None:
            return hook(project, progress=progress)
        try:
            return hook(project, progress=progress, get_image=source.require)
        finally:
            if source is not ctx.frames:
                source.close()

    def done(result: Any, cancelled: bool) -> None:
        if isinstance(result, Command):
            ctx.push(result)

    return ctx.run_job(title, job, done)


def load_rom(ctx: ActionContext) -> None:
    """Process > Load ROM (the ROM project is read and checked by the command)."""
    from carapost.commands.tracking import LoadRom

    path = ctx.dialogs.open_file("Load ROM", CARA_FILTER)
    if path:
        ctx.make_and_push(lambda: LoadRom(ctx.project, path), "Load ROM")
