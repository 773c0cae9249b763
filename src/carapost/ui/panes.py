"""Docked panes: History, Selected Point, Log, Properties, Selection, Tracker.

Each pane gets the window's :class:`~carapost.ui.context.ActionContext`, listens to its
change signals itself and changes the project only through the handlers of
:mod:`carapost.ui.handlers` and the context (``ctx.set_properties``), which call the
open project's Session. The Labelling pane is in `carapost.ui.labelling_pane`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from PySide6.QtCore import QModelIndex, Qt
from PySide6.QtGui import QColor
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
    QListView,
    QListWidget,
    QListWidgetItem,
    QPlainTextEdit,
    QPushButton,
    QSpinBox,
    QTableView,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from carapost.model.events import Change
from carapost.model.properties import SECTIONS, TARGET_TRACKER, specs_in_section
from carapost.session import Session
from carapost.ui.actions import NOT_AVAILABLE, requirement_met
from carapost.ui.bridge import LogEntry
from carapost.ui.context import ActionContext
from carapost.ui.handlers import edit as edit_menu
from carapost.ui.models import HistoryModel, LogModel
from carapost.ui.opening import defer_while_opening
from carapost.ui.settings import (
    DISPLAY_PREFERENCES,
    FRAME_PREFERENCES,
    PREFERENCES,
    preference,
    preference_signals,
    set_preference,
)
from carapost.ui.throttle import FrameThrottle
from carapost.ui.views.continuity import ContinuityView


def _vbox(widget: QWidget) -> QVBoxLayout:
    layout = QVBoxLayout(widget)
    layout.setContentsMargins(4, 4, 4, 4)
    return layout


def _touches(change: Change, parts: set[str]) -> bool:
    return bool(change.parts & (parts | {"file"}))


class HistoryPane(QWidget):
    """The undo stack: undone entries in red; click an entry to undo/redo to it."""

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        layout = _vbox(self)
        self.model = HistoryModel(lambda: ctx.stack)
        self.list = QListView()
        self.list.setModel(self.model)
        self.list.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        layout.addWidget(self.list)
        row = QHBoxLayout()
        self.memory = QLabel()
        self.clear_button = QPushButton("Clear History")
        row.addWidget(self.memory, 1)
        row.addWidget(self.clear_button)
        layout.addLayout(row)
        self.clear_button.clicked.connect(lambda: edit_menu.clear_history(ctx))
        self.list.clicked.connect(self._clicked)
        ctx.history_changed.connect(self.refresh)
        self.refresh()

    def refresh(self) -> None:
        """Follow the command stack."""
        self.model.reload()
        self.list.setCurrentIndex(self.model.index(self.model.position))
        self.memory.setText(f"{self.ctx.stack.memory() / 1e6:.1f} MB held")

    def _clicked(self, index: QModelIndex) -> None:
        edit_menu.goto_history(self.ctx, index.row())


class LogPane(QWidget):
    """Time, level, category and text of every log record of the application."""

    MAX_ROWS = 5000

    def __init__(self) -> None:
        super().__init__()
        layout = _vbox(self)
        self.model = LogModel(self.MAX_ROWS)
        self.table = QTableView()
        self.table.setModel(self.model)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setWordWrap(False)
        self.table.verticalHeader().setDefaultSectionSize(self.table.fontMetrics().height() + 6)
        hdr = self.table.horizontalHeader()
        hdr.setSectionResizeMode(3, QHeaderView.ResizeMode.Stretch)
        # the whole time stamp on one line ("2026.01.31 12:00:00.00")
        stamp_width = self.table.fontMetrics().horizontalAdvance("0000.00.00 00:00:00.00")
        self.table.setColumnWidth(0, stamp_width + 16)
        self.table.setColumnWidth(1, 60)
        self.table.setColumnWidth(2, 80)
        self.table.setStyleSheet("QTableView { background: #202020; }")
        layout.addWidget(self.table)
        # the whole message of the selected record (rows show its first line)
        self.detail = QPlainTextEdit()
        self.detail.setReadOnly(True)
        self.detail.setPlaceholderText("Select a message to read it in full")
        self.detail.setMaximumHeight(5 * self.table.fontMetrics().height() + 12)
        layout.addWidget(self.detail)
        self.table.selectionModel().currentRowChanged.connect(self._show_detail)
        self.model.rowsInserted.connect(lambda *_: self.table.scrollToBottom())

    def _show_detail(self, current: QModelIndex, _previous: QModelIndex) -> None:
        entries = self.model.entries
        row = current.row()
        self.detail.setPlainText(entries[row].text if 0 <= row < len(entries) else "")

    @property
    def entries(self) -> list[LogEntry]:
        """The records shown, oldest first."""
        return list(self.model.entries)

    def add(self, entry: LogEntry) -> None:
        """Append one record (shown on the next event-loop turn)."""
        self.model.add(entry)


class PropertiesPane(QWidget):
    """Every section of the properties registry, editable, with units, ranges and help."""

    #: the per-computer group of the main Properties pane (the guide's Show Again Flags)
    PREFERENCES_TITLE = "Show Again Flags (this computer)"
    #: the per-computer group of the guide's Display section, shown first
    DISPLAY_TITLE = "Display (this computer)"
    FRAMES_TITLE = "Frames (this computer)"

    def __init__(self, ctx: ActionContext, sections: tuple[str, ...] | None = None,
                 preferences: tuple[str, ...] | None = None,
                 preferences_title: str = PREFERENCES_TITLE, compact: bool = False) -> None:
        super().__init__()
        self.ctx = ctx
        #: a narrow pane (the Tracker's): each check box carries its name across the row
        self.compact = compact
        layout = _vbox(self)
        self.tree = QTreeWidget()
        self.tree.setColumnCount(3)
        self.tree.setHeaderLabels(["Property", "Value", "Unit"])
        self.tree.setColumnWidth(0, 190)
        self.tree.setColumnWidth(1, 110)
        layout.addWidget(self.tree)
        self.restore_button = QPushButton("Restore Properties To Defaults")
        layout.addWidget(self.restore_button)
        self.restore_button.clicked.connect(
            lambda: edit_menu.session_action(Session.restore_properties_to_defaults,
                                             ctx))
        self.editors: dict[str, QWidget] = {}
        self._updating = False
        shown = sections or tuple(s for s in SECTIONS if s != TARGET_TRACKER)
        for section in shown:
            top = QTreeWidgetItem([section])
            top.setFirstColumnSpanned(True)
            self.tree.addTopLevelItem(top)
            for spec in specs_in_section(section):
                item = QTreeWidgetItem([spec.label, "", spec.unit])
                # the name first: a narrow pane elides it in the Property column
                tip = f"{spec.label}: {spec.help}" + (
                    f" Allowed: {spec.range_text()}." if spec.range_text() else ""
                ) + f" Default: {spec.default}."
                for col in range(3):
                    item.setToolTip(col, tip)
                top.addChild(item)
                editor = self._editor(spec)
                editor.setToolTip(tip)
                self._place(item, editor, spec.label)
                self.editors[spec.key] = editor
            top.setExpanded(section in ("Display", "Selection", "Blob Parameters"))
        main_pane = preferences is None and sections is None
        self.preference_editors: dict[str, QWidget] = {}
        if main_pane:
            preferences = ("show_version_check_dialog",)
            self.preference_editors.update(
                self._add_preferences(DISPLAY_PREFERENCES, self.DISPLAY_TITLE, index=0))
        self.preference_editors.update(
            self._add_preferences(preferences or (), preferences_title))
        # a preference set elsewhere (a view's right-click menu, another window)
        preference_signals().changed.connect(self._show_preference)
        if main_pane:
            self.frame_editors = self._add_preferences(
                tuple(p.key for p in FRAME_PREFERENCES), self.FRAMES_TITLE)
        # the names take the room the values and units leave: a wider pane shows them
        # whole, a narrow one elides them (the tooltip has the whole name and its help)
        header = self.tree.header()
        header.setStretchLastSection(False)
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        header.setSectionResizeMode(1, QHeaderView.ResizeMode.Fixed)
        header.setSectionResizeMode(2, QHeaderView.ResizeMode.ResizeToContents)
        self.tree.setColumnWidth(1, 110)
        if compact:   # the values as wide as their editors, the names get the rest
            self.tree.setIndentation(12)
            self.tree.setColumnWidth(1, max([72] + [
                e.sizeHint().width() for e in (*self.editors.values(),
                                               *self.preference_editors.values())
                if not isinstance(e, QCheckBox)]))
            self.tree.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.tree.setTextElideMode(Qt.TextElideMode.ElideMiddle)
        for i in range(self.tree.topLevelItemCount()):   # spanning needs the item in a tree
            self.tree.topLevelItem(i).setFirstColumnSpanned(True)
        self.refresh(None)
        ctx.view.changed.connect(self.refresh)

    def _add_preferences(self, keys: tuple[str, ...], title: str,
                         index: int | None = None) -> dict[str, QWidget]:
        """A group of GUI preferences, kept in the user settings (QSettings) of this
        computer, not in the project: editing them is not a History entry. The group
        goes at top-level position ``index`` (last when None)."""
        editors: dict[str, QWidget] = {}
        if not keys:
            return editors
        top = QTreeWidgetItem([title])
        top.setFirstColumnSpanned(True)
        top.setToolTip(0, "Kept for you on this computer (not saved in the project).")
        if index is None:
            self.tree.addTopLevelItem(top)
        else:
            self.tree.insertTopLevelItem(index, top)
        by_key = {pref.key: pref for pref in PREFERENCES + FRAME_PREFERENCES}
        settings = self.ctx.settings
        for key in keys:
            pref = by_key[key]
            item = QTreeWidgetItem([pref.label, "", pref.unit])
            allowed = (f" Allowed: from {pref.minimum} to {pref.maximum}."
                       if pref.kind == "int" else "")
            tip = (f"{pref.label}: {pref.help}{allowed} Default: {pref.default}. Kept for "
                   "you on this computer.")
            item.setToolTip(0, tip)
            top.addChild(item)
            editor: QWidget
            if pref.kind == "int":
                spin = QSpinBox()
                spin.setRange(int(pref.minimum if pref.minimum is not None else -10**9),
                              int(pref.maximum if pref.maximum is not None else 10**9))
                spin.setSingleStep(pref.step)
                spin.setKeyboardTracking(False)
                spin.setValue(int(preference(settings, key)))
                spin.valueChanged.connect(
                    lambda v, k=key: set_preference(settings, k, int(v)))
                editor = spin
            else:
                box = QCheckBox()
                box.setChecked(bool(preference(settings, key)))
                box.toggled.connect(lambda v, k=key: set_preference(settings, k, bool(v)))
                editor = box
            editor.setToolTip(tip)
            self._place(item, editor, pref.label)
            editors[key] = editor
        top.setExpanded(True)
        return editors

    def _place(self, item: QTreeWidgetItem, editor: QWidget, label: str) -> None:
        """Put a row's editor in the Value column; in a compact pane a check box takes
        the whole row with its name (clicking the name toggles it, nothing is elided)."""
        if self.compact and isinstance(editor, QCheckBox):
            item.setText(0, "")
            item.setFirstColumnSpanned(True)
            editor.setText(label)
            self.tree.setItemWidget(item, 0, editor)
        else:
            self.tree.setItemWidget(item, 1, editor)

    def _show_preference(self, key: str) -> None:
        editor = self.preference_editors.get(key)
        if editor is None:
            return
        value = preference(self.ctx.settings, key)
        editor.blockSignals(True)
        try:
            if isinstance(editor, QSpinBox):
                editor.setValue(int(value))
            elif isinstance(editor, QCheckBox):
                editor.setChecked(bool(value))
        finally:
            editor.blockSignals(False)

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
            # an open end is a million units (mm, px, s): beyond any value in use, and an
            # editor no wider than the others (1e9 with 3 decimals crowds out the names)
            w.setRange(spec.minimum if spec.minimum is not None else -1e6,
                       spec.maximum if spec.maximum is not None else 1e6)
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
        cur = QColor(self.ctx.project.properties[key])
        colour = QColorDialog.getColor(cur, self, "Colour")
        if colour.isValid():
            self._set(key, colour.name())

    def _set(self, key: str, value: Any) -> None:
        if self._updating or self.ctx.project.properties[key] == value:
            return
        self.ctx.set_properties({key: value})

    @defer_while_opening
    def refresh(self, change: Change | None) -> None:
        """Show the project's current values."""
        if change is not None and not _touches(change, {"properties"}):
            return
        props = self.ctx.project.properties
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

    PARTS = {"selection", "cameras"}

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        layout = _vbox(self)
        layout.addWidget(QLabel("Cameras used by processing and detach commands\n"
                                "(none checked = all cameras):"))
        self.list = QListWidget()
        layout.addWidget(self.list)
        self.summary = QLabel()
        layout.addWidget(self.summary)
        self.list.itemChanged.connect(self._checked)
        ctx.view.changed.connect(self._changed)

    @defer_while_opening
    def _changed(self, change: Change) -> None:
        if _touches(change, self.PARTS):
            self.refresh()

    def refresh(self) -> None:
        """Show the cameras and what is selected."""
        p = self.ctx.project
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

    def _checked(self, item: QListWidgetItem) -> None:
        cams = {c for c in range(self.list.count())
                if self.list.item(c).checkState() == Qt.CheckState.Checked}
        self.ctx.project.set_selection(cameras=cams)


class TrackerPane(QWidget):
    """Target Tracker controls and settings.

    The buttons call the Target Tracker handlers (:mod:`carapost.ui.handlers.target`):
    a track button reads Pause while its run is on the worker.
    """

    BUTTONS = (("<<", "Track back to start", "back_to_start"),
               ("<", "Track back one frame", "back_one"),
               (">", "Track forward one frame", "forward_one"),
               (">>", "Track forward to end", "forward_to_end"),
               ("Clear Tracked Points", "Clear Tracked Points", "clear"),
               ("Add Keyframe To Current Frame", "Add Keyframe To Current Frame",
                "add_keyframe"))
    REQUIRES = "carapost.commands.target_track:prepare_target_track"

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        layout = _vbox(self)
        available = requirement_met(self.REQUIRES)
        row = QHBoxLayout()
        self.buttons: dict[str, QPushButton] = {}
        for i, (text, tip, name) in enumerate(self.BUTTONS):
            b = QPushButton(text)
            b.setToolTip(tip if available else f"{tip} ({NOT_AVAILABLE})")
            b.setEnabled(available)
            if i < 4:
                row.addWidget(b)
            else:
                if i == 4:
                    layout.addLayout(row)
                layout.addWidget(b)
            self.buttons[name] = b
        self.settings_box = QCheckBox("Settings")
        self.settings_box.setChecked(True)
        layout.addWidget(self.settings_box)
        self.settings = PropertiesPane(ctx, (TARGET_TRACKER,), preferences=(
            "tracker_update_timeline_every_frame", "tracker_update_2d_view_every_frame"),
            preferences_title="While Tracking (this computer)", compact=True)
        self.settings.restore_button.hide()
        self.settings.tree.expandAll()
        layout.addWidget(self.settings, 1)
        self.settings_box.toggled.connect(self.settings.setVisible)
        if available:
            from carapost.ui.handlers.target import wire_tracker_pane

            wire_tracker_pane(self, ctx)


def sample_text(project: Any,
                live: dict[tuple[int, int], tuple[int, float, float]] | None = None,
                direction: int = 1) -> str:
    """One line on the selected point's sample at the current frame ("" unless exactly
    one point is selected).

    ``live`` is a Target Tracker run's latest (frame, x, y) of each (point id, camera),
    not yet in the model, and ``direction`` the run's (+1 / -1): a frame the run has
    tracked reads "being target-tracked" with the cameras that have tracked it (each
    camera's track goes on at its own pace), not the model's empty sample."""
    from carapost.algorithms.codes import (
        RECON_FILTERED,
        RECON_INTERPOLATED,
        RECON_NAMES,
        RECON_NONE,
    )

    ids = list(project.selection.points)
    if len(ids) != 1 or ids[0] not in set(project.points.ids.tolist()):
        return ""
    col = int(project.points.index_of(ids)[0])
    f = project.current_frame
    if not 0 <= f < project.n_frames:
        return ""
    if live:
        n = sum(1 for (pid, _), (frame, _, _) in live.items()
                if pid == ids[0] and (frame - f) * direction >= 0)
        if n:
            return (f"{project.point_label(col)} at frame {f}: being target-tracked, "
                    f"{n} camera{'s' if n != 1 else ''}")
    recon = int(project.points.recon[f, col])
    text = f"{project.point_label(col)} at frame {f}: {RECON_NAMES.get(recon, '?')}"
    sig = float(project.points.sigma[f, col])
    if recon in (RECON_INTERPOLATED, RECON_FILTERED):
        if np.isfinite(sig):
            text += f", estimated error {sig:.2f} mm"
        return text
    if recon != RECON_NONE:
        text += f", sigma {sig:.3f} mm" if np.isfinite(sig) else ", sigma unknown"
    n = int(np.isfinite(project.points.obs[f, col, :, 0]).sum())
    return text + f", {n} camera{'s' if n != 1 else ''}"


class SelectedPointPane(QWidget):
    """Continuity of the one selected point, overall and per camera, and the estimated
    uncertainty (sigma) of its sample at the current frame."""

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        layout = _vbox(self)
        self.chart = ContinuityView(ctx.view, single=True)
        # tall enough to name every row of a four-camera rig (the point and its cameras):
        # shorter, the row names are thinned to every other one
        self.chart.setMinimumHeight(ContinuityView.ROW_PX * 5 + 44)
        layout.addWidget(self.chart)
        # the sample at the current frame: how it was made, its estimated error (sigma:
        # from the cameras that see it, or the self-test of Interpolate Gaps for a fill)
        self.sample = QLabel("")
        self.sample.setToolTip("The selected point's sample at the current frame: how it "
                               "was made and its estimated error (mm, one standard "
                               "deviation)")
        layout.addWidget(self.sample)
        self.ctx = ctx
        ctx.view.changed.connect(self.refresh)
        ctx.view.live_changed.connect(self._show_sample)
        self.sample.setText(sample_text(ctx.project))
        # the sample text follows the frame: a few times a second while playing
        self._throttle = FrameThrottle(ctx.view, self._follow_frame)

    def _follow_frame(self) -> None:
        """The refresh the throttle deferred: frame changes only (any other change was
        shown at once), so the chart moves its cursor and keeps its rows; refreshing
        everything recomputed the codes of every point in every frame, 4 times a second
        while playing."""
        self._refresh(Change(frozenset({"current_frame"})))

    @defer_while_opening
    def refresh(self, change: Change | None) -> None:
        """Follow the selection and data."""
        if self._throttle.defer(change):
            return
        self._refresh(change)

    def _refresh(self, change: Change | None) -> None:
        if change is not None and change.parts & {"selection"}:
            self.chart.refresh(None)
        else:
            self.chart.refresh(change)
        self._show_sample()

    def _show_sample(self) -> None:
        view = self.ctx.view
        text = sample_text(self.ctx.project, view.live_xy, view.live_direction)
        if text != self.sample.text():   # an unchanged label costs no re-layout
            self.sample.setText(text)
            self.chart.setToolTip(text)
