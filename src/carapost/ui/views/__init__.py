"""The views of a workspace: camera (Sensor N), 3D, Graph and Continuity."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Signal
from PySide6.QtWidgets import QMenu, QWidget

from carapost.model.events import Change
from carapost.ui.context import ViewContext


class BaseView(QWidget):
    """Common interface of the views.

    Signals
    -------
    menu_requested(QPoint)
        Right-click at a global position; the workspace shows the View menu.
    activated()
        The user interacted with the view (it becomes the active view).
    """

    menu_requested = Signal(QPoint)
    activated = Signal()
    kind = "base"

    def __init__(self, ctx: ViewContext, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.ctx = ctx
        self.camera = 0

    def title(self) -> str:
        """Header text."""
        return self.kind

    def set_camera(self, camera: int) -> None:
        """Choose the sensor (camera and graph views)."""
        self.camera = camera
        self.refresh(None)

    def refresh(self, change: Change | None) -> None:
        """Redraw after a model change (None = everything)."""

    def add_menu_items(self, menu: QMenu) -> None:
        """Add this view's own right-click items."""

    def center_selection(self, frame: bool = False) -> None:
        """Center (or frame, when ``frame``) the selected points in this view."""

    def fit(self) -> None:
        """Fit the view's content."""
