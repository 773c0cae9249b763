"""Edit menu: undo and history, the Edit commands, labels, sticks, Relocate Files."""

from __future__ import annotations

from collections.abc import Callable

from carapost.commands import edit
from carapost.commands.stack import Command
from carapost.model.project import Project
from carapost.ui.context import ActionContext
from carapost.ui.handlers.file import VIDEO_FILTER

#: A command built from the project alone (its constructor validates).
CommandFactory = Callable[[Project], Command]


def command(factory: CommandFactory, ctx: ActionContext) -> bool:
    """Build ``factory(project)`` and push it (Merge, Delete Selected, Clear All Labels...).

    The action table binds ``factory`` (a command class or one of its classmethod
    constructors) with :func:`functools.partial`.
    """
    return ctx.make_and_push(lambda: factory(ctx.project),
                             getattr(factory, "__qualname__", "Edit"))


def undo(ctx: ActionContext) -> None:
    """Edit > Undo (Ctrl+Z); waits for a running job."""
    if not ctx.runner.busy:
        ctx.stack.undo()


def redo(ctx: ActionContext) -> None:
    """Edit > Redo (Ctrl+Y)."""
    if not ctx.runner.busy:
        ctx.stack.redo()


def goto_history(ctx: ActionContext, position: int) -> None:
    """History pane click: undo/redo until ``position`` commands are applied."""
    if not ctx.runner.busy:
        ctx.stack.goto(position)


def clear_history(ctx: ActionContext) -> None:
    """Edit > Clear History (logs the memory freed)."""
    freed = ctx.stack.clear()
    ctx.status(f"History cleared: {freed / 1e6:.1f} MB freed", 5000)


def detach(ctx: ActionContext, which: str) -> None:
    """Detach Detections [Current Frame] (``"current"``) / [Active Range] (``"range"``)."""
    ctor = (edit.DetachDetections.current_frame if which == "current"
            else edit.DetachDetections.active_range)
    ctx.make_and_push(lambda: ctor(ctx.project, active_camera=ctx.view.active_camera),
                      "Detach Detections")


def delete_selected_labels(ctx: ActionContext) -> None:
    """Delete Selected Labels (those selected in the Labelling pane)."""
    names = list(ctx.label_selection)
    ctx.make_and_push(lambda: edit.DeleteSelectedLabels(ctx.project, names),
                      "Delete Selected Labels")


def assign_label(ctx: ActionContext, name: str) -> None:
    """Labelling pane click: the one selected point takes the label."""
    sel = ctx.selection.points
    if len(sel) == 1:
        ctx.push(edit.AssignLabel(ctx.project, next(iter(sel)), name))


def rename_label(ctx: ActionContext, old: str) -> None:
    """Labelling pane double-click: rename a label (and the point carrying it)."""
    new = ctx.dialogs.get_text("Rename Label", "New name:", old)
    if new and new != old:
        from carapost.ui.uicommands import RenameLabel

        ctx.push(RenameLabel(ctx.project, old, new))


def rename_point(ctx: ActionContext) -> None:
    """Rename Point (Ctrl+R)."""
    p = ctx.project
    sel = p.selection.points
    if len(sel) != 1:
        ctx.report_error("Rename Point", "Rename Point: select exactly one point", show=False)
        return
    pid = next(iter(sel))
    col = int(p.points.index_of([pid])[0])
    text = ctx.dialogs.get_text("Rename Point", f"Label of point {pid}:", p.points.labels[col])
    if text is not None:
        ctx.make_and_push(lambda: edit.RenamePoint(p, pid, text), "Rename Point")


def create_stick_mesh(ctx: ActionContext) -> None:
    """Create Stick Mesh (Delaunay triangulation of the selected points)."""
    from carapost.ui.uicommands import CreateStickMesh

    ctx.make_and_push(lambda: CreateStickMesh(ctx.project), "Create Stick Mesh")


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
        ctx.make_and_push(lambda: edit.EditStickColor(p, idx, colour), "Edit Stick Color")


def relocate_files(ctx: ActionContext) -> None:
    """Relocate Files: choose the video of each camera, then reopen the images."""
    from carapost.ui.uicommands import RelocateVideos

    paths: dict[int, str] = {}
    for c, cam in enumerate(ctx.project.take.cameras):
        path = ctx.dialogs.open_file(f"Video of camera {cam.name} (was {cam.video_path})",
                                     VIDEO_FILTER)
        if path:
            paths[c] = path
    if paths and ctx.make_and_push(lambda: RelocateVideos(ctx.project, paths),
                                   "Relocate Files"):
        ctx.reload_frames()


def point_edit_mode(ctx: ActionContext, mode: str) -> None:
    """Add (``"add"``) / Edit (``"edit"``) Target Track modes; "" stops them."""
    ctx.point_mode = mode
    text = {"add": "Add Target Track", "edit": "Edit Target Track"}.get(mode, "")
    ctx.status(text or "Point edit mode stopped", 3000)


def rotate_sensors(ctx: ActionContext, clockwise: bool) -> None:
    """Rotate Selected Sensors Clockwise (Ctrl+Right) / Anticlockwise (Ctrl+Left).

    The explicitly selected cameras, else the active camera view.
    """
    p = ctx.project
    active = ctx.view.active_camera
    cams = p.selection.cameras or ({active} if active is not None else set())
    ctx.make_and_push(lambda: edit.RotateSelectedSensors(p, cams or None, clockwise=clockwise),
                      "Rotate Selected Sensors")
