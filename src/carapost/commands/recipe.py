"""The recipe every processing command follows: prepare, compute, apply.

1. ``prepare_*(project, ...) -> Job`` runs on the calling (GUI) thread. It validates
   (raising :class:`~carapost.commands.stack.CommandError`) and snapshots everything the
   algorithm needs as plain arrays and parameter objects. The job keeps no reference
   to the project, so the project may change while the job runs.
2. ``job.compute(progress) -> Result`` runs on a worker thread: pure algorithm calls on
   the snapshot, no project access. It may refuse too (the algorithm found nothing).
3. ``ApplyResult(result)`` applies the result on the GUI thread as one undoable step
   through the journal (``result.write(project, journal)``) and keeps the result for
   redo.

:func:`run_job` does 2 and 3 in one call for scripts and the session::

    job = prepare_initialize_3d(project, frame=0)   # snapshot, validation
    result = job.compute(progress)                  # worker thread, no project
    stack.push(ApplyResult(result))                 # one History entry
    # or, synchronously:  run_job(stack, prepare_initialize_3d(project, 0))

A new Process item is a :class:`Job` subclass with its snapshot as fields, a
:class:`Result` subclass whose ``write`` states what it changes, and a ``prepare_*``
function.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from carapost.commands.stack import Command, CommandStack, Journal
from carapost.model.project import Project

#: ``progress(done, total) -> bool``; False asks the job to stop (what is done is kept).
Progress = Callable[[int, int], bool] | None

__all__ = ["ApplyResult", "Job", "Progress", "Result", "ResultCommand", "run_job"]


def _held_bytes(obj: Any, depth: int = 0) -> int:
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if depth > 3:
        return 0
    if isinstance(obj, dict):
        return sum(_held_bytes(v, depth + 1) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(_held_bytes(v, depth + 1) for v in obj)
    if hasattr(obj, "__dict__") and not isinstance(obj, type):
        return sum(_held_bytes(v, depth + 1) for v in vars(obj).values())
    if hasattr(obj, "_asdict"):
        return _held_bytes(obj._asdict(), depth + 1)
    return 0


class Result:
    """What a job computed: plain data plus :meth:`write`, which applies it.

    Attributes
    ----------
    description : str
        The History entry.
    message : str
        A line for the Log pane / the caller ("" if none).
    cancelled : bool
        The user stopped the job; the part computed is applied.
    """

    description: str = "Process"
    message: str = ""
    cancelled: bool = False

    def write(self, project: Project, journal: Journal) -> None:
        """Apply the result to ``project``, recording every change in ``journal``.

        Called on do and on every redo, always on the state the result was computed
        for (so point ids, not columns, identify the points).
        """
        raise NotImplementedError

    def changes_nothing(self) -> bool:
        """True when applying the result would change nothing (a job cancelled before it
        finished anything): the caller then adds no History entry."""
        return False

    def nbytes(self) -> int:
        """Memory the result holds for redo (bytes)."""
        return _held_bytes(self)


class Job:
    """A processing step's inputs, snapshotted by a ``prepare_*`` function.

    Subclasses hold plain arrays and parameter objects (never the project) and
    implement :meth:`compute`. Image sources (``get_image(frame, camera)``) are the
    one callable a job may hold: the caller gives it one safe for the worker thread.
    """

    description: str = "Process"

    def compute(self, progress: Progress = None) -> Result:
        """Run the algorithm on the snapshot (worker thread); never touches a project."""
        raise NotImplementedError


class ApplyResult(Command):
    """Apply a :class:`Result` as one undoable step; the result is kept for redo.

    Built from the result, not the project (the exception to ``Cmd(project, ...)``):
    ``ApplyResult(job.compute(progress))``.
    """

    def __init__(self, result: Result) -> None:
        super().__init__()
        self.result = result
        self.description = result.description

    @property
    def message(self) -> str:
        """The result's message."""
        return self.result.message

    @property
    def cancelled(self) -> bool:
        """Whether the job was cancelled (the part computed is applied)."""
        return self.result.cancelled

    def apply(self, project: Project, journal: Journal) -> None:
        self.result.write(project, journal)

    def memory(self) -> int:
        """Bytes held: the saved old state plus the result kept for redo."""
        return super().memory() + self.result.nbytes()


class ResultCommand(ApplyResult):
    """An :class:`ApplyResult` for the one-call commands of scripts: the result is also
    reachable as ``computation``."""

    @property
    def computation(self) -> Any:
        """The result applied."""
        return self.result


def run_job(stack: CommandStack, job: Job, progress: Progress = None) -> ApplyResult:
    """Compute ``job`` here and push its result: the synchronous form of the recipe."""
    return stack.push(ApplyResult(job.compute(progress)))  # type: ignore[return-value]
