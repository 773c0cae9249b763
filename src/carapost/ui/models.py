"""Qt item models over the command stack's history and the application's log records.

The History and Log panes show these through plain views: no item widgets are built
per row, and the Log keeps at most :attr:`LogModel.max_rows` records in a ring.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import (
    QAbstractListModel,
    QAbstractTableModel,
    QModelIndex,
    QPersistentModelIndex,
    Qt,
    QTimer,
)
from PySide6.QtGui import QBrush, QColor

from carapost.commands.stack import CommandStack, HistoryEntry
from carapost.ui.bridge import LogEntry

RED = QColor(230, 70, 70)
GREY = QColor(150, 150, 150)
YELLOW = QColor(235, 210, 40)
WHITE = QColor(235, 235, 235)

Index = QModelIndex | QPersistentModelIndex
_INVALID = QModelIndex()


class HistoryModel(QAbstractListModel):
    """Row 0 is the opened state, row ``k`` the state after the ``k``-th command.

    Undone entries are drawn red; :meth:`reload` follows the stack after every change.
    ``stack`` is read through a callable because each project has its own stack.
    """

    def __init__(self, stack: Callable[[], CommandStack]) -> None:
        super().__init__()
        self._stack = stack
        self._entries: list[HistoryEntry] = []

    def reload(self) -> None:
        """Take the stack's current history."""
        self.beginResetModel()
        self._entries = self._stack().history()
        self.endResetModel()

    @property
    def position(self) -> int:
        """Row of the current state."""
        return self._stack().position

    def rowCount(self, parent: Index = _INVALID) -> int:
        """Opened state plus one row per command."""
        return 0 if parent.isValid() else 1 + len(self._entries)

    def data(self, index: Index, role: int = Qt.ItemDataRole.DisplayRole) -> Any:
        """Text (description and memory held) and colour of a row."""
        row = index.row()
        if not index.isValid() or not 0 <= row < self.rowCount():
            return None
        entry = self._entries[row - 1] if row else None
        if role == Qt.ItemDataRole.DisplayRole:
            if entry is None:
                return "(opened)"
            return f"{entry.description}   [{entry.memory / 1e6:.2f} MB]"
        if role == Qt.ItemDataRole.ForegroundRole:
            if entry is None:
                return QBrush(GREY)
            return QBrush(RED if entry.undone else WHITE)
        return None


class LogModel(QAbstractTableModel):
    """Time, level, category and text of log records, newest last, at most ``max_rows``.

    Records arriving in a burst are inserted together on the next event-loop turn, and
    the oldest ones dropped in one step once the ring is full.
    """

    HEADERS = ("Time", "Level", "Category", "Text")
    COLOURS = {logging.DEBUG: GREY, logging.INFO: WHITE, logging.WARNING: YELLOW,
               logging.ERROR: RED, logging.CRITICAL: RED}

    def __init__(self, max_rows: int = 5000) -> None:
        super().__init__()
        self.max_rows = max_rows
        self.entries: deque[LogEntry] = deque()
        self._incoming: list[LogEntry] = []
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(0)
        self._timer.timeout.connect(self.flush)

    def add(self, entry: LogEntry) -> None:
        """Queue one record (shown on the next event-loop turn, or at :meth:`flush`)."""
        self._incoming.append(entry)
        if not self._timer.isActive():
            self._timer.start()

    def flush(self) -> None:
        """Show every queued record now."""
        new, self._incoming = self._incoming[-self.max_rows:], []
        if not new:
            return
        drop = max(len(self.entries) + len(new) - self.max_rows, 0)
        if drop:
            self.beginRemoveRows(QModelIndex(), 0, drop - 1)
            for _ in range(drop):
                self.entries.popleft()
            self.endRemoveRows()
        n = len(self.entries)
        self.beginInsertRows(QModelIndex(), n, n + len(new) - 1)
        self.entries.extend(new)
        self.endInsertRows()

    def rowCount(self, parent: Index = _INVALID) -> int:
        """Records shown."""
        return 0 if parent.isValid() else len(self.entries)

    def columnCount(self, parent: Index = _INVALID) -> int:
        """Time, Level, Category, Text."""
        return 0 if parent.isValid() else len(self.HEADERS)

    def headerData(self, section: int, orientation: Qt.Orientation,
                   role: int = Qt.ItemDataRole.DisplayRole) -> Any:
        """Column titles."""
        if orientation == Qt.Orientation.Horizontal and role == Qt.ItemDataRole.DisplayRole:
            return self.HEADERS[section]
        return None

    def colour(self, level: int) -> QColor:
        """Text colour of a level: errors red, warnings yellow, the rest white or grey."""
        return self.COLOURS.get(level, WHITE if level < logging.WARNING else RED)

    def data(self, index: Index, role: int = Qt.ItemDataRole.DisplayRole) -> Any:
        """Cell text, full text as tooltip, colour by level."""
        if not index.isValid() or not 0 <= index.row() < len(self.entries):
            return None
        entry = self.entries[index.row()]
        col = index.column()
        if role == Qt.ItemDataRole.DisplayRole:
            if col == 0:
                stamp = time.strftime("%Y.%m.%d %H:%M:%S", time.localtime(entry.time))
                return stamp + f".{int((entry.time % 1) * 100):02d}"
            if col == 1:
                return logging.getLevelName(entry.level).capitalize()
            if col == 2:
                return entry.category
            return entry.text.splitlines()[0] if entry.text else ""
        if role == Qt.ItemDataRole.ForegroundRole:
            return QBrush(self.colour(entry.level))
        if role == Qt.ItemDataRole.ToolTipRole and col == 3:
            return entry.text
        return None
