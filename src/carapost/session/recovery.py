"""Crash recovery when a project is opened: the newer autosave copy is never ignored.

The window asks (File > Open); scripts choose with ``recover`` (`Session.open`,
`carapost.api.open_project`) and the command line with ``--recover``. Without a choice
the file is opened as it is, and the newer copy is reported: a `NewerAutosaveWarning`,
a log warning, and ``session.newer_autosave``.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from carapost.session import Session

log = logging.getLogger("carapost")

__all__ = ["NewerAutosaveWarning", "open_with_recovery"]


class NewerAutosaveWarning(UserWarning):
    """A project was opened from its file although a newer autosave copy exists."""


def open_with_recovery(cls: type[Session], path: str | Path, *, relocate: Any = None,
                       get_image: Any = None, source: str | Path | None = None,
                       recover: bool | None = None) -> Session:
    """`Session.open` (see there for the parameters)."""
    from carapost.io.autosave import recoverable_autosave
    from carapost.io.cara import load_project

    newer = recoverable_autosave(path) if source is None and recover is not False else None
    if newer is not None and recover:
        source = newer
    recovered = source is not None and Path(source) != Path(path)
    project = load_project(source if recovered else path, relocate=relocate)
    project.path = str(Path(path).absolute())
    project.modified = False
    session = cls(project, get_image=get_image)
    if recovered:  # the autosave copy differs from the file until it is saved
        session.stack.mark_unsaved()
        log.info("Opened %s from its autosave copy %s", path, source)
    elif newer is not None:
        session.newer_autosave = newer
        message = (f"{path}: an autosave copy newer than the file exists ({newer.name}: the "
                   "program may have stopped before saving); the file was opened. Open "
                   "with recover=True (carapost ... --recover) to use the copy.")
        log.warning("%s", message)
        warnings.warn(message, NewerAutosaveWarning, stacklevel=3)
    return session
