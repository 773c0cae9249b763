"""Undoable commands: a journal of what each command changed, and the command stack.

A command's ``apply`` makes its change through a :class:`Journal`, which copies only the
slices about to change (a block of frames x points, the detections of a few images, a
list attribute) before they change. Undo plays the journal backwards, which restores
the model bit for bit; redo re-applies the command (deterministic on the restored
state) or, for processing results computed elsewhere, re-writes the stored result.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.model.project import Project

log = logging.getLogger("carapost.commands")


def _as_index(cols: NDArray[np.intp]) -> slice | NDArray[np.intp]:
    """A slice for a contiguous run of columns (slice copies are much faster)."""
    if len(cols) and np.all(np.diff(cols) == 1):
        return slice(int(cols[0]), int(cols[-1]) + 1)
    return cols


def _nbytes(obj: Any) -> int:
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, dict):
        return sum(_nbytes(v) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(_nbytes(v) for v in obj)
    return 64


class Journal:
    """Records how to undo the changes made to one project."""

    def __init__(self, project: Project) -> None:
        self.project = project
        self._undo: list[tuple[str, Any]] = []
        self.parts: set[str] = set()
        self._next_id = project.points.next_id

    # -- recording helpers ---------------------------------------------------------------
    def point_block(self, frames: slice, columns: Any, names: Any = None) -> None:
        """Save a (frames x columns) block of the per-point arrays before changing it."""
        pts = self.project.points
        cols = np.atleast_1d(np.asarray(columns, dtype=np.intp))
        if cols.size == 0:
            return
        ids = pts.ids[cols].copy()
        keys = list(names) if names is not None else list(pts.arrays)
        idx = _as_index(cols)
        saved = {k: pts.arrays[k][frames, idx].copy() for k in keys}
        self._undo.append(("block", (frames, ids, saved)))
        self.parts.add("points")

    def remove_points(self, columns: Any) -> None:
        """Remove point columns (recording them so undo can put them back)."""
        cols = np.atleast_1d(np.asarray(columns, dtype=np.intp))
        if cols.size == 0:
            return
        saved = self.project.points.remove(cols)
        self._undo.append(("removed", saved))
        self.parts.update({"points", "point_list"})

    def append_points(self, n: int, *, labels: list[str] | None = None, kind: Any = 0) -> NDArray:
        """Append ``n`` empty points; returns their columns."""
        cols = self.project.points.append(n, labels=labels, kind=kind)
        self._undo.append(("appended", self.project.points.ids[cols].copy()))
        self.parts.update({"points", "point_list"})
        return cols

    def detections(self, images: list[tuple[int, int]]) -> None:
        """Save the detections of the given images before replacing them."""
        if not images:
            return
        tables = self.project.detections.take_images(images)
        self._undo.append(("detections", (list(images), tables)))
        self.parts.add("detections")

    def setattr(self, obj: Any, name: str, value: Any, part: str) -> None:
        """Set ``obj.name = value``, recording a deep copy of the old value."""
        old = copy.deepcopy(getattr(obj, name))
        self._undo.append(("attr", (obj, name, old)))
        setattr(obj, name, value)
        self.parts.add(part)

    def call(self, undo: Callable[[], None], part: str, nbytes: int = 64) -> None:
        """Record an arbitrary undo function (for small state)."""
        self._undo.append(("call", (undo, nbytes)))
        self.parts.add(part)

    # -- playback ------------------------------------------------------------------------
    def rollback(self) -> None:
        """Undo everything recorded, newest first."""
        pts = self.project.points
        for kind, data in reversed(self._undo):
            if kind == "block":
                frames, ids, saved = data
                idx = _as_index(pts.index_of(ids))
                for k, v in saved.items():
                    pts.arrays[k][frames, idx] = v
            elif kind == "removed":
                pts.insert(data)
            elif kind == "appended":
                pts.remove(pts.index_of(data))
            elif kind == "detections":
                images, tables = data
                self.project.detections.replace_images(images, tables)
            elif kind == "attr":
                obj, name, old = data
                setattr(obj, name, old)
            elif kind == "call":
                data[0]()
        pts.next_id = self._next_id
        self._undo.clear()

    def nbytes(self) -> int:
        """Memory held by the saved slices (bytes)."""
        total = 0
        for kind, data in self._undo:
            if kind == "call":
                total += data[1]
            else:
                total += _nbytes(data if kind != "attr" else data[2])
        return total


class Command:
    """Base class: subclasses implement :meth:`apply` using the journal."""

    description = "Command"

    def __init__(self, project: Project | None = None) -> None:
        # ``project`` is accepted so that every command is built as ``Cmd(project, ...)``.
        self._journal: Journal | None = None

    def apply(self, project: Project, journal: Journal) -> None:
        """Make the change (subclasses). Raise CommandError to refuse without a change."""
        raise NotImplementedError

    def do(self, project: Project) -> None:
        """Apply the command; on error the project is left unchanged."""
        journal = Journal(project)
        try:
            self.apply(project, journal)
        except Exception:
            journal.rollback()
            raise
        self._journal = journal
        self._emit(project, journal.parts)

    def undo(self, project: Project) -> None:
        """Revert the change made by :meth:`do`."""
        if self._journal is None:
            raise RuntimeError(f"{self.description}: undo before do")
        parts = set(self._journal.parts)
        self._journal.rollback()
        self._journal = None
        self._emit(project, parts)

    def memory(self) -> int:
        """Bytes held for undo."""
        return self._journal.nbytes() if self._journal is not None else 0

    @staticmethod
    def _emit(project: Project, parts: set[str]) -> None:
        project.modified = True
        if parts:
            project.events.emit(*sorted(parts))


class CommandError(Exception):
    """A command refused to run (nothing was changed); the message says why."""


@dataclass
class HistoryEntry:
    """One line of the History pane."""

    index: int
    description: str
    memory: int
    undone: bool


class CommandStack:
    """Undo/redo stack of commands applied to one project.

    Parameters
    ----------
    project : Project
    on_change : callable, optional
        Called with no argument whenever the stack changes (push, undo, redo, clear).
    """

    def __init__(self, project: Project, on_change: Callable[[], None] | None = None) -> None:
        self.project = project
        self._commands: list[Command] = []
        self._position = 0  # number of applied commands
        self.on_change = on_change
        self._clean_position: int | None = 0

    # -- operations ------------------------------------------------------------------------
    def push(self, command: Command) -> Command:
        """Run a command and put it on the stack (dropping undone entries)."""
        command.do(self.project)
        del self._commands[self._position :]
        if self._clean_position is not None and self._clean_position > self._position:
            self._clean_position = None
        self._commands.append(command)
        self._position += 1
        log.info("%s", command.description)
        self._changed()
        return command

    def undo(self) -> bool:
        """Undo the last applied command; False when there is none."""
        if not self.can_undo:
            return False
        self._position -= 1
        cmd = self._commands[self._position]
        cmd.undo(self.project)
        log.info("Undo %s", cmd.description)
        self._changed()
        return True

    def redo(self) -> bool:
        """Redo the next undone command; False when there is none."""
        if not self.can_redo:
            return False
        cmd = self._commands[self._position]
        cmd.do(self.project)
        self._position += 1
        log.info("Redo %s", cmd.description)
        self._changed()
        return True

    def goto(self, position: int) -> None:
        """Undo or redo until ``position`` commands are applied (History pane click)."""
        position = int(min(max(position, 0), len(self._commands)))
        with self.project.events.batch():
            while self._position > position:
                self.undo()
            while self._position < position:
                self.redo()

    def clear(self) -> int:
        """Forget the whole history; returns the bytes freed."""
        freed = sum(c.memory() for c in self._commands)
        self._commands.clear()
        self._position = 0
        self._clean_position = 0 if not self.project.modified else None
        self._changed()
        log.info("History cleared (%.1f MB freed)", freed / 1e6)
        return freed

    # -- state -----------------------------------------------------------------------------
    @property
    def can_undo(self) -> bool:
        """Whether there is a command to undo."""
        return self._position > 0

    @property
    def can_redo(self) -> bool:
        """Whether there is a command to redo."""
        return self._position < len(self._commands)

    @property
    def position(self) -> int:
        """Number of applied commands."""
        return self._position

    def __len__(self) -> int:
        return len(self._commands)

    def history(self) -> list[HistoryEntry]:
        """Every entry, oldest first; undone entries flagged."""
        return [
            HistoryEntry(i, c.description, c.memory(), i >= self._position)
            for i, c in enumerate(self._commands)
        ]

    def memory(self) -> int:
        """Bytes held by the whole history."""
        return sum(c.memory() for c in self._commands)

    def undo_text(self) -> str:
        """Description of the command Undo would revert ("" if none)."""
        return self._commands[self._position - 1].description if self.can_undo else ""

    def redo_text(self) -> str:
        """Description of the command Redo would re-apply ("" if none)."""
        return self._commands[self._position].description if self.can_redo else ""

    def mark_clean(self) -> None:
        """Remember the current position as saved."""
        self._clean_position = self._position
        self.project.modified = False

    @property
    def is_clean(self) -> bool:
        """True when the project equals its last saved state."""
        return self._clean_position == self._position

    def _changed(self) -> None:
        self.project.modified = not self.is_clean
        if self.on_change is not None:
            self.on_change()
