"""Edit menu: undo and history, the Edit commands, labels, sticks, Relocate Files.

Each item calls a method of the open project's :class:`~carapost.session.Session`
through ``ctx.act`` (one History entry; a refusal is logged and shown in the status
bar), with the window's defaults (the selection, the active camera view).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from carapost.ui.context import ActionContext
from carapost.ui.handlers.file import VIDEO_FILTER

#: An unbound Session method (``Session.merge``) called with the session alone.
SessionAction = Callable[..., Any]


def title_of(action: SessionAction) -> str:
    """The menu-like title of a Session method (``merge`` -> "Merge")."""
    return action.__name__.replace("_", " ").title()


def session_action(action: SessionAction, ctx: ActionContext, **options: Any) -> bool:
    """Call ``action(ctx.session, **options)`` (Merge, Delete Selected, Clear All Labels...).

    The action table binds the unbound Session method (and its options) with
    :func:`functools.partial`, so the window does exactly what the script call
    ``session.merge()`` does.
    """
    return ctx.act(title_of(action), action, ctx.session, **options) is not None


def undo(ctx: ActionContext) -> None:
    """Edit > Undo (Ctrl+Z); waits for a running job."""
    if not ctx.runner.busy:
        ctx.session.undo()


def redo(ctx: ActionContext) -> None:
    """Edit > Redo (Ctrl+Y)."""
    if not ctx.runner.busy:
        ctx.session.redo()


def goto_history(ctx: ActionContext, position: int) -> None:
    """History pane click: undo/redo until ``position`` commands are applied."""
    if not ctx.runner.busy:
        ctx.session.goto(position)


def clear_history(ctx: ActionContext) -> None:
    """Edit > Clear History (logs the memory freed)."""
    freed = ctx.session.clear_history()
    ctx.status(f"History cleared: {freed / 1e6:.1f} MB freed", 5000)


def detach(ctx: ActionContext, which: str) -> None:
    """Detach Detections [Current Frame] (``"current"``) / [Active Range] (``"range"``):
    the explicitly selected cameras, else the active camera view."""
    frames = "current" if which == "current" else "active"
    ctx.act("Detach Detections", ctx.session.detach_detections, frames,
            active_camera=ctx.view.active_camera)


def delete_selected_labels(ctx: ActionContext) -> None:
    """Delete Selected Labels (those selected in the Labelling pane)."""
    ctx.act("Delete Selected Labels", ctx.session.delete_labels, list(ctx.label_selection))


def assign_label(ctx: ActionContext, name: str) -> None:
    """Labelling pane click: the one selected point takes the label."""
    sel = ctx.selection.points
    if len(sel) == 1:
        ctx.act("Assign Label", ctx.session.assign_label, next(iter(sel)), name)


def rename_label(ctx: ActionContext, old: str) -> None:
    """Labelling pane double-click: rename a label (and the point carrying it)."""
    new = ctx.dialogs.get_text("Rename Label", "New name:", old)
    if new and new != old:
        ctx.act("Rename Label", ctx.session.rename_label, old, new)


def rename_point(ctx: ActionContext) -> None:
    """Rename Point (Ctrl+R)."""
    p = ctx.project
    sel = p.selection.points
    if len(sel) != 1:
        ctx.report_error("Rename Point", "Rename Point: select exactly one point", show=False)
        return
    pid = next(iter(sel))
    col = int(p.points.index_of([pid])[0])
    # completion from the label list: the names the marker set uses, unassigned first
    taken = set(p.points.labels)
    names = [n for n in p.labels if n not in taken] + [n for n in p.labels if n in taken]
    text = ctx.dialogs.get_completed_text("Rename Point", f"Label of {p.point_label(col)}:",
                                          p.points.labels[col], names)
    if text is not None:
        ctx.act("Rename Point", ctx.session.rename_point, pid, text)


def edit_stick_color(ctx: ActionContext) -> None:
    """Edit Stick Color: sticks between selected points get a new colour."""
    p = ctx.project
    sel = p.selection.points
    idx = [i for i, s in enumerate(p.sticks) if s.a in sel and s.b in sel]
    if not idx:
        ctx.report_error("Edit Stick Color", "Edit Stick Color: select the points at both "
                         "ends of a stick", show=False)
        return
    colour = ctx.dialogs.get_colour("Stick colour")
    if colour is not None:
        ctx.act("Edit Stick Color", ctx.session.edit_stick_color, idx, colour)


def relocate_files(ctx: ActionContext) -> bool:
    """Relocate Files: choose the video of each camera (``session.relocate_files``, which
    refuses a video of another image size), then reopen the images."""
    paths: dict[str | int, str] = {}
    for c, cam in enumerate(ctx.project.take.cameras):
        path = ctx.dialogs.open_file(f"Video of camera {cam.name} (was {cam.video_path})",
                                     VIDEO_FILTER)
        if path:
            paths[c] = path
    if not paths or ctx.act("Relocate Files", ctx.session.relocate_files, paths) is None:
        return False
    ctx.reload_frames()
    return True


def point_edit_mode(ctx: ActionContext, mode: str) -> None:
    """Add (``"add"``) / Edit (``"edit"``) Target Track modes; "" stops them."""
    ctx.point_mode = mode
    text = {"add": "Add Target Track", "edit": "Edit Target Track"}.get(mode, "")
    ctx.status(text or "Point edit mode stopped", 3000)


def rotate_sensors(ctx: ActionContext, clockwise: bool) -> None:
    """Rotate Selected Sensors Clockwise (Ctrl+Right) / Anticlockwise (Ctrl+Left).

    The explicitly selected cameras, else the active camera view.
    """
    active = ctx.view.active_camera
    cams = ctx.project.selection.cameras or ({active} if active is not None else set())
    ctx.act("Rotate Selected Sensors", ctx.session.rotate_sensors, cams or None,
            clockwise=clockwise)

