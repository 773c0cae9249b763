"""Undoable commands: a journal of what each command changed, and the command stack.

A command's ``apply`` makes its change through a :class:`Journal`, which copies only the
slices about to change (a block of frames x points, the masked samples of a sparse edit,
the detections of a few images, calibration frames, properties, a list attribute) before
they change. Undo plays the journal backwards, which restores the model bit for bit; redo
re-applies the command (deterministic on the restored state) or, for processing results
computed elsewhere (:mod:`carapost.commands.recipe`), re-writes the stored result.

The journal also knows *where* it changed the model, so the change event a command
emits names the frames, point columns and cameras concerned (:class:`Change`) and views
can redraw only those. :meth:`CommandStack.group` makes several pushes one History
entry (a drag, a multi-step action).
"""

from __future__ import annotations

import contextlib
import copy
import logging
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.model.project import Project

log = logging.getLogger("carapost.commands")

#: Marks an extent that covers a whole axis (every frame, point or camera).
_ALL = "all"


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


def _frame_span(frames: slice | int | ArrayLike, n_frames: int) -> tuple[int, int] | str:
    """Inclusive (first, last) frame of ``frames``, or ``_ALL`` when it is every frame."""
    if isinstance(frames, slice):
        a, b, _ = frames.indices(n_frames)
        if a == 0 and b >= n_frames:
            return _ALL
        return (a, max(a, b - 1))
    f = np.atleast_1d(np.asarray(frames, dtype=np.intp))
    f = np.where(f < 0, f + n_frames, f)
    return (int(f.min()), int(f.max())) if f.size else _ALL


class Journal:
    """Records how to undo the changes made to one project, and where they were made.

    Every recording helper saves the old state *before* the change and notes its extent
    (frames, point columns, cameras); :meth:`extent` merges those for the change event.
    """

    def __init__(self, project: Project) -> None:
        self.project = project
        self._undo: list[tuple[str, Any]] = []
        self.parts: set[str] = set()
        self._next_id = project.points.next_id
        # per axis: list of extents (a (first, last) range or an index array) or _ALL
        self._extents: dict[str, list[Any] | str] = {"frames": [], "points": [],
                                                     "cameras": []}

    # -- extents -------------------------------------------------------------------------
    def _touch(self, parts: Iterable[str], **extents: Any) -> None:
        """Note ``parts`` changed over ``extents`` (axis -> range / indices / _ALL).

        Axes not named are not concerned (a calibration change has no point axis).
        """
        self.parts.update(parts)
        for axis, value in extents.items():
            cur = self._extents[axis]
            if cur == _ALL:
                continue
            if isinstance(value, str):
                self._extents[axis] = _ALL
            else:
                cur.append(value)

    def extent(self) -> dict[str, Any]:
        """Keyword arguments for :meth:`EventHub.emit`: ``frames``, ``points``, ``cameras``.

        ``frames`` is the inclusive range covering every frame changed, ``points`` and
        ``cameras`` the sorted point columns and cameras; None where the change covers
        the whole axis or is not known more precisely.
        """
        out: dict[str, Any] = {}
        f = self._extents["frames"]
        out["frames"] = (None if f == _ALL or not f else
                         (min(a for a, _ in f), max(b for _, b in f)))
        for axis in ("points", "cameras"):
            v = self._extents[axis]
            out[axis] = (None if v == _ALL or not v else
                         np.unique(np.concatenate([np.atleast_1d(x) for x in v]))
                         .astype(np.intp))
        return out

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
        self._touch(("points",), frames=_frame_span(frames, pts.n_frames), points=cols,
                    cameras=_ALL)

    def write_points(self, frames: slice | int, columns: Any,
                     arrays: Mapping[str, ArrayLike]) -> None:
        """Write computed per-point arrays over a block, saving the old block first.

        Parameters
        ----------
        frames : slice or int
            Frames of the block (an int is the one-frame block ``f:f+1``).
        columns : array of int
            Point columns of the block.
        arrays : mapping name -> array
            New values, each broadcastable to ``points.<name>[frames][:, columns]``
            (``(n_frames, n_cols, ...)``; a scalar such as ``False`` fills the block).
            Values are cast to the stored dtype as by numpy assignment. New
            ``positions`` without a ``sigma`` clear the block's ``sigma``: an
            uncertainty must not outlive the sample it describes.
        """
        if isinstance(frames, int | np.integer):
            frames = slice(int(frames), int(frames) + 1)
        cols = np.atleast_1d(np.asarray(columns, dtype=np.intp))
        if cols.size == 0:
            return
        if "positions" in arrays and "sigma" not in arrays:
            arrays = {**arrays, "sigma": np.nan}
        self.point_block(frames, cols, list(arrays))
        pts = self.project.points
        for name, value in arrays.items():
            sub = pts.arrays[name][frames]
            sub[:, cols] = value

    def point_mask(self, frames: slice, columns: Any, mask: NDArray[np.bool_],
                   names: Any = None) -> None:
        """Save only the masked samples of a (frames x columns) block before changing them.

        The compact record of a sparse edit (as napari's masked paint atom): the bounding
        box of ``mask``, the mask (packed to bits, or flat indices when fewer than one
        sample in 32 is masked) and the old values under it. The command
        must change nothing outside the mask.

        Parameters
        ----------
        frames : slice
            Frames of the block (step 1).
        columns : array of int
            Point columns of the block.
        mask : bool array (n_frames, n_cols)
            The samples that will change.
        names : sequence of str, optional
            Per-point arrays concerned (default all).
        """
        pts = self.project.points
        cols = np.atleast_1d(np.asarray(columns, dtype=np.intp))
        mask = np.asarray(mask, dtype=bool)
        if cols.size == 0 or not mask.any():
            return
        a = frames.indices(pts.n_frames)[0]
        rows = np.flatnonzero(mask.any(1))
        used = np.flatnonzero(mask.any(0))
        box_frames = slice(a + int(rows[0]), a + int(rows[-1]) + 1)
        box_cols = cols[used[0]: used[-1] + 1]
        box = mask[rows[0]: rows[-1] + 1, used[0]: used[-1] + 1]
        idx = _as_index(box_cols)
        keys = list(names) if names is not None else list(pts.arrays)
        saved = {k: pts.arrays[k][box_frames, idx][box] for k in keys}
        # the mask as bits over the box, or as flat indices when that is smaller
        flat = np.flatnonzero(box)
        where = flat.astype(np.uint32) if flat.size * 32 < box.size else np.packbits(box)
        self._undo.append(("masked", (box_frames, pts.ids[box_cols].copy(), where,
                                      box.shape, saved)))
        self._touch(("points",), frames=(box_frames.start, box_frames.stop - 1),
                    points=box_cols[box.any(0)], cameras=_ALL)

    def remove_points(self, columns: Any) -> None:
        """Remove point columns (recording them so undo can put them back)."""
        cols = np.atleast_1d(np.asarray(columns, dtype=np.intp))
        if cols.size == 0:
            return
        saved = self.project.points.remove(cols)
        self._undo.append(("removed", saved))
        self._touch(("points", "point_list"), frames=_ALL, points=_ALL, cameras=_ALL)

    def append_points(self, n: int, *, labels: list[str] | None = None, kind: Any = 0) -> NDArray:
        """Append ``n`` empty points; returns their columns."""
        cols = self.project.points.append(n, labels=labels, kind=kind)
        self._undo.append(("appended", self.project.points.ids[cols].copy()))
        self._touch(("points", "point_list"), frames=_ALL, points=_ALL, cameras=_ALL)
        return cols

    def detections(self, images: list[tuple[int, int]]) -> None:
        """Save the detections of the given images before replacing them."""
        if not images:
            return
        tables = self.project.detections.take_images(images)
        self._undo.append(("detections", (list(images), tables)))
        f = [int(i[0]) for i in images]
        self._touch(("detections",), frames=(min(f), max(f)),
                    cameras=np.array([int(i[1]) for i in images], dtype=np.intp))

    def calibration(self, frames: slice | int | ArrayLike | None) -> None:
        """Save camera poses before changing them.

        Parameters
        ----------
        frames : slice, int, array of int or None
            Frames whose ``R``, ``t`` and ``solved`` flag will change. None: the command
            replaces the whole calibration object (intrinsics, every frame, XCP extras);
            undo puts the old object back.
        """
        project = self.project
        if frames is None:
            old_cal = project.calibration.copy()

            def undo_all() -> None:
                project.calibration = old_cal

            self._undo.append(("call", (undo_all, int(old_cal.R.nbytes + old_cal.t.nbytes))))
            self._touch(("cameras",), frames=_ALL, cameras=_ALL)
            return
        cal = project.calibration
        old = (cal.R[frames].copy(), cal.t[frames].copy(), np.copy(cal.solved[frames]))

        def undo() -> None:
            cal.R[frames], cal.t[frames], cal.solved[frames] = old

        self._undo.append(("call", (undo, old[0].nbytes + old[1].nbytes)))
        self._touch(("cameras",), frames=_frame_span(frames, project.n_frames),
                    cameras=_ALL)

    def properties(self, keys: Iterable[str]) -> None:
        """Save the values of some properties before changing them."""
        props = self.project.properties
        old = {k: props[k] for k in keys}
        self._undo.append(("call", (lambda: props.update(old), 64 * max(len(old), 1))))
        self._touch(("properties",))

    def setattr(self, obj: Any, name: str, value: Any, part: str) -> None:
        """Set ``obj.name = value``, recording a deep copy of the old value."""
        old = copy.deepcopy(getattr(obj, name))
        self._undo.append(("attr", (obj, name, old)))
        setattr(obj, name, value)
        self._touch((part,), frames=_ALL, points=_ALL, cameras=_ALL)

    def call(self, undo: Callable[[], None], part: str, nbytes: int = 64) -> None:
        """Record an arbitrary undo function (for small state; extent unknown = all)."""
        self._undo.append(("call", (undo, nbytes)))
        self._touch((part,), frames=_ALL, points=_ALL, cameras=_ALL)

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
            elif kind == "masked":
                frames, ids, where, shape, saved = data
                idx = _as_index(pts.index_of(ids))
                if where.dtype == np.uint32:
                    mask = np.zeros(shape, dtype=bool)
                    mask.flat[where] = True
                else:
                    mask = np.unpackbits(where, count=shape[0] * shape[1]).reshape(shape)
                    mask = mask.astype(bool)
                for k, v in saved.items():
                    block = pts.arrays[k][frames, idx]
                    block[mask] = v
                    pts.arrays[k][frames, idx] = block
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
        """Memory held by the saved slices (bytes; at least 64 per record)."""
        total = 0
        for kind, data in self._undo:
            if kind == "call":
                size = data[1]
            elif kind == "masked":
                size = _nbytes(data[1]) + _nbytes(data[2]) + _nbytes(data[4])
            else:
                size = _nbytes(data if kind != "attr" else data[2])
            total += max(int(size), 64)
        return total


class Command:
    """Base class: subclasses implement :meth:`apply` using the journal.

    Construction convention: a command is built as ``Cmd(project, ...)``; the
    constructor validates its arguments against the project (raising
    :class:`CommandError`, nothing changed) and keeps only plain values (ids, not
    columns), because it is re-applied on redo. ``project`` is not stored. The one
    documented exception is the family of result commands
    (:class:`carapost.commands.recipe.ApplyResult` and its subclasses), built from a
    result computed without the project: ``ApplyResult(result)``.
    """

    description = "Command"

    def __init__(self, project: Project | None = None) -> None:
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
        self._extent = journal.extent()
        self._emit(project, journal.parts, self._extent)

    def undo(self, project: Project) -> None:
        """Revert the change made by :meth:`do`."""
        if self._journal is None:
            raise RuntimeError(f"{self.description}: undo before do")
        parts = set(self._journal.parts)
        self._journal.rollback()
        self._journal = None
        self._emit(project, parts, getattr(self, "_extent", None))

    def memory(self) -> int:
        """Bytes held for undo."""
        return self._journal.nbytes() if self._journal is not None else 0

    @staticmethod
    def _emit(project: Project, parts: set[str], extent: Mapping[str, Any] | None = None
              ) -> None:
        project.modified = True
        if parts:
            project.events.emit(*sorted(parts), **(extent or {}))


class CommandError(Exception):
    """A command refused to run (nothing was changed); the message says why."""


class CommandGroup(Command):
    """Several commands undone and redone as one History entry (see
    :meth:`CommandStack.group`)."""

    def __init__(self, description: str) -> None:
        super().__init__()
        self.description = description
        self.commands: list[Command] = []
        self._done = False

    def add(self, project: Project, command: Command) -> None:
        """Do ``command`` now and make it part of the group."""
        command.do(project)
        self.commands.append(command)
        self._done = True

    def do(self, project: Project) -> None:
        """Redo every member, oldest first (one change event); all or nothing."""
        done: list[Command] = []
        with project.events.batch():
            try:
                for cmd in self.commands:
                    cmd.do(project)
                    done.append(cmd)
            except Exception:
                for cmd in reversed(done):
                    cmd.undo(project)
                raise
        self._done = True

    def undo(self, project: Project) -> None:
        """Undo every member, newest first (one change event)."""
        if not self._done:
            raise RuntimeError(f"{self.description}: undo before do")
        with project.events.batch():
            for cmd in reversed(self.commands):
                cmd.undo(project)
        self._done = False

    def memory(self) -> int:
        """Bytes held by the members."""
        return sum(c.memory() for c in self.commands)


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
        self._groups: list[CommandGroup] = []  # open groups, outermost first

    # -- operations ------------------------------------------------------------------------
    def push(self, command: Command) -> Command:
        """Run a command and put it on the stack (dropping undone entries).

        Inside :meth:`group` the command joins the innermost open group instead.
        """
        if self._groups:
            self._groups[-1].add(self.project, command)
            log.info("%s", command.description)
            return command
        command.do(self.project)
        self._record(command)
        log.info("%s", command.description)
        return command

    def _record(self, command: Command) -> None:
        del self._commands[self._position :]
        if self._clean_position is not None and self._clean_position > self._position:
            self._clean_position = None
        self._commands.append(command)
        self._position += 1
        self._changed()

    @contextlib.contextmanager
    def group(self, description: str) -> Iterator[CommandGroup]:
        """Make every push inside the ``with`` block one History entry.

        One undo/redo reverts/re-applies them all; change events are merged into one.
        Groups nest (an inner group becomes one member of the outer). When the block
        raises, the steps already pushed in this group are undone, the exception
        propagates and the stack is as before; an empty group adds no entry.

        Examples
        --------
        >>> with stack.group("Move Keyframe"):            # doctest: +SKIP
        ...     for step in drag_steps:
        ...         stack.push(SetObservation(project, ...))
        """
        grp = CommandGroup(description)
        self._groups.append(grp)
        try:
            with self.project.events.batch():
                try:
                    yield grp
                except BaseException:
                    if grp.commands:
                        grp.undo(self.project)
                    raise
        finally:
            self._groups.pop()
        if not grp.commands:
            return
        if self._groups:
            self._groups[-1].commands.append(grp)
            self._groups[-1]._done = True
        else:
            self._record(grp)
            log.info("%s (%d steps)", description, len(grp.commands))

    def undo(self) -> bool:
        """Undo the last applied command; False when there is none."""
        self._no_open_group("undo")
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
        self._no_open_group("redo")
        if not self.can_redo:
            return False
        cmd = self._commands[self._position]
        cmd.do(self.project)
        self._position += 1
        log.info("Redo %s", cmd.description)
        self._changed()
        return True

    def _no_open_group(self, what: str) -> None:
        if self._groups:
            raise RuntimeError(f"cannot {what} while the group "
                               f"{self._groups[-1].description!r} is open")

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
        self._no_open_group("clear the history")
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

    def applied(self) -> list[Command]:
        """The commands currently applied (not undone), oldest first."""
        return list(self._commands[: self._position])

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
        """Remember the current position as saved (``on_change`` follows, as for every
        change of the clean state: the window title and Undo text)."""
        self._clean_position = self._position
        self.project.modified = False
        if self.on_change is not None:
            self.on_change()

    def mark_unsaved(self) -> None:
        """No position of the history equals a saved file (a recovered autosave was
        opened): the project stays modified until it is saved."""
        self._clean_position = None
        self.project.modified = True
        if self.on_change is not None:
            self.on_change()

    @property
    def is_clean(self) -> bool:
        """True when the project equals its last saved state."""
        return self._clean_position == self._position

    def _changed(self) -> None:
        self.project.modified = not self.is_clean
        if self.on_change is not None:
            self.on_change()
