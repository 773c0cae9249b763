"""The menu bar built from the action table (:data:`carapost.ui.actions.ACTIONS`)."""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtCore import Qt
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QMainWindow, QMenu

from carapost.ui import actions as action_table

#: ``make_trigger(spec) -> slot`` of an available item's ``triggered(bool)`` signal.
TriggerFactory = Callable[[action_table.ActionSpec], Callable[[bool], None]]


class MenuBar:
    """The window's menus and one QAction per item of the action table.

    Attributes
    ----------
    menus : dict of str to QMenu
        By menu path (``"File"``, ``"View/Panels"``).
    actions : dict of str to QAction
        By action id (``"edit.merge"``).
    """

    def __init__(self, window: QMainWindow, make_trigger: TriggerFactory) -> None:
        self.window = window
        self.menus: dict[str, QMenu] = {}
        self.actions: dict[str, QAction] = {}
        for top in action_table.MENUS:
            self.menu(top)
        for spec in action_table.ACTIONS:
            if not spec.title:  # a submenu placeholder
                parent = self.menu(spec.menu.rpartition("/")[0])
                if spec.separator:
                    parent.addSeparator()
                self.menu(spec.menu)
                continue
            menu = self.menu(spec.menu)
            if spec.separator:
                menu.addSeparator()
            act = QAction(spec.title, window)
            act.setObjectName(spec.id)
            if spec.shortcut:
                act.setShortcut(QKeySequence(spec.shortcut))
                act.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
            act.setCheckable(spec.checkable)
            if spec.available:
                act.setToolTip(spec.tip or spec.title)
                act.triggered.connect(make_trigger(spec))
            else:
                act.setEnabled(False)
                act.setToolTip(action_table.NOT_AVAILABLE)
                act.setStatusTip(f"{spec.title}: {action_table.NOT_AVAILABLE}")
            menu.addAction(act)
            window.addAction(act)  # shortcuts work with the menu bar hidden (full screen)
            self.actions[spec.id] = act

    def menu(self, path: str) -> QMenu:
        """The menu at ``path``, created (with its parents) on first use."""
        if path in self.menus:
            return self.menus[path]
        parent, _, name = path.rpartition("/")
        menu = self.menu(parent).addMenu(name) if parent else \
            self.window.menuBar().addMenu(name)
        menu.setToolTipsVisible(True)
        self.menus[path] = menu
        return menu

    def fill_recent(self, files: list[str], open_file: Callable[[str], object]) -> None:
        """File > Recent Files: one item per path, or a disabled "(none)"."""
        menu = self.menus["File/Recent Files"]
        menu.clear()
        for path in files:
            menu.addAction(path, lambda p=path: [open_file(p)] and None)
        if not files:
            menu.addAction("(none)").setEnabled(False)
