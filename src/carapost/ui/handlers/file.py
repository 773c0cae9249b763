"""File menu: open, save, autosave, import, export, recent files."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from carapost.model.project import new_project
from carapost.ui.context import ActionContext
from carapost.ui.settings import add_recent_file, clear_recent_files

log = logging.getLogger("carapost.ui")

CARA_FILTER = "carapost projects (*.cara);;All files (*)"
VIDEO_FILTER = "Videos (*.mkv *.avi *.mp4 *.mov);;All files (*)"
EXPORT_FILTERS = {"c3d": "C3D (*.c3d)", "fbx": "FBX (*.fbx)", "xcp": "XCP (*.xcp)"}


def maybe_save(ctx: ActionContext) -> bool:
    """Ask about unsaved changes; False if the user cancelled."""
    if not ctx.is_modified or ctx.project.n_frames == 0:
        return True
    answer = ctx.dialogs.ask_save(ctx.project_name())
    if answer == "cancel":
        return False
    if answer == "save":
        return save_project(ctx)
    return True


def open_project(ctx: ActionContext, path: str | None = None) -> bool:
    """File > Open (Ctrl+O); offers the autosave copy when it is newer."""
    from carapost.io.cara import load_project, recoverable_autosave
    from carapost.io.errors import CaraFileError

    if not maybe_save(ctx):
        return False
    if path is None:
        path = ctx.dialogs.open_file("Open project", CARA_FILTER)
        if not path:
            return False
    source = path
    auto = recoverable_autosave(path)
    if auto is not None and ctx.dialogs.confirm(
            "Recover", f"An autosaved copy of {Path(path).name} is newer than the file "
            "(the program may have stopped unexpectedly). Open the autosaved copy?"):
        source = str(auto)

    def relocate(camera: str, missing: str) -> str | None:
        return ctx.dialogs.open_file(f"Find the video of camera {camera} ({missing})",
                                     VIDEO_FILTER)
    try:
        project = load_project(source, relocate=relocate)
    except CaraFileError as exc:
        ctx.report_error("Open", str(exc))
        return False
    project.path = str(Path(path).absolute())
    recovered = source != path
    project.modified = recovered
    ctx.set_project(project)
    if recovered:
        # a recovered copy is unsaved until saved: a fresh stack with a modified
        # project has no clean position, so undoing to here still counts as modified
        ctx.stack.clear()
    add_recent_file(ctx.settings, project.path)
    log.info("Opened %s", path)
    return True


def clear_project(ctx: ActionContext) -> None:
    """File > Clear: close the project."""
    if maybe_save(ctx):
        ctx.set_project(new_project(0, 0))


def save_project(ctx: ActionContext) -> bool:
    """File > Save (Ctrl+S)."""
    if ctx.project.path is None:
        return save_project_as(ctx)
    return save_to(ctx, ctx.project.path)


def save_project_as(ctx: ActionContext) -> bool:
    """File > Save As."""
    path = ctx.dialogs.save_file("Save project", CARA_FILTER,
                                 ctx.project.path or f"{ctx.project.take.name}.cara")
    return bool(path) and save_to(ctx, path)


def save_to(ctx: ActionContext, path: str) -> bool:
    """Write the project to ``path`` and mark the history clean."""
    from carapost.io.cara import save_project as write_project
    from carapost.io.errors import CaraFileError

    try:
        written = write_project(ctx.project, path)
    except (CaraFileError, OSError) as exc:
        ctx.report_error("Save", str(exc))
        return False
    ctx.stack.mark_clean()
    ctx.history_changed.emit()  # the window title and Undo text follow the clean state
    add_recent_file(ctx.settings, str(written))
    ctx.status(f"Saved {written}", 4000)
    return True


def autosave(ctx: ActionContext) -> None:
    """Write the autosave copy beside the project when there are unsaved changes."""
    from carapost.io.cara import autosave_project

    if ctx.project.path and ctx.is_modified and not ctx.runner.busy:
        try:
            autosave_project(ctx.project)
        except Exception as exc:  # autosave must never interrupt work
            log.warning("autosave failed: %s", exc)


def clear_recent(ctx: ActionContext) -> None:
    """File > Clear Recent Files (the menu is refilled each time it opens)."""
    clear_recent_files(ctx.settings)


def exit_window(ctx: ActionContext) -> None:
    """File > Exit (the window asks about unsaved changes)."""
    if ctx.shell is not None:
        ctx.shell.close()


def import_take(ctx: ActionContext, path: str | None = None) -> bool:
    """File > Import Camera Files: read a take on a worker thread."""
    from carapost.api import import_take as read_take

    if path is None:
        if not maybe_save(ctx):
            return False
        path = ctx.dialogs.open_file("Import camera files (choose one camera's file or "
                                     "the take's .json)",
                                     "Takes (*.json *.mkv *.avi *.mp4);;All files (*)")
    if not path:
        return False
    take = path
    return ctx.run_job("Import Camera Files", lambda progress: read_take(take),
                       lambda project, cancelled: project is not None
                       and ctx.set_project(project))


def import_brim(ctx: ActionContext) -> None:
    """File > Import Calibration Brim [svg]: a planar custom brim replaces the brim."""
    from carapost.commands.process import ImportBrimSvg

    path = ctx.dialogs.open_file("Import Calibration Brim [svg]",
                                 "SVG files (*.svg);;All files (*)")
    if path:
        ctx.make_and_push(lambda: ImportBrimSvg(ctx.project, path),
                          "Import Calibration Brim [svg]")


def import_xcp(ctx: ActionContext) -> None:
    """File > Import XCP."""
    from carapost.io.errors import CaraFileError
    from carapost.io.xcp import read_xcp
    from carapost.ui.uicommands import ApplyCalibration

    path = ctx.dialogs.open_file("Import XCP", "Calibration (*.xcp);;All files (*)")
    if not path:
        return
    try:
        calib = read_xcp(path)
    except (CaraFileError, OSError, ValueError) as exc:
        ctx.report_error("Import XCP", str(exc))
        return
    for note in calib.notes:
        log.warning("%s: %s", Path(path).name, note)
    ctx.make_and_push(lambda: ApplyCalibration(ctx.project, calib, path), "Import XCP")


def import_labels(ctx: ActionContext, kind: str) -> None:
    """Import Labels From Cara File (``kind="cara"``) / Text File (``"text"``)."""
    from carapost.commands.edit import AddLabels
    from carapost.io.errors import CaraFileError
    from carapost.io.labels import read_label_file, read_labels_from_cara

    filters = CARA_FILTER if kind == "cara" else "Label files (*.txt);;All files (*)"
    path = ctx.dialogs.open_file("Import labels", filters)
    if not path:
        return
    try:
        names = read_labels_from_cara(path) if kind == "cara" else read_label_file(path)
    except (CaraFileError, OSError, ValueError) as exc:
        ctx.report_error("Import Labels", str(exc))
        return
    ctx.make_and_push(lambda: AddLabels(ctx.project, names,
                                        description=f"Import Labels From {Path(path).name}"),
                      "Import Labels")


def export(ctx: ActionContext, kind: str) -> None:
    """Export C3D / FBX / XCP [Current Frame] (``kind`` ``"c3d"``, ``"fbx"``, ``"xcp"``)."""
    from carapost import api

    writers: dict[str, Any] = {"c3d": api.export_c3d, "fbx": api.export_fbx,
                               "xcp": api.export_xcp}
    path = ctx.dialogs.save_file(f"Export {kind.upper()}", EXPORT_FILTERS[kind],
                                 f"{ctx.project.take.name}.{kind}")
    if not path:
        return
    fn = writers[kind]
    kwargs = {"frame": ctx.project.current_frame} if kind == "xcp" else {}
    project = ctx.project
    ctx.run_job(f"Export {kind.upper()}", lambda progress: fn(project, path, **kwargs),
                lambda result, cancelled: log.info("Exported %s", path))
