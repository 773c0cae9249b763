"""The window's autosave copy, written on a thread of its own.

Writing a project is not quick: the autosave of a 36,000-frame take with its detections
froze the window for 240 ms on the GUI thread (docs/benchmarks.md, seventeenth
session). `Autosaver` writes the copy on a worker thread to a ``.partial`` file beside
it and, back on the GUI thread, moves it into place only if the project did not change
meanwhile (any change but the current frame or the selection: an edit made during the
write could have reached the file half written). A changed project's partial copy is
thrown away and the next autosave tick writes a new one; a project saved, discarded or
closed meanwhile (`drop`) throws its pending copy away too. Crash recovery never sees a
partial file (it looks for ``*.cara.autosave`` and, for never-saved projects, ``*.cara``).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, Qt, Signal

if TYPE_CHECKING:
    from carapost.model.project import Project

__all__ = ["AUTOSAVE_NICE", "PARTIAL_SUFFIX", "Autosaver"]

log = logging.getLogger("carapost.ui")

#: Suffix of the copy being written (moved onto the autosave copy when done).
PARTIAL_SUFFIX = ".partial"

#: Nice value added to the writer thread (the decoders' read-ahead has 10).
AUTOSAVE_NICE = 15

#: Changes that leave the saved data as it was (a write may overlap them).
_HARMLESS = frozenset({"current_frame", "selection"})


@dataclass(eq=False)
class _Write:
    """One autosave being written."""

    project: Project
    target: Path
    partial: Path
    beside: bool  # beside the project's file (else a never-saved project's copy)
    changed: bool = False
    dropped: bool = False
    error: BaseException | None = None
    thread: threading.Thread | None = None
    unsubscribe: Any = None
    done: threading.Event = field(default_factory=threading.Event)

    def note(self, change: Any) -> None:
        """Project listener: a change that may alter what is being written."""
        parts = getattr(change, "parts", None)
        if parts is None or not parts <= _HARMLESS:
            self.changed = True


class Autosaver(QObject):
    """Autosave copies of the window's project written off the GUI thread.

    ``start(project)`` begins a write (False while one is under way); the copy appears
    a moment later, when the GUI thread gets the worker's result. ``wait()`` finishes
    a pending write at once (tests, closing the window).
    """

    _finished = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._write: _Write | None = None
        self._finished.connect(self._complete, Qt.ConnectionType.QueuedConnection)

    @property
    def running(self) -> bool:
        """Whether a copy is being written."""
        return self._write is not None

    def start(self, project: Project) -> bool:
        """Write ``project``'s autosave copy in the background.

        Raises
        ------
        CaraFileError
            When the folder of a never-saved project's copy cannot be created.
        """
        from carapost.io.autosave import autosave_target
        from carapost.io.launcher import launch

        if self._write is not None:
            return False
        beside = project.path is not None
        target = autosave_target(project)
        job = _Write(project, target, target.with_name(target.name + PARTIAL_SUFFIX), beside)
        job.unsubscribe = project.events.subscribe(job.note)
        job.thread = threading.Thread(target=self._run, args=(job,), daemon=True,
                                      name="carapost-autosave")
        self._write = job
        launch(job.thread)
        return True

    def _run(self, job: _Write) -> None:
        from carapost.io.cara import save_project
        from carapost.io.launcher import lower_thread_priority

        # the write takes CPU (zip members, checksums) for a second or more on a long
        # take: the GUI thread and the decoders come first
        lower_thread_priority(AUTOSAVE_NICE)
        try:
            save_project(job.project, job.partial, autosave=True)
        except BaseException as exc:  # reported on the GUI thread; autosave never stops work
            job.error = exc
        job.done.set()
        with contextlib.suppress(RuntimeError):  # the window is gone
            self._finished.emit(job)

    def _complete(self, job: _Write) -> None:
        """On the GUI thread: move the copy into place, or throw it away."""
        if job is not self._write:
            return  # finished already (`wait`)
        self._write = None
        job.unsubscribe()
        if job.error is None and not job.changed and not job.dropped:
            try:
                os.replace(job.partial, job.target)
            except OSError as exc:
                job.error = exc
            else:
                if job.beside:  # this session's copy: discarded with the project's changes
                    job.project.session_autosave = job.target
                return
        if job.error is not None:
            log.warning("autosave failed: %s", job.error)
        with contextlib.suppress(OSError):
            job.partial.unlink(missing_ok=True)

    def drop(self) -> None:
        """The project was saved, discarded or closed: a copy being written is thrown
        away when it is done."""
        if self._write is not None:
            self._write.dropped = True

    def wait(self, timeout: float = 60.0) -> None:
        """Finish a pending write now (its copy in place or thrown away)."""
        from carapost.io.launcher import started

        job = self._write
        if job is None or job.thread is None:
            return
        if started(job.thread, timeout):
            job.done.wait(timeout)
        if not job.done.is_set():  # still writing: its queued completion cleans up
            job.dropped = True
            return
        self._complete(job)
