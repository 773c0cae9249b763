"""Find Problems pane: the gaps, spikes and suspected swaps of the take, each with
jump-to-frame (click) and a one-click repair (one History entry each)."""

from __future__ import annotations

import logging
from typing import Any

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from carapost.ui.context import ActionContext

log = logging.getLogger("carapost.ui")

_ROLE = Qt.ItemDataRole.UserRole


class ProblemsPane(QWidget):
    """The list of Find Problems (Process > Find Problems fills it too)."""

    def __init__(self, ctx: ActionContext) -> None:
        super().__init__()
        self.ctx = ctx
        ctx.problems_pane = self  # type: ignore[attr-defined]  # for Process > Find Problems
        layout = QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        row = QHBoxLayout()
        self.find_button = QPushButton("Find")
        self.find_button.setToolTip("Look for gaps, spikes and suspected identity swaps of "
                                    "the selected (or all) points in the active range")
        self.repair_button = QPushButton("Repair")
        self.repair_button.setToolTip("Gap: fill it; spike: cut and fill; swap: exchange the "
                                      "two points from that frame on (one undo step)")
        self.find_button.clicked.connect(self.find)
        self.repair_button.clicked.connect(self.repair_current)
        row.addWidget(self.find_button)
        row.addWidget(self.repair_button)
        row.addStretch(1)
        layout.addLayout(row)
        self.list = QListWidget()
        self.list.currentItemChanged.connect(self._jump)
        self.list.itemDoubleClicked.connect(lambda item: self.repair(item.data(_ROLE)))
        layout.addWidget(self.list)
        self.summary = QLabel("Process > Find Problems, or Find")
        self._scope: frozenset[int] = frozenset()
        layout.addWidget(self.summary)
        ctx.project_replaced.connect(lambda: self.show_problems([]))

    def problems(self) -> list[Any]:
        """The problems listed, in order."""
        return [self.list.item(i).data(_ROLE) for i in range(self.list.count())]

    def find(self, again: bool = False) -> list[Any]:
        """Run Find Problems on the selected (or all) points and list the result;
        ``again``: on the points of the previous search (clicking an entry selects its
        point, which must not narrow the next search)."""
        scope = self._scope if again else self.ctx.selection.points
        found = self.ctx.act("Find Problems", self.ctx.session.find_problems,
                             sorted(scope) if scope else
                             [int(i) for i in self.ctx.project.points.ids])
        self.show_problems(found or [], scope)
        return found or []

    def show_problems(self, problems: list[Any], scope: Any = None) -> None:
        """List ``problems`` found on the points ``scope`` (None: all) and bring the
        pane to the front."""
        self._scope = frozenset(scope) if scope else frozenset()
        self.list.blockSignals(True)
        self.list.clear()
        self.list.blockSignals(False)
        for p in problems:
            item = QListWidgetItem(p.text)
            item.setData(_ROLE, p)
            self.list.addItem(item)
        n = {k: sum(1 for p in problems if p.kind == k) for k in ("gap", "spike", "swap")}
        self.summary.setText(f"{n['gap']} gaps, {n['spike']} spikes, {n['swap']} suspected "
                             "swaps")
        dock = self.parentWidget()
        if problems and dock is not None and hasattr(dock, "raise_"):
            dock.show()
            dock.raise_()

    def _jump(self, item: QListWidgetItem | None, _previous: Any = None) -> None:
        if item is None:
            return
        p = item.data(_ROLE)
        ctx = self.ctx
        if not all(pid in set(ctx.project.points.ids.tolist()) for pid in p.point_ids):
            return
        ctx.project.set_selection(points=list(p.point_ids))
        # a gap: the frame before it, where the point was last seen (as Go To Next Gap)
        ctx.set_frame(max(p.first - 1, 0) if p.kind == "gap" else p.first)

    def repair_current(self) -> None:
        """Repair the problem under the cursor."""
        item = self.list.currentItem()
        if item is not None:
            self.repair(item.data(_ROLE))

    def repair(self, problem: Any) -> bool:
        """One-click repair; the list is searched again afterwards (a swap moves data)."""
        done = self.ctx.act(f"Repair {problem.kind}", self.ctx.session.repair, problem)
        if done is None:
            return False
        row = self.list.currentRow()
        self.find(again=True)
        if self.list.count():
            self.list.setCurrentRow(min(max(row, 0), self.list.count() - 1))
        return True
