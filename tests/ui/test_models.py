"""The History and Log item models, without a window."""

from __future__ import annotations

import logging

from PySide6.QtCore import Qt

from carapost.commands.edit import SetRange
from carapost.commands.stack import CommandStack
from carapost.model.project import new_project
from carapost.ui.bridge import LogEntry
from carapost.ui.models import HistoryModel, LogModel

DISPLAY, FOREGROUND = Qt.ItemDataRole.DisplayRole, Qt.ItemDataRole.ForegroundRole


def test_history_model_follows_the_stack(qapp):
    p = new_project(30, 2)
    stack = CommandStack(p)
    model = HistoryModel(lambda: stack)
    model.reload()
    assert model.rowCount() == 1 and model.data(model.index(0), DISPLAY) == "(opened)"
    stack.push(SetRange(p, "active_range", (2, 9)))
    stack.push(SetRange(p, "active_range", (3, 8)))
    stack.undo()
    model.reload()
    texts = [model.data(model.index(r), DISPLAY) for r in range(model.rowCount())]
    assert len(texts) == 3 and all(t.endswith("MB]") for t in texts[1:])
    red = model.data(model.index(2), FOREGROUND).color()
    white = model.data(model.index(1), FOREGROUND).color()
    assert red.green() < 100 < red.red() and white.green() > 200
    assert model.position == 1
    assert model.data(model.index(5), DISPLAY) is None


def test_log_model_keeps_a_ring_of_the_newest_records(qapp):
    model = LogModel(max_rows=5)
    removed = []
    model.rowsRemoved.connect(lambda parent, a, b: removed.append((a, b)))
    for i in range(4):
        model.add(LogEntry(1.0e9 + i, logging.INFO, "test", f"line {i}"))
    model.flush()
    assert model.rowCount() == 4 and not removed
    for i in range(4, 12):  # a burst: dropped in one step, not row by row
        model.add(LogEntry(1.0e9 + i, logging.WARNING if i % 2 else logging.ERROR, "test",
                           f"line {i}\nsecond line"))
    model.flush()
    assert model.rowCount() == 5 and removed == [(0, 3)]
    texts = [model.data(model.index(r, 3), DISPLAY) for r in range(5)]
    assert texts == [f"line {i}" for i in range(7, 12)]
    assert model.data(model.index(0, 3), Qt.ItemDataRole.ToolTipRole) == "line 7\nsecond line"
    assert model.data(model.index(0, 1), DISPLAY) == "Warning"
    assert model.data(model.index(1, 3), FOREGROUND).color().name() == "#e64646"
    assert model.headerData(2, Qt.Orientation.Horizontal) == "Category"
