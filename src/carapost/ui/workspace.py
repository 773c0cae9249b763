"""A workspace: 1, 2 or 4 views, each of a type chosen from its right-click View menu."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Qt, Signal
from PySide6.QtWidgets import (
    QFrame,
    QGridLayout,
    QHBoxLayout,
    QMainWindow,
    QMenu,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from carapost.model.events import Change
from carapost.ui.context import ViewContext
from carapost.ui.views import BaseView
from carapost.ui.views.camera import CameraView
from carapost.ui.views.continuity import ContinuityView
from carapost.ui.views.graph import GraphView
from carapost.ui.views.view3d import View3D

LAYOUTS = (1, 2, 4)


def make_view(ctx: ViewContext, spec: str) -> BaseView:
    """A view from its spec: ``sensor:N``, ``3d``, ``graph:N`` or ``continuity``."""
    kind, _, arg = spec.partition(":")
    cam = int(arg) if arg.isdigit() else 0
    if kind == "sensor":
        return CameraView(ctx, cam)
    if kind == "graph":
        return GraphView(ctx, cam)
    if kind == "continuity":
        return ContinuityView(ctx)
    return View3D(ctx)


def view_spec(view: BaseView) -> str:
    """Inverse of :func:`make_view`."""
    if view.kind in ("sensor", "graph"):
        return f"{view.kind}:{view.camera}"
    return view.kind


class ViewContainer(QFrame):
    """Holds one view and swaps it when the user picks another type."""

    activated = Signal(object)

    def __init__(self, ctx: ViewContext, spec: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.ctx = ctx
        self.setFrameShape(QFrame.Shape.Box)
        self.setLineWidth(1)
        self._layout = QVBoxLayout(self)
        self._layout.setContentsMargins(1, 1, 1, 1)
        self.view: BaseView = make_view(ctx, spec)
        self._install(self.view)

    def _install(self, view: BaseView) -> None:
        self._layout.addWidget(view)
        view.menu_requested.connect(self.show_menu)
        view.activated.connect(self._view_activated)
        view.frame_clicked.connect(self.ctx.frame_requested)
        view.range_dragged.connect(self.ctx.range_requested)

    def _view_activated(self) -> None:
        self.activated.emit(self)

    def set_spec(self, spec: str) -> None:
        """Change the view type (``sensor:1``, ``3d``...)."""
        if spec == view_spec(self.view):
            return
        old = self.view
        self.view = make_view(self.ctx, spec)
        self._layout.removeWidget(old)
        old.setParent(None)
        old.deleteLater()
        self._install(self.view)
        self.view.refresh(None)
        self.activated.emit(self)

    def build_menu(self) -> QMenu:
        """The right-click menu: View and Sensor submenus, then the view's own items."""
        menu = QMenu(self)
        n = max(self.ctx.project.n_cameras, 1)
        views = menu.addMenu("View")
        for spec, title in ([("3d", "3D"), (f"graph:{self.view.camera}", "Graph"),
                             ("continuity", "Continuity")]
                            + [(f"sensor:{c}", f"Sensor {c}") for c in range(n)]):
            act = views.addAction(title)
            act.setCheckable(True)
            act.setChecked(spec == view_spec(self.view))
            act.triggered.connect(lambda _=False, s=spec: self.set_spec(s))
        if self.view.kind in ("sensor", "graph"):
            sensors = menu.addMenu("Sensor")
            for c in range(n):
                act = sensors.addAction(f"Sensor {c}")
                act.setCheckable(True)
                act.setChecked(c == self.view.camera)
                act.triggered.connect(lambda _=False, cam=c: self.view.set_camera(cam))
        menu.addSeparator()
        self.view.add_menu_items(menu)
        return menu

    def show_menu(self, pos: QPoint) -> None:
        """Pop the menu up at a global position."""
        menu = self.build_menu()
        menu.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        menu.popup(pos)


class Workspace(QWidget):
    """1, 2 or 4 views in a grid with layout buttons."""

    active_changed = Signal(object)

    def __init__(self, ctx: ViewContext, specs: list[str] | None = None, n: int = 4,
                 parent: QWidget | None = None, *, buttons: bool = True) -> None:
        super().__init__(parent)
        self.ctx = ctx
        self.specs = list(specs or ["sensor:0", "sensor:1", "sensor:2", "sensor:3"])
        self.containers: list[ViewContainer] = []
        self.active: ViewContainer | None = None
        outer = QVBoxLayout(self)
        outer.setContentsMargins(0, 0, 0, 0)
        outer.setSpacing(2)
        self.bar = QHBoxLayout()
        self.bar.setContentsMargins(2, 0, 2, 0)
        self.layout_buttons: dict[int, QToolButton] = {}
        if buttons:
            for k in LAYOUTS:
                b = QToolButton()
                b.setText({1: "1 view", 2: "2 views", 4: "4 views"}[k])
                b.setCheckable(True)
                b.clicked.connect(lambda _=False, kk=k: self.set_layout(kk, reset=True))
                self.bar.addWidget(b)
                self.layout_buttons[k] = b
            self.bar.addStretch(1)
            outer.addLayout(self.bar)
        self.grid_host = QWidget()
        self.grid = QGridLayout(self.grid_host)
        self.grid.setContentsMargins(0, 0, 0, 0)
        self.grid.setSpacing(2)
        outer.addWidget(self.grid_host, 1)
        self.n = 0
        self.set_layout(n)
        ctx.changed.connect(self.refresh)
        ctx.options_changed.connect(lambda: self.refresh(None))

    def set_layout(self, n: int, reset: bool = False, *, keep_specs: bool = False) -> None:
        """Show ``n`` views (1, 2 or 4); ``reset`` restores default zoom and rotation.

        ``keep_specs`` builds the views from ``specs`` as set (restoring settings)
        instead of first copying the current views' types into it.
        """
        n = n if n in LAYOUTS else 4
        if not keep_specs:
            self.specs_update()
        while len(self.specs) < n:
            self.specs.append(f"sensor:{len(self.specs) % max(self.ctx.project.n_cameras, 1)}")
        for c in self.containers:
            self.grid.removeWidget(c)
            c.setParent(None)
            c.deleteLater()
        self.containers = []
        for i in range(n):
            box = ViewContainer(self.ctx, self.specs[i])
            box.activated.connect(self._set_active)
            self.grid.addWidget(box, i // 2 if n == 4 else 0, i % 2 if n == 4 else i)
            self.containers.append(box)
        self.n = n
        for k, b in self.layout_buttons.items():
            b.setChecked(k == n)
        self.active = self.containers[0]
        if reset:
            for box in self.containers:
                box.view.fit()

    def specs_update(self) -> None:
        """Copy the containers' current view types into ``specs``."""
        for i, c in enumerate(self.containers):
            if i < len(self.specs):
                self.specs[i] = view_spec(c.view)

    def current_specs(self) -> list[str]:
        """View types of the visible views."""
        return [view_spec(c.view) for c in self.containers]

    def views(self) -> list[BaseView]:
        """The visible views."""
        return [c.view for c in self.containers]

    def _set_active(self, box: ViewContainer) -> None:
        self.active = box
        for c in self.containers:
            c.setStyleSheet("QFrame { border: 1px solid #e0a000; }" if c is box else "")
        if box.view.kind == "sensor":
            self.ctx.active_camera = box.view.camera
        self.active_changed.emit(box.view)

    def refresh(self, change: Change | None) -> None:
        """Redraw every view (while a take opens, each in a slice of its own)."""
        opening = self.ctx.opening
        for c in self.containers:
            view = c.view
            if not opening.hold(view, change, lambda v=view: v.refresh(change)):
                view.refresh(change)


class FloatingWorkspace(QMainWindow):
    """View > New Floating Workspace: a separate window with its own workspace (3D first)."""

    def __init__(self, ctx: ViewContext, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("carapost - workspace")
        self.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        self.workspace = Workspace(ctx, ["3d", "continuity", "graph:0", "sensor:0"], n=1)
        self.setCentralWidget(self.workspace)
        self.resize(800, 600)
