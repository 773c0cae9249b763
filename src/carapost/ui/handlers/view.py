"""View menu: display toggles, full screen, docks, floating workspaces, centring."""

from __future__ import annotations

from typing import Any

from carapost.ui.context import ActionContext


def toggle_blob_preview(ctx: ActionContext, on: bool) -> None:
    """Toggle Blob Preview (Ctrl+B)."""
    ctx.view.options.blob_preview = on
    ctx.view.notify_options()


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
