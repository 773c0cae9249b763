"""The views of a workspace: camera (Sensor N), 3D, Graph and Continuity."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Signal
from PySide6.QtWidgets import QMenu, QWidget

from carapost.model.events import Change
from carapost.ui.context import ViewContext
from carapost.ui.settings import set_preference


class BaseView(QWidget):
    """Common interface of the views.

    Signals
    -------
    menu_requested(QPoint)
        Right-click at a global position; the workspace shows the View menu.
    activated()
        The user interacted with the view (it becomes the active view).
    frame_clicked(int)
        The user asked for this frame (a click on the graph's time axis).
    range_dragged(int, int)
        Ctrl+drag over frames: the user asks for this active range.
    """

    menu_requested = Signal(QPoint)
    activated = Signal()
    frame_clicked = Signal(int)
    range_dragged = Signal(int, int)
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

    def add_option_items(self, menu: QMenu, titles: tuple[tuple[str, str], ...]) -> None:
        """Add the checkable display options and Point Labels: All to a right-click menu.

        Parameters
        ----------
        menu : QMenu
        titles : tuple of (str, str)
            ``(ViewContext.options attribute, menu title)`` of each option, in menu order.
        """
        opts = self.ctx.options
        for key, title in titles:
            act = menu.addAction(title)
            act.setCheckable(True)
            act.setChecked(getattr(opts, key))
            act.toggled.connect(lambda on, k=key: self._set_option(k, on))
        act = menu.addAction("Point Labels: All")
        act.setCheckable(True)
        act.setChecked(self.ctx.label_mode()[0])
        act.toggled.connect(self._set_labels_all)

    def _set_option(self, key: str, on: bool) -> None:
        setattr(self.ctx.options, key, on)
        self.ctx.notify_options()

    def _set_labels_all(self, on: bool) -> None:
        # a user setting (not the take's, so no History entry): every view redraws
        # through the preference's changed signal
        set_preference(self.ctx.user_settings(), "point_labels_all", on)

    def center_selection(self, frame: bool = False) -> None:
        """Center (or frame, when ``frame``) the selected points in this view."""

    def fit(self) -> None:
        """Fit the view's content."""
