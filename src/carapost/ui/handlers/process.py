"""Process menu: every item is a :class:`~carapost.session.Session` Process action.

The long ones follow the recipe in the window's threads: ``session.prepare(action,
...)`` validates and snapshots on the GUI thread, ``job.compute(progress)`` runs on the
worker (with its own image decoder), and ``ctx.apply(result)`` pushes the one History
entry on the GUI thread. Default brims and Load ROM change the project at once.
"""

from __future__ import annotations

import logging
from typing import Any

from carapost.commands.stack import CommandError
from carapost.ui.context import ActionContext
from carapost.ui.handlers.file import CARA_FILTER

log = logging.getLogger("carapost.ui")


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
    if ctx.runner.busy:
        ctx.report_error("Busy", f"{title}: wait for {ctx.runner.title} to finish (or "
                         "cancel it)", show=False)
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
    started = ctx.runner.start_job(job, ctx.apply, title=title, finished=close)
    if not started:
        close()
    return started


def default_brim(ctx: ActionContext, version: str) -> None:
    """Initialize Default Calibration Brim [v2.0 / v1.1 / v1.0]."""
    ctx.act(f"Initialize Default Calibration Brim [v{version}]",
            ctx.session.initialize_default_brim, version)


def load_rom(ctx: ActionContext) -> None:
    """Process > Load ROM (the ROM project is read and checked by ``session.load_rom``)."""
    path = ctx.dialogs.open_file("Load ROM", CARA_FILTER)
    if path:
        ctx.act("Load ROM", ctx.session.load_rom, path)
