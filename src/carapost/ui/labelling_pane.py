"""Labelling pane: the take's label list, a filter, and labelling one click per point.

Red = unassigned, grey = assigned, yellow = assigned but the point has no 3D at this
frame. Clicking a label with one point selected gives that point the label;
double-click renames the label. With **Assign and Next** on, selecting a point in any
view gives it the current label and moves on to the next unassigned one, so labelling
89 points is 89 clicks in the camera views. The filter box narrows the list (Down moves
into it, Enter assigns the current label to the selected point and moves to the next).
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtGui import QBrush, QKeyEvent
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QListWidget,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from carapost.model.events import Change
from carapost.session import Session
from carapost.ui.context import ActionContext
from carapost.ui.handlers import edit as edit_menu
from carapost.ui.models import GREY, RED, YELLOW
from carapost.ui.opening import defer_while_opening
from carapost.ui.throttle import FrameThrottle

__all__ = ["LabellingPane"]


class _LabelList(QListWidget):
    """The list; Enter / Return assigns the current label and moves to the next."""

    def __init__(self, pane: LabellingPane) -> None:
        super().__init__()
        self.pane = pane

    def keyPressEvent(self, ev: QKeyEvent) -> None:
        if ev.key() in (Qt.Key.Key_Return, Qt.Key.Key_Enter):
            self.pane.assign_and_next()
            ev.accept()
            return
        super().keyPressEvent(ev)


class _Filter(QLineEdit):
    """The filter box: Down goes to the list, Escape clears, Enter assigns."""

    def __init__(self, pane: LabellingPane) -> None:
        super().__init__()
        self.pane = pane

    def keyPressEvent(self, ev: QKeyEvent) -> None:
        key = ev.key()
        if key == Qt.Key.Key_Down:
            self.pane.list.setFocus()
            self.pane.move_to(self.pane.first_visible())
        elif key == Qt.Key.Key_Escape:
            self.clear()
        elif key in (Qt.Key.Key_Return, Qt.Key.Key_Enter):
            self.pane.assign_and_next()
        else:
            super().keyPressEvent(ev)
            return
        ev.accept()


class LabellingPane(QWidget):
    """Label list with a filter, keyboard navigation and Assign and Next."""

    PARTS = {"labels", "current_frame", "points", "point_list", "file"}

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        layout = QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        row = QHBoxLayout()
        self.clear_button = QPushButton("Clear All Labels")
        self.delete_button = QPushButton("Delete Selected Labels")
        row.addWidget(self.clear_button)
        row.addWidget(self.delete_button)
        layout.addLayout(row)
        self.filter = _Filter(self)
        self.filter.setPlaceholderText("Filter labels (e.g. lid, _R)")
        self.filter.setClearButtonEnabled(True)
        layout.addWidget(self.filter)
        self.next_box = QCheckBox("Assign and Next")
        self.next_box.setToolTip(
            "Selecting a point gives it the current label, then the next unassigned label "
            "becomes current: one click per point")
        self.assign_button = QPushButton("Assign to Selected && Next")
        self.assign_button.setToolTip("Give the selected point the current label and move "
                                      "to the next unassigned label (Enter)")
        row2 = QHBoxLayout()
        row2.addWidget(self.next_box)
        row2.addWidget(self.assign_button)
        layout.addLayout(row2)
        self.list = _LabelList(self)
        self.list.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.list.setUniformItemSizes(True)
        layout.addWidget(self.list, 1)
        self.status = QLabel()
        self.status.setWordWrap(True)
        layout.addWidget(self.status)
        self.clear_button.clicked.connect(
            lambda: edit_menu.session_action(Session.clear_all_labels, ctx))
        self.delete_button.clicked.connect(lambda: edit_menu.delete_selected_labels(ctx))
        self.assign_button.clicked.connect(self.assign_and_next)
        self.list.itemClicked.connect(lambda item: self._clicked(item.text()))
        self.list.itemDoubleClicked.connect(
            lambda item: edit_menu.rename_label(ctx, item.text()))
        self.list.itemSelectionChanged.connect(self._selection_changed)
        self.filter.textChanged.connect(self._apply_filter)
        ctx.view.changed.connect(self._changed)
        self._last_selection: frozenset[int] = frozenset()
        self._drawn_states: list[str] = []  # state each row is coloured for
        self._row_names: list[str] = []  # the names of the list's rows, in order
        # the colours follow the frame: a few times a second while playing
        self._throttle = FrameThrottle(ctx.view, self.refresh)

    # -- state -----------------------------------------------------------------------------
    def selected_labels(self) -> list[str]:
        """Names selected in the list."""
        return [i.text() for i in self.list.selectedItems()]

    def current_label(self) -> str | None:
        """The label the next assignment gives (the list's current item)."""
        item = self.list.currentItem()
        return item.text() if item is not None and not item.isHidden() else None

    def label_state(self, name: str) -> str:
        """``unassigned``, ``assigned`` or ``absent`` (assigned, no 3D this frame)."""
        p = self.ctx.project
        try:
            col = p.points.labels.index(name)
        except ValueError:
            return "unassigned"
        if p.n_frames and np.isnan(p.points.positions[p.current_frame, col, 0]):
            return "absent"
        return "assigned"

    def label_states(self, names: list[str]) -> list[str]:
        """`label_state` of every name at once (one array lookup for the frame)."""
        p = self.ctx.project
        col_of: dict[str, int] = {}
        for k, name in enumerate(p.points.labels):
            col_of.setdefault(name, k)  # the first column, as `label_state`
        cols = np.array([col_of.get(n, -1) for n in names], np.intp)
        out = np.where(cols >= 0, "assigned", "unassigned").astype(object)
        if p.n_frames and (cols >= 0).any():
            absent = np.isnan(p.points.positions[p.current_frame, cols[cols >= 0], 0])
            out[np.flatnonzero(cols >= 0)[absent]] = "absent"
        return [str(x) for x in out]

    def visible_rows(self) -> list[int]:
        """Rows the filter shows."""
        return [i for i in range(self.list.count()) if not self.list.item(i).isHidden()]

    def first_visible(self) -> int | None:
        rows = self.visible_rows()
        return rows[0] if rows else None

    def next_unassigned(self, after: int | None) -> int | None:
        """The next visible unassigned label after row ``after`` (wrapping), or None."""
        rows = self.visible_rows()
        if not rows:
            return None
        start = 0 if after is None else next((k for k, r in enumerate(rows) if r > after),
                                             len(rows))
        for r in rows[start:] + rows[:start]:
            if r != after and self.label_state(self.list.item(r).text()) == "unassigned":
                return r
        return None

    def move_to(self, row: int | None) -> None:
        """Make ``row`` the current label (selected and scrolled into view)."""
        if row is None:
            return
        self.list.setCurrentRow(row)
        self.list.scrollToItem(self.list.item(row),
                               QAbstractItemView.ScrollHint.PositionAtCenter)

    # -- actions ---------------------------------------------------------------------------
    def _clicked(self, name: str) -> None:
        edit_menu.assign_label(self.ctx, name)
        self._update_status()

    def assign_and_next(self) -> bool:
        """Give the one selected point the current label, then move to the next
        unassigned label. Returns whether a label was assigned."""
        name = self.current_label()
        sel = self.ctx.selection.points
        if name is None or len(sel) != 1:
            self.status.setText("Select one point and a label to assign")
            return False
        row = self.list.currentRow()
        edit_menu.assign_label(self.ctx, name)
        assigned = self.label_state(name) != "unassigned"
        if assigned:
            self.move_to(self.next_unassigned(row))
        self._update_status()
        return assigned

    def _selection_changed(self) -> None:
        self.ctx.label_selection = self.selected_labels()

    def _apply_filter(self, text: str) -> None:
        words = text.lower().split()
        for i in range(self.list.count()):
            item = self.list.item(i)
            name = item.text().lower()
            item.setHidden(bool(words) and not all(w in name for w in words))
        cur = self.list.currentItem()
        if cur is None or cur.isHidden():
            self.move_to(self.next_unassigned(None) if self.visible_rows() else None)
        self._update_status()

    @defer_while_opening
    def _changed(self, change: Change) -> None:
        if self._throttle.defer(change):
            return
        if change.parts is None or change.parts & self.PARTS:
            self.refresh()
        if (self.next_box.isChecked() and (change.parts is None or "selection" in
                                            change.parts)):
            sel = frozenset(self.ctx.selection.points)
            if sel != self._last_selection:
                self._last_selection = sel
                if len(sel) == 1 and self._unlabelled(next(iter(sel))):
                    self.assign_and_next()

    def _unlabelled(self, pid: int) -> bool:
        pts = self.ctx.project.points
        col = pts.index_of([pid])
        return len(col) == 1 and not pts.labels[int(col[0])]

    def refresh(self) -> None:
        """Rebuild the list when the labels changed; colours follow the frame."""
        names = list(self.ctx.project.labels)
        # the rows' names, kept beside the list: reading them back from the widget on
        # every frame change cost more than the rest of the refresh
        if self._row_names != names or self.list.count() != len(names):
            current = self.current_label()
            self.list.clear()
            self._drawn_states = []
            self.list.addItems(names)
            self._row_names = names
            self._apply_filter(self.filter.text())
            if current in names:
                self.list.setCurrentRow(names.index(current))
        colours = {"unassigned": RED, "assigned": GREY, "absent": YELLOW}
        states = self.label_states(self._row_names)
        if len(self._drawn_states) != len(states):
            self._drawn_states = [""] * len(states)
        for i, state in enumerate(states):
            if state == self._drawn_states[i]:
                continue  # the colours follow the frame: touch only the rows that change
            item = self.list.item(i)
            item.setForeground(QBrush(colours[state]))
            item.setToolTip(f"{item.text()}: {state}")
            self._drawn_states[i] = state
        self._update_status()

    def _update_status(self) -> None:
        names = list(self.ctx.project.labels)
        if not names:
            self.status.setText("No labels yet: File > Import Labels, or Process > Label "
                                "From Template")
            return
        todo = self.label_states(names).count("unassigned")
        shown = len(self.visible_rows())
        text = f"{len(names) - todo} of {len(names)} labels assigned"
        if shown != len(names):
            text += f"; {shown} shown"
        self.status.setText(text)
