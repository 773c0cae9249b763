"""View menu: display toggles, full screen, docks, floating workspaces, centring."""

from __future__ import annotations

import logging
from typing import Any

from carapost.ui.context import ActionContext

log = logging.getLogger("carapost.ui")


def toggle_blob_preview(ctx: ActionContext, on: bool) -> None:
    """Toggle Blob Preview (Ctrl+B)."""
    ctx.view.options.blob_preview = on
    ctx.view.notify_options()


def toggle_show_stabilized(ctx: ActionContext, on: bool) -> None:
    """Toggle Show Stabilized (Ctrl+Shift+S): every view shows stabilised (and aligned)
    or raw positions."""
    from carapost.model.stabilization import has_processing

    ctx.session.show_stabilized(on)
    ctx.view.show_stabilized = on
    if on and not has_processing(ctx.project):
        log.info("Show Stabilized: the take is not stabilised yet (Process > Stabilize "
                 "Data); the views show raw positions")


def toggle_full_screen(ctx: ActionContext, on: bool) -> None:
    """Full Screen (F)."""
    if ctx.shell is not None:
        ctx.shell.set_full_screen(on)


def toggle_docks(ctx: ActionContext) -> None:
    """Toggle Dock Widget Visibility (Ctrl+F): only the workspace and timebar."""
    if ctx.shell is not None:
        ctx.shell.toggle_docks()


def new_floating_workspace(ctx: ActionContext) -> Any:
    """View > New Floating Workspace (a 3D view to start with)."""
    return ctx.shell.new_floating_workspace() if ctx.shell is not None else None


def center_selection(ctx: ActionContext, frame: bool) -> None:
    """Center (C) or, with ``frame``, Frame (Shift+C) the selection in all 2D views."""
    for view in ctx.shell.all_views() if ctx.shell is not None else ():
        if view.kind == "sensor":
            view.center_selection(frame=frame)
