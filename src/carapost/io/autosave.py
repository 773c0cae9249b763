"""Autosave copies of projects: where they live, writing them, finding and discarding them.

A saved project's copy sits beside it (``<name>.cara.autosave``); a never-saved
project's copy goes to `untitled_autosave_folder`. `carapost.io.cara.save_project`
removes copies that a save makes stale; crash recovery (`carapost.session.recovery`)
offers a copy newer than its project.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from carapost.io.errors import CaraFileError

if TYPE_CHECKING:
    from carapost.model.project import Project

AUTOSAVE_SUFFIX = ".autosave"


def autosave_path(path: str | Path) -> Path:
    """Where the autosave copy of a project lives (beside it)."""
    path = Path(path)
    return path.with_name(path.name + AUTOSAVE_SUFFIX)


def untitled_autosave_folder() -> Path:
    """Where autosave copies of never-saved projects go (``CARAPOST_AUTOSAVE_DIR``, else
    ``$XDG_STATE_HOME/carapost/autosave`` or ``~/.local/state/carapost/autosave``)."""
    env = os.environ.get("CARAPOST_AUTOSAVE_DIR")
    if env:
        return Path(env)
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "carapost" / "autosave"


def untitled_autosaves() -> list[Path]:
    """Autosave copies of never-saved projects left by sessions that did not end
    normally, newest first (a normal close removes its own)."""
    folder = untitled_autosave_folder()
    try:
        found = [p for p in folder.glob("*.cara") if p.is_file()]
    except OSError:
        return []
    return sorted(found, key=lambda p: p.stat().st_mtime, reverse=True)


def discard_autosaves(project: Project) -> None:
    """Remove the autosave copies this session wrote for a project whose changes the
    user discards (closed without saving): the copy of a never-saved project, and the
    copy beside a saved one. A copy the session did not write (say, one left by a crash
    that the user declined to recover) stays."""
    for copy in (project.untitled_autosave, project.session_autosave):
        if copy is not None:
            with contextlib.suppress(OSError):
                Path(copy).unlink(missing_ok=True)
    project.untitled_autosave = None
    project.session_autosave = None


def autosave_target(project: Project, path: str | Path | None = None) -> Path:
    """Where the autosave copy of a project goes: beside its file (or ``path``), or for
    a project that was never saved a ``.cara`` file in `untitled_autosave_folder`
    (named after the take and the time it was first autosaved, remembered in the
    project, the folder created). File > Open opens such a copy; the project's first
    save removes it."""
    target = path or project.path
    if target is not None:
        return autosave_path(target)
    copy = project.untitled_autosave
    if copy is None:
        folder = untitled_autosave_folder()
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CaraFileError(folder, f"cannot be created: {exc.strerror or exc}") from None
        name = "".join(c if c.isalnum() or c in "-_" else "_" for c in
                       (project.take.name or "untitled"))[:80]
        copy = folder / f"{name}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.cara"
        project.untitled_autosave = copy
    return Path(copy)


def autosave_project(project: Project, path: str | Path | None = None) -> Path | None:
    """Write the autosave copy of a project (beside its file, or ``path``; a project
    that was never saved goes to `untitled_autosave_folder`, see `autosave_target`).

    Synchronous (scripts, tests); the window writes its copy on a thread of its own
    (`carapost.ui.autosaver`).
    """
    from carapost.io.cara import save_project  # cara imports this module

    beside = (path or project.path) is not None
    written = save_project(project, autosave_target(project, path), autosave=True)
    if beside:  # this session's copy: discarded with the project's changes
        project.session_autosave = written
    return written


def recoverable_autosave(path: str | Path) -> Path | None:
    """The autosave copy of ``path`` when it is newer than the project (crash recovery)."""
    path = Path(path)
    auto = autosave_path(path)
    if not auto.exists():
        return None
    if path.exists() and auto.stat().st_mtime <= path.stat().st_mtime:
        return None
    return auto
