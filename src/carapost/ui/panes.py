"""Docked panes: Labelling, History, Selected Point, Log, Properties, Selection, Tracker.

Panes read the project and change it only through the window's ``push(command)``.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QColorDialog,
    QComboBox,
    QDoubleSpinBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QLineEdit,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from carapost.commands import edit
from carapost.model.events import Change
from carapost.model.properties import SECTIONS, TARGET_TRACKER, specs_in_section
from carapost.ui.actions import NOT_AVAILABLE, requirement_met
from carapost.ui.bridge import LogEntry
from carapost.ui.views.continuity import ContinuityView

if TYPE_CHECKING:
    from carapost.ui.mainwindow import MainWindow

RED = QColor(230, 70, 70)
GREY = QColor(150, 150, 150)
YELLOW = QColor(235, 210, 40)
WHITE = QColor(235, 235, 235)


def _vbox(widget: QWidget) -> QVBoxLayout:
    layout = QVBoxLayout(widget)
    layout.setContentsMargins(4, 4, 4, 4)
    return layout


class LabellingPane(QWidget):
    """Label list: red = unassigned, grey = assigned, yellow = assigned but absent now.

    Clicking a label with one point selected assigns it; double-click renames it.
    """

    def __init__(self, win: MainWindow) -> None:
        super().__init__()
        self.win = win
        layout = _vbox(self)
        row = QHBoxLayout()
        self.clear_button = QPushButton("Clear All Labels")
        self.delete_button = QPushButton("Delete Selected Labels")
        row.addWidget(self.clear_button)
        row.addWidget(self.delete_button)
        layout.addLayout(row)
        self.list = QListWidget()
        self.list.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        layout.addWidget(self.list)
        self.clear_button.clicked.connect(lambda: win.edit_command("ClearAllLabels"))
        self.delete_button.clicked.connect(win.delete_selected_labels)
        self.list.itemClicked.connect(self._clicked)
        self.list.itemDoubleClicked.connect(self._rename)

    def selected_labels(self) -> list[str]:
        """Names selected in the list."""
        return [i.text() for i in self.list.selectedItems()]

    def label_state(self, name: str) -> str:
        """``unassigned``, ``assigned`` or ``absent`` (assigned, no 3D this frame)."""
        p = self.win.project
        try:
            col = p.points.labels.index(name)
        except ValueError:
            return "unassigned"
        if p.n_frames and np.isnan(p.points.positions[p.current_frame, col, 0]):
            return "absent"
        return "assigned"

    def refresh(self, change: Change | None) -> None:
        """Rebuild the list (labels change rarely; colours follow the frame)."""
        p = self.win.project
        names = list(p.labels)
        if [self.list.item(i).text() for i in range(self.list.count())] != names:
            self.list.clear()
            self.list.addItems(names)
        colours = {"unassigned": RED, "assigned": GREY, "absent": YELLOW}
        for i in range(self.list.count()):
            item = self.list.item(i)
            item.setForeground(QBrush(colours[self.label_state(item.text())]))

    def _clicked(self, item: QListWidgetItem) -> None:
        p = self.win.project
        if len(p.selection.points) == 1:
            pid = next(iter(p.selection.points))
            self.win.push(edit.AssignLabel(p, pid, item.text()))

    def _rename(self, item: QListWidgetItem) -> None:
        old = item.text()
        new = self.win.dialogs.get_text("Rename Label", "New name:", old)
        if new and new != old:
            from carapost.ui.uicommands import RenameLabel

            self.win.push(RenameLabel(self.win.project, old, new))


class HistoryPane(QWidget):
    """The undo stack: undone entries in red; click an entry to undo/redo to it."""

    def __init__(self, win: MainWindow) -> None:
        super().__init__()
        self.win = win
        layout = _vbox(self)
        self.list = QListWidget()
        layout.addWidget(self.list)
        row = QHBoxLayout()
        self.memory = QLabel()
        self.clear_button = QPushButton("Clear History")
        row.addWidget(self.memory, 1)
        row.addWidget(self.clear_button)
        layout.addLayout(row)
        self.clear_button.clicked.connect(win.clear_history)
        self.list.itemClicked.connect(self._clicked)

    def refresh(self) -> None:
        """Rebuild from the command stack."""
        stack = self.win.stack
        self.list.blockSignals(True)
        self.list.clear()
        head = QListWidgetItem("(opened)")
        head.setForeground(QBrush(GREY))
        self.list.addItem(head)
        for entry in stack.history():
            item = QListWidgetItem(f"{entry.description}   [{entry.memory / 1e6:.2f} MB]")
            item.setForeground(QBrush(RED if entry.undone else WHITE))
            self.list.addItem(item)
        self.list.setCurrentRow(stack.position)
        self.list.blockSignals(False)
        self.memory.setText(f"{stack.memory() / 1e6:.1f} MB held")

    def _clicked(self, item: QListWidgetItem) -> None:
        row = self.list.row(item)
        self.win.goto_history(row)


class LogPane(QWidget):
    """Time, level, category and text of every log record of the application."""

    MAX_ROWS = 5000
    COLOURS = {logging.DEBUG: GREY, logging.INFO: WHITE, logging.WARNING: YELLOW,
               logging.ERROR: RED, logging.CRITICAL: RED}

    def __init__(self) -> None:
        super().__init__()
        layout = _vbox(self)
        self.table = QTableWidget(0, 4)
        self.table.setHorizontalHeaderLabels(["Time", "Level", "Category", "Text"])
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        hdr = self.table.horizontalHeader()
        hdr.setSectionResizeMode(3, QHeaderView.ResizeMode.Stretch)
        self.table.setColumnWidth(0, 150)
        self.table.setColumnWidth(1, 60)
        self.table.setColumnWidth(2, 80)
        self.table.setStyleSheet("QTableWidget { background: #202020; }")
        layout.addWidget(self.table)
        self.entries: list[LogEntry] = []

    def add(self, entry: LogEntry) -> None:
        """Append one record."""
        self.entries.append(entry)
        t = self.table
        if t.rowCount() >= self.MAX_ROWS:
            t.removeRow(0)
            self.entries.pop(0)
        row = t.rowCount()
        t.insertRow(row)
        stamp = time.strftime("%Y.%m.%d %H:%M:%S", time.localtime(entry.time))
        stamp += f".{int((entry.time % 1) * 100):02d}"
        level = logging.getLevelName(entry.level).capitalize()
        colour = self.COLOURS.get(entry.level, WHITE if entry.level < 30 else RED)
        for col, text in enumerate((stamp, level, entry.category,
                                    entry.text.splitlines()[0] if entry.text else "")):
            item = QTableWidgetItem(text)
            item.setForeground(QBrush(colour))
            if col == 3:
                item.setToolTip(entry.text)
            t.setItem(row, col, item)
        t.scrollToBottom()


class PropertiesPane(QWidget):
    """Every section of the properties registry, editable, with units, ranges and help."""

    def __init__(self, win: MainWindow, sections: tuple[str, ...] | None = None) -> None:
        super().__init__()
        self.win = win
        layout = _vbox(self)
        self.tree = QTreeWidget()
        self.tree.setColumnCount(3)
        self.tree.setHeaderLabels(["Property", "Value", "Unit"])
        self.tree.setColumnWidth(0, 190)
        self.tree.setColumnWidth(1, 110)
        layout.addWidget(self.tree)
        self.restore_button = QPushButton("Restore Properties To Defaults")
        layout.addWidget(self.restore_button)
        self.restore_button.clicked.connect(lambda: win.edit_command(
            "RestorePropertiesToDefaults"))
        self.editors: dict[str, QWidget] = {}
        self._updating = False
        shown = sections or tuple(s for s in SECTIONS if s != TARGET_TRACKER)
        for section in shown:
            top = QTreeWidgetItem([section])
            top.setFirstColumnSpanned(True)
            self.tree.addTopLevelItem(top)
            for spec in specs_in_section(section):
                item = QTreeWidgetItem([spec.label, "", spec.unit])
                tip = spec.help + (f" Allowed: {spec.range_text()}." if spec.range_text()
                                   else "") + f" Default: {spec.default}."
                for col in range(3):
                    item.setToolTip(col, tip)
                top.addChild(item)
                editor = self._editor(spec)
                editor.setToolTip(tip)
                self.tree.setItemWidget(item, 1, editor)
                self.editors[spec.key] = editor
            top.setExpanded(section in ("Display", "Selection", "Blob Parameters"))
        self.refresh(None)

    def _editor(self, spec: Any) -> QWidget:
        key = spec.key
        kind = spec.kind
        if kind == "bool":
            w = QCheckBox()
            w.toggled.connect(lambda v: self._set(key, bool(v)))
        elif kind == "int":
            w = QSpinBox()
            w.setRange(int(spec.minimum) if spec.minimum is not None else -10**9,
                       int(spec.maximum) if spec.maximum is not None else 10**9)
            w.setKeyboardTracking(False)
            w.valueChanged.connect(lambda v: self._set(key, int(v)))
        elif kind == "float":
            w = QDoubleSpinBox()
            w.setDecimals(3)
            w.setRange(spec.minimum if spec.minimum is not None else -1e9,
                       spec.maximum if spec.maximum is not None else 1e9)
            w.setSingleStep(0.05 if (spec.maximum or 10) <= 1 else 1.0)
            w.setKeyboardTracking(False)
            w.valueChanged.connect(lambda v: self._set(key, float(v)))
        elif kind == "choice":
            w = QComboBox()
            w.addItems(list(spec.choices or ()))
            w.currentTextChanged.connect(lambda v: self._set(key, v))
        elif kind == "colour":
            w = QPushButton()
            w.clicked.connect(lambda: self._pick_colour(key))
        else:
            w = QLineEdit()
            w.editingFinished.connect(lambda: self._set(key, w.text()))
        return w

    def _pick_colour(self, key: str) -> None:
        cur = QColor(self.win.project.properties[key])
        colour = QColorDialog.getColor(cur, self, "Colour")
        if colour.isValid():
            self._set(key, colour.name())

    def _set(self, key: str, value: Any) -> None:
        if self._updating or self.win.project.properties[key] == value:
            return
        self.win.set_properties({key: value})

    def refresh(self, change: Change | None) -> None:
        """Show the project's current values."""
        if change is not None and not change.parts & {"properties", "file"}:
            return
        props = self.win.project.properties
        self._updating = True
        try:
            for key, w in self.editors.items():
                v = props[key]
                if isinstance(w, QCheckBox):
                    w.setChecked(bool(v))
                elif isinstance(w, QSpinBox | QDoubleSpinBox):
                    w.setValue(v)
                elif isinstance(w, QComboBox):
                    w.setCurrentText(str(v))
                elif isinstance(w, QPushButton):
                    w.setText(str(v))
                    w.setStyleSheet(f"background: {v};")
                elif isinstance(w, QLineEdit):
                    w.setText(str(v))
        finally:
            self._updating = False


class SelectionPane(QWidget):
    """Explicit camera selection used by processing and detach commands."""

    def __init__(self, win: MainWindow) -> None:
        super().__init__()
        self.win = win
        layout = _vbox(self)
        layout.addWidget(QLabel("Cameras used by processing and detach commands\n"
                                "(none checked = all cameras):"))
        self.list = QListWidget()
        layout.addWidget(self.list)
        self.summary = QLabel()
        layout.addWidget(self.summary)
        self.list.itemChanged.connect(self._changed)

    def refresh(self, change: Change | None) -> None:
        """Show the cameras and what is selected."""
        p = self.win.project
        self.list.blockSignals(True)
        if self.list.count() != p.n_cameras:
            self.list.clear()
            for c, cam in enumerate(p.take.cameras):
                item = QListWidgetItem(f"Sensor {c} ({cam.name})")
                item.setFlags(item.flags() | Qt.ItemFlag.ItemIsUserCheckable)
                self.list.addItem(item)
        for c in range(self.list.count()):
            self.list.item(c).setCheckState(Qt.CheckState.Checked if c in p.selection.cameras
                                            else Qt.CheckState.Unchecked)
        self.list.blockSignals(False)
        sel = p.selection
        self.summary.setText(f"{len(sel.points)} points, {len(sel.detections)} detections, "
                             f"{len(sel.cameras)} cameras selected")

    def _changed(self, item: QListWidgetItem) -> None:
        cams = {c for c in range(self.list.count())
                if self.list.item(c).checkState() == Qt.CheckState.Checked}
        self.win.project.set_selection(cameras=cams)


class TrackerPane(QWidget):
    """Target Tracker controls; the buttons are wired by the target-tracker module."""

    BUTTONS = (("<<", "Track back to start", "back_to_start"),
               ("<", "Track back one frame", "back_one"),
               (">", "Track forward one frame", "forward_one"),
               (">>", "Track forward to end", "forward_to_end"))
    REQUIRES = "carapost.commands.target_track:track_points"

    def __init__(self, win: MainWindow) -> None:
        super().__init__()
        self.win = win
        layout = _vbox(self)
        available = requirement_met(self.REQUIRES)
        row = QHBoxLayout()
        self.buttons: dict[str, QPushButton] = {}
        for text, tip, name in self.BUTTONS:
            b = QPushButton(text)
            b.setToolTip(tip if available else f"{tip} ({NOT_AVAILABLE})")
            b.setEnabled(available)
            b.clicked.connect(lambda _=False, n=name: win.target_track(n))
            row.addWidget(b)
            self.buttons[name] = b
        layout.addLayout(row)
        for title, name in (("Clear Tracked Points", "clear"),
                            ("Add Keyframe To Current Frame", "add_keyframe")):
            b = QPushButton(title)
            b.setEnabled(available)
            b.setToolTip(title if available else NOT_AVAILABLE)
            b.clicked.connect(lambda _=False, n=name: win.target_track(n))
            layout.addWidget(b)
            self.buttons[name] = b
        self.settings_box = QCheckBox("Settings")
        self.settings_box.setChecked(True)
        layout.addWidget(self.settings_box)
        self.settings = PropertiesPane(win, (TARGET_TRACKER,))
        self.settings.restore_button.hide()
        self.settings.tree.expandAll()
        layout.addWidget(self.settings, 1)
        self.settings_box.toggled.connect(self.settings.setVisible)


class SelectedPointPane(QWidget):
    """Continuity of the one selected point, overall and per camera."""

    def __init__(self, win: MainWindow) -> None:
        super().__init__()
        layout = _vbox(self)
        self.chart = ContinuityView(win.ctx, single=True)
        self.chart.setMinimumHeight(90)
        layout.addWidget(self.chart)

    def refresh(self, change: Change | None) -> None:
        """Follow the selection and data."""
        if change is not None and change.parts & {"selection"}:
            self.chart.refresh(None)
        else:
            self.chart.refresh(change)
