"""The dock panes of the main window, declared once: what each holds and where it docks.

Adding a pane is one :class:`PaneSpec` row: its widget factory takes the window's
:class:`~carapost.ui.context.ActionContext` (the pane subscribes to the changes it shows
itself), and View > Panels lists it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QDockWidget, QMainWindow, QWidget

from carapost.ui.context import ActionContext
from carapost.ui.labelling_pane import LabellingPane
from carapost.ui.panes import (
    HistoryPane,
    LogPane,
    PropertiesPane,
    SelectedPointPane,
    SelectionPane,
    TrackerPane,
)
from carapost.ui.problems import ProblemsPane

Area = Qt.DockWidgetArea


@dataclass(frozen=True)
class PaneSpec:
    """One dock pane.

    Attributes
    ----------
    name : str
        Title, object name suffix (``dock-<name>``) and View > Panels entry.
    factory : callable
        ``factory(ctx) -> QWidget``.
    area : Qt.DockWidgetArea
        Where it docks by default.
    tab_with : str
        Name of an earlier pane to share a tabbed dock with ("" = its own dock).
    """

    name: str
    factory: Callable[[ActionContext], QWidget]
    area: Area
    tab_with: str = ""


#: Panes in View > Panels order.
PANES: tuple[PaneSpec, ...] = (
    PaneSpec("Labelling", LabellingPane, Area.RightDockWidgetArea),
    PaneSpec("History", HistoryPane, Area.RightDockWidgetArea),
    PaneSpec("Selected Point", SelectedPointPane, Area.BottomDockWidgetArea),
    PaneSpec("Log", lambda ctx: LogPane(), Area.BottomDockWidgetArea),
    PaneSpec("Properties", lambda ctx: PropertiesPane(ctx, compact=True),
             Area.LeftDockWidgetArea),
    PaneSpec("Selection", SelectionPane, Area.LeftDockWidgetArea, tab_with="Properties"),
    PaneSpec("Tracker", TrackerPane, Area.LeftDockWidgetArea, tab_with="Properties"),
    PaneSpec("Find Problems", ProblemsPane, Area.RightDockWidgetArea, tab_with="History"),
)


def pane_names() -> list[str]:
    """Pane titles in View > Panels order."""
    return [spec.name for spec in PANES]


def build_docks(window: QMainWindow, ctx: ActionContext) -> dict[str, QDockWidget]:
    """Create every pane of :data:`PANES` in its dock and lay the docks out."""
    docks: dict[str, QDockWidget] = {}
    for spec in PANES:
        dock = QDockWidget(spec.name, window)
        dock.setObjectName(f"dock-{spec.name}")
        dock.setWidget(spec.factory(ctx))
        window.addDockWidget(spec.area, dock)
        if spec.tab_with:
            window.tabifyDockWidget(docks[spec.tab_with], dock)
        docks[spec.name] = dock
    for spec in PANES:
        if spec.tab_with:
            docks[spec.tab_with].raise_()
    window.splitDockWidget(docks["Log"], docks["Selected Point"], Qt.Orientation.Horizontal)
    window.resizeDocks([docks["Properties"], docks["Labelling"]], [330, 260],
                       Qt.Orientation.Horizontal)
    window.resizeDocks([docks["Log"]], [170], Qt.Orientation.Vertical)
    return docks
