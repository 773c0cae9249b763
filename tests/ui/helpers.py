"""Mouse helpers for the GUI tests."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt
from PySide6.QtGui import QMouseEvent
from PySide6.QtWidgets import QApplication


def send_mouse(widget, kind, pos, button=Qt.MouseButton.LeftButton,
               buttons=None, mods=Qt.KeyboardModifier.NoModifier):
    """Send a real mouse event (QTest cannot carry held buttons on moves in Qt 6)."""
    types = {"press": QEvent.Type.MouseButtonPress, "move": QEvent.Type.MouseMove,
             "release": QEvent.Type.MouseButtonRelease,
             "double": QEvent.Type.MouseButtonDblClick}
    p = QPointF(pos)
    glob = QPointF(widget.mapToGlobal(QPoint(int(p.x()), int(p.y()))))
    if buttons is None:
        buttons = Qt.MouseButton.NoButton if kind == "release" else button
    ev = QMouseEvent(types[kind], p, glob, button if kind != "move" else
                     Qt.MouseButton.NoButton, buttons, mods)
    QApplication.sendEvent(widget, ev)


def drag(widget, a, b, mods=Qt.KeyboardModifier.NoModifier, steps=6,
         button=Qt.MouseButton.LeftButton):
    """Press at a, move in steps to b, release."""
    send_mouse(widget, "press", a, button, mods=mods)
    for k in range(1, steps + 1):
        t = k / steps
        q = QPointF(a.x() + (b.x() - a.x()) * t, a.y() + (b.y() - a.y()) * t)
        send_mouse(widget, "move", q, button, buttons=button, mods=mods)
    send_mouse(widget, "release", b, button, mods=mods)


def image_to_widget(view, xy):
    """Raw image px of a camera view -> position in its GraphicsView viewport."""
    scene = view.group.mapToScene(QPointF(float(xy[0]), float(xy[1])))
    return QPointF(view.gv.mapFromScene(scene))


def finite(a):
    return a[~np.isnan(a).any(axis=-1)]


def history_rows(w):
    """(text, colour) of each row of the History pane."""
    model = w.pane("History").model
    return [(model.data(model.index(r), Qt.ItemDataRole.DisplayRole),
             model.data(model.index(r), Qt.ItemDataRole.ForegroundRole).color())
            for r in range(model.rowCount())]


def log_rows(w):
    """(time, level, category, text, colour of the text) of each row of the Log pane."""
    model = w.pane("Log").model
    rows = []
    for r in range(model.rowCount()):
        cells = [model.data(model.index(r, c), Qt.ItemDataRole.DisplayRole) for c in range(4)]
        colour = model.data(model.index(r, 3), Qt.ItemDataRole.ForegroundRole).color()
        rows.append((*cells, colour))
    return rows
