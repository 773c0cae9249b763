"""Adapters between the Qt-free model and Qt: change events, log records, worker jobs.

* :class:`ModelBridge` turns the model's plain-callback change events into one Qt
  signal delivered on the GUI thread, merging bursts (a scrub, a batch of edits) into a
  single redraw per event-loop turn.
* :class:`LogBridge` is a :class:`logging.Handler` whose records reach the Log pane
  through a queued signal, whatever thread logged them.
* :class:`JobRunner` runs ``fn(progress)`` on a worker thread and hands the result back
  on the GUI thread (progress bar, Cancel button and error reporting are the window's);
  ``start_job(job, apply)`` runs a processing job and applies its result.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, QTimer, Signal

from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.events import Change, merge_changes
from carapost.model.project import Project

if TYPE_CHECKING:
    from carapost.commands.recipe import Job, Result

log = logging.getLogger("carapost.ui")


class ModelBridge(QObject):
    """Model change events -> ``changed(Change)`` on the GUI thread, coalesced.

    The listener may be called from any thread; it only queues the change and asks the
    GUI thread (through a queued signal) to flush. ``flush()`` delivers everything
    pending at once, so tests and benchmarks can force a synchronous redraw.
    """

    changed = Signal(object)
    _wake = Signal()

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._pending: list[Change] = []
        self._lock = threading.Lock()
        self._unsubscribe: Callable[[], None] | None = None
        self._scheduled = False
        self._wake.connect(self._schedule)
        self.project: Project | None = None

    def attach(self, project: Project) -> None:
        """Listen to ``project`` (and stop listening to the previous one)."""
        self.detach()
        self.project = project
        self._unsubscribe = project.events.subscribe(self._on_change)

    def detach(self) -> None:
        """Stop listening."""
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        with self._lock:
            self._pending.clear()

    def _on_change(self, change: Change) -> None:
        with self._lock:
            self._pending.append(change)
        if threading.current_thread() is threading.main_thread():
            self._schedule()
        else:
            self._wake.emit()  # queued across threads

    def _schedule(self) -> None:
        if not self._scheduled:
            self._scheduled = True
            QTimer.singleShot(0, self.flush)

    def flush(self) -> None:
        """Deliver pending changes now (one merged signal)."""
        self._scheduled = False
        with self._lock:
            pending, self._pending = self._pending, []
        if pending:
            self.changed.emit(merge_changes(pending))


@dataclass
class LogEntry:
    """One line of the Log pane."""

    time: float
    level: int
    category: str
    text: str


class _LogSignal(QObject):
    record = Signal(object)


class LogBridge(logging.Handler):
    """A logging handler that forwards records as ``signals.record(LogEntry)`` (queued)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.signals = _LogSignal()

    def emit(self, rec: logging.LogRecord) -> None:
        try:
            text = rec.getMessage()
            if rec.exc_info and rec.levelno >= logging.ERROR:
                text += "\n" + "".join(traceback.format_exception(*rec.exc_info)).rstrip()
            category = rec.name.split(".")[1] if rec.name.startswith("carapost.") else rec.name
            self.signals.record.emit(LogEntry(rec.created, rec.levelno, category, text))
        except RuntimeError:  # the Qt object is already gone at interpreter exit
            pass


class Cancelled(Exception):
    """Raised inside a job when the user pressed Cancel (optional for job functions)."""


class JobRunner(QObject):
    """Runs one long job at a time on a worker thread.

    ``start(title, fn, done)``: ``fn(progress)`` runs on the worker with
    ``progress(done, total) -> bool`` (False once the user cancelled); ``done(result,
    cancelled)`` runs on the GUI thread. Exceptions are reported through ``failed``,
    except a job's refusal (``CommandError``) after Cancel: a job cancelled before it
    finished anything has nothing to apply, which is what the user asked for, so
    ``done(None, True)`` runs and :attr:`outcome` says "cancelled; nothing changed".

    Attributes
    ----------
    outcome : str
        How the last job ended, for the status bar: "finished", "cancelled",
        "cancelled; nothing changed" or "failed" ("" before the first one).
    """

    started = Signal(str)
    progressed = Signal(int, int)
    finished = Signal(str, bool)  # title, cancelled
    failed = Signal(str, str)  # title, message
    _result = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self._title = ""
        self._done: Callable[[Any, bool], None] | None = None
        self._result.connect(self._on_result)
        self._last_emit = 0.0
        self.outcome = ""

    @property
    def busy(self) -> bool:
        """Whether a job is running."""
        return self._thread is not None

    @property
    def title(self) -> str:
        """Title of the running job ("" when idle)."""
        return self._title if self.busy else ""

    def start(self, title: str, fn: Callable[[Callable[[int, int], bool]], Any],
              done: Callable[[Any, bool], None]) -> bool:
        """Start a job; False (and nothing started) while another one runs."""
        if self.busy:
            log.warning("%s: another process (%s) is still running", title, self._title)
            return False
        self._cancel.clear()
        self._title = title
        self._done = done
        self._last_emit = 0.0

        def progress(n_done: int, total: int) -> bool:
            now = time.monotonic()
            # throttle: the GUI needs at most ~30 progress updates a second
            if now - self._last_emit > 0.03 or n_done >= total:
                self._last_emit = now
                self.progressed.emit(int(n_done), int(total))
            return not self._cancel.is_set()

        def body() -> None:
            t0 = time.monotonic()
            try:
                result = fn(progress)
                outcome: tuple[str, Any] = ("ok", result)
            except Cancelled:
                outcome = ("nothing", None)
            except CommandError as exc:
                # cancelled before anything was finished, the job refuses: nothing to apply
                outcome = (("nothing", exc) if self._cancel.is_set()
                           else ("error", (exc, traceback.format_exc())))
            except Exception as exc:  # reported on the GUI thread, never swallowed
                outcome = ("error", (exc, traceback.format_exc()))
            self._result.emit((outcome, time.monotonic() - t0))

        self._thread = threading.Thread(target=body, name=f"job:{title}", daemon=True)
        self.started.emit(title)
        log.info("%s started", title)
        self._thread.start()
        return True

    def start_job(self, job: Job, apply: Callable[[Result], Any], *,
                  title: str | None = None,
                  finished: Callable[[Any, bool], None] | None = None) -> bool:
        """Run a processing job (:mod:`carapost.commands.recipe`): ``job.compute`` on the
        worker, then ``apply(result)`` on the GUI thread (the window:
        ``ActionContext.apply``, which is ``Session.apply``: one History entry).

        ``finished(result, cancelled)``, when given, runs after ``apply`` (or with None
        when the job returned nothing), e.g. to close a worker's image source.
        """
        def done(result: Any, cancelled: bool) -> None:
            try:
                if result is not None:
                    apply(result)
            finally:
                if finished is not None:
                    finished(result, cancelled)

        def compute(progress: Callable[[int, int], bool]) -> Result:
            result = job.compute(progress)
            if result.cancelled and result.changes_nothing():
                raise Cancelled  # nothing to apply: "cancelled; nothing changed"
            return result

        return self.start(title or job.description, compute, done)

    def cancel(self) -> None:
        """Ask the running job to stop (it returns what it has finished)."""
        if self.busy:
            self._cancel.set()
            log.info("%s: cancel requested", self._title)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the worker thread ends (does not deliver the result)."""
        th = self._thread
        if th is not None:
            th.join(timeout)
            return not th.is_alive()
        return True

    def _on_result(self, payload: Any) -> None:
        (kind, value), seconds = payload
        title, done = self._title, self._done
        cancelled = self._cancel.is_set()
        if self._thread is not None:
            self._thread.join()
        self._thread = None
        self._done = None
        if kind == "error":
            exc, tb = value
            if isinstance(exc, CaraFileError):  # the message names the file: no traceback
                logging.getLogger("carapost.process").error("%s failed: %s", title, exc)
            else:
                logging.getLogger("carapost.process").error("%s failed: %s\n%s", title, exc,
                                                            tb)
            self.outcome = "failed"
            self.failed.emit(title, f"{title} failed: {exc}")
            self.finished.emit(title, cancelled)
            return
        reason = ""
        if kind == "nothing":  # value: the job's refusal (logged below), not a result
            reason, value = (f" ({value})" if value is not None else ""), None
        try:
            if done is not None:
                done(value, cancelled)
        except Exception as exc:
            logging.getLogger("carapost.process").exception("%s: applying the result failed",
                                                            title)
            self.outcome = "failed"
            self.failed.emit(title, f"{title} failed: {exc}")
        else:
            self.outcome = ("cancelled; nothing changed" if kind == "nothing" else
                            "cancelled" if cancelled else "finished")
            log.info("%s %s in %.1f s%s", title, self.outcome, seconds, reason)
        self.finished.emit(title, cancelled)
