"""File menu: open, save, autosave, import, export, recent files.

Every item that changes the project calls the open project's
:class:`~carapost.session.Session` (``ctx.session``); a take is read by
:func:`carapost.session.read_take`, the function behind ``Session.import_take``,
``api.import_take`` and ``carapost gui take.json``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
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
    """Ask about unsaved changes; False if the user cancelled.

    When the project is left (saved or discarded), the autosave copies this session
    wrote go with it.
    """
    from carapost.io.autosave import discard_autosaves

    if not ctx.is_modified or ctx.project.n_frames == 0:
        ctx.autosaver.drop()
        discard_autosaves(ctx.project)
        return True
    answer = ctx.dialogs.ask_save(ctx.project_name())
    if answer == "cancel":
        return False
    ctx.autosaver.drop()  # saved or discarded: a copy being written is stale
    if answer == "save":
        return save_project(ctx)
    discard_autosaves(ctx.project)
    return True


def offer_untitled_recovery(ctx: ActionContext) -> bool:
    """At start: offer the newest autosave of a never-saved project that a session
    which did not end normally left behind; opened unsaved, as it was."""
    from carapost.io.autosave import untitled_autosaves
    from carapost.session import Session

    found = untitled_autosaves()
    if not found or not ctx.dialogs.confirm(
            "Recover", f"carapost stopped before an unsaved project was saved. Open its "
            f"autosaved copy ({found[0].name})?"):
        return False
    session = ctx.act("Recover", Session.open, found[0], recover=False)
    if session is None:
        return False
    session.project.path = None
    session.project.untitled_autosave = found[0]
    session.stack.mark_unsaved()
    ctx.set_session(session)
    log.info("Recovered the unsaved project from %s", found[0])
    return True


def open_project(ctx: ActionContext, path: str | None = None) -> bool:
    """File > Open (Ctrl+O); offers the autosave copy when it is newer."""
    from carapost.io.autosave import recoverable_autosave
    from carapost.session import Session

    if not maybe_save(ctx):
        return False
    if path is None:
        path = ctx.dialogs.open_file("Open project", CARA_FILTER)
        if not path:
            return False
    auto = recoverable_autosave(path)
    source = None
    if auto is not None and ctx.dialogs.confirm(
            "Recover", f"An autosaved copy of {Path(path).name} is newer than the file "
            "(the program may have stopped unexpectedly). Open the autosaved copy?"):
        source = str(auto)

    def relocate(camera: str, missing: str) -> str | None:
        return ctx.dialogs.open_file(f"Find the video of camera {camera} ({missing})",
                                     VIDEO_FILTER)
    session = ctx.act("Open", Session.open, path, relocate=relocate, source=source,
                      recover=False)  # the user was asked
    if session is None:
        return False
    ctx.set_session(session)
    add_recent_file(ctx.settings, session.project.path)
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
    """Write the project to ``path`` (``session.save``) and mark the history clean."""
    try:
        written = ctx.act("Save", ctx.session.save, path)
    except OSError as exc:
        ctx.report_error("Save", str(exc))
        return False
    if written is None:
        return False
    add_recent_file(ctx.settings, str(written))
    ctx.status(f"Saved {written}", 4000)
    return True


def autosave(ctx: ActionContext) -> None:
    """Start writing the autosave copy beside the project when there are unsaved
    changes, on a thread of its own (`carapost.ui.autosaver`: the copy is in place a
    moment later, or thrown away if the project changed meanwhile)."""
    # never-saved projects too (their copy goes to the autosave folder)
    if ctx.is_modified and ctx.project.n_frames and not ctx.runner.busy:
        try:
            ctx.autosaver.start(ctx.project)
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
    """File > Import Camera Files (and ``carapost gui take.json``): read a take on the
    worker with :func:`carapost.session.read_take` and open a session on it."""
    from carapost.session import Session, read_take

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
                       and ctx.set_session(Session(project)))


def import_brim(ctx: ActionContext) -> None:
    """File > Import Calibration Brim [svg] (a .csv of label,x,y,z in mm too): the brim
    model replaces the brim points."""
    path = ctx.dialogs.open_file("Import Calibration Brim [svg]",
                                 "Brim models (*.svg *.csv);;All files (*)")
    if path:
        ctx.act("Import Calibration Brim [svg]", file_errors_shown(ctx.session.import_brim),
                path)


def file_errors_shown(action: Callable[..., Any]) -> Callable[..., Any]:
    """``action`` with a refusal caused by a damaged file re-raised as that file's
    `CaraFileError`, which `ActionContext.act` shows in a box (refusals only go to the
    log and the status bar)."""
    from carapost.commands.stack import CommandError
    from carapost.io.errors import CaraFileError

    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return action(*args, **kwargs)
        except CommandError as exc:
            if isinstance(exc.__cause__, CaraFileError):
                raise exc.__cause__ from None
            raise
    return run


def import_xcp(ctx: ActionContext) -> None:
    """File > Import XCP."""
    path = ctx.dialogs.open_file("Import XCP", "Calibration (*.xcp);;All files (*)")
    if path:
        ctx.act("Import XCP", ctx.session.import_xcp, path)


def import_labels(ctx: ActionContext, kind: str) -> None:
    """Import Labels From Cara File (``kind="cara"``) / Text File (``"text"``)."""
    filters = CARA_FILTER if kind == "cara" else "Label files (*.txt);;All files (*)"
    path = ctx.dialogs.open_file("Import labels", filters)
    if path:
        ctx.act("Import Labels", ctx.session.import_labels, path, kind)


def export(ctx: ActionContext, kind: str) -> bool:
    """Export C3D / FBX / XCP [Current Frame] (``kind`` ``"c3d"``, ``"fbx"``, ``"xcp"``)
    on the worker, with the Export properties (``session.export_c3d`` ...)."""
    path = ctx.dialogs.save_file(f"Export {kind.upper()}", EXPORT_FILTERS[kind],
                                 f"{ctx.project.take.name}.{kind}")
    if not path:
        return False
    s, frame = ctx.session, ctx.project.current_frame
    writers = {"c3d": lambda: s.export_c3d(path), "fbx": lambda: s.export_fbx(path),
               "xcp": lambda: s.export_xcp(path, frame=frame)}
    write = writers[kind]
    return ctx.run_job(f"Export {kind.upper()}", lambda progress: write(),
                       lambda written, cancelled: written is not None and log.info(
                           "Exported %s", written))
