"""Graph view: the selected points' 3D x, y, z (mm) and 2D u, v (px, in the chosen
sensor) against frame, one stacked plot per coordinate so each has its own axis. With
Uncertainty Band on, each 3D curve carries a translucent band of +-1 sigma (the sample's
estimated error, where known)."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMenu, QVBoxLayout

from carapost.model.events import Change
from carapost.model.stabilization import display_positions
from carapost.ui.context import ViewContext
from carapost.ui.views import BaseView

#: Colours of x, y, z (and u, v) when one point is drawn.
AXIS_COLOURS = ((230, 50, 50), (50, 200, 60), (70, 120, 255))
#: One colour per point when several are drawn (the coordinate is the plot's row).
POINT_COLOURS = ((240, 90, 80), (80, 200, 255), (250, 210, 60), (120, 230, 120),
                 (220, 130, 255), (255, 160, 60), (240, 240, 240), (60, 160, 150))
MAX_CURVE_POINTS = 8  # selected points drawn at most
ROWS = (("x", "mm", 3, 0), ("y", "mm", 3, 1), ("z", "mm", 3, 2),
        ("u", "px", 2, 0), ("v", "px", 2, 1))


class _ViewBox(pg.ViewBox):
    def __init__(self, graph: GraphView) -> None:
        super().__init__(enableMenu=False)
        self.graph = graph

    def mouseClickEvent(self, ev) -> None:
        self.graph.activated.emit()
        if ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.graph.menu_requested.emit(ev.screenPos().toPoint())
        elif ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            x = self.mapSceneToView(ev.scenePos()).x()
            self.graph.frame_clicked.emit(int(round(x)))

    def mouseDragEvent(self, ev, axis=None) -> None:
        mods = ev.modifiers()
        left = ev.button() == Qt.MouseButton.LeftButton
        if left and mods & Qt.KeyboardModifier.ControlModifier:
            ev.accept()
            a = self.mapSceneToView(ev.buttonDownScenePos()).x()
            b = self.mapSceneToView(ev.scenePos()).x()
            self.graph.show_drag(a, b, ev.isFinish())
            if ev.isFinish():
                self.graph.range_dragged.emit(*self.graph.frames_between(a, b))
            return
        if (left and mods & Qt.KeyboardModifier.AltModifier
                and mods & Qt.KeyboardModifier.ShiftModifier):
            ev.accept()  # zoom to the dragged frames
            a = self.mapSceneToView(ev.buttonDownScenePos()).x()
            b = self.mapSceneToView(ev.scenePos()).x()
            self.graph.show_drag(a, b, ev.isFinish())
            if ev.isFinish() and abs(b - a) >= 1:
                self.setXRange(min(a, b), max(a, b), padding=0)
            return
        super().mouseDragEvent(ev, axis)


class GraphView(BaseView):
    """Stacked graphs of the selected points' coordinates, with a legend."""

    kind = "graph"

    def __init__(self, ctx: ViewContext, camera: int = 0, parent=None) -> None:
        super().__init__(ctx, parent)
        self.camera = camera
        self.track_data = True
        self.recon_data = True
        # None: automatic, each curve about its mean when several points are drawn (their
        # offsets would otherwise stretch each axis over the whole face)
        self.about_mean: bool | None = None
        self.sigma_band = True
        self.layout_widget = pg.GraphicsLayoutWidget()
        self.layout_widget.setBackground((30, 30, 30))
        self.plots: list[pg.PlotItem] = []
        self.cursors: list[pg.InfiniteLine] = []
        self.drag_regions: list[pg.LinearRegionItem] = []
        for i, (name, unit, _, _) in enumerate(ROWS):
            plot = self.layout_widget.addPlot(row=i, col=0, viewBox=_ViewBox(self))
            plot.setLabel("left", name, units=unit)
            plot.hideButtons()
            plot.showGrid(x=True, y=True, alpha=0.15)
            plot.getAxis("left").setWidth(62)
            if i:
                plot.setXLink(self.plots[0])
            if i < len(ROWS) - 1:
                plot.getAxis("bottom").setStyle(showValues=False)
            cursor = pg.InfiniteLine(angle=90, pen=pg.mkPen((255, 255, 255, 150)))
            plot.addItem(cursor, ignoreBounds=True)
            region = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(80, 160, 255, 60))
            region.hide()
            plot.addItem(region, ignoreBounds=True)
            self.plots.append(plot)
            self.cursors.append(cursor)
            self.drag_regions.append(region)
        self.plots[-1].setLabel("bottom", "frame")
        self.legend = pg.LegendItem(offset=(-10, 5), labelTextColor=(230, 230, 230),
                                    brush=pg.mkBrush(20, 20, 20, 200))
        self.legend.setParentItem(self.plots[0].getViewBox())
        self.hint = pg.TextItem("Select one or more points to graph their coordinates",
                                color=(200, 200, 200), anchor=(0.5, 0.5))
        self.plots[2].addItem(self.hint, ignoreBounds=True)
        self.curves: list[list[pg.PlotDataItem]] = [[] for _ in ROWS]
        self.bands: list[pg.ErrorBarItem] = []  # point i, coordinate k: bands[3 * i + k]
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.layout_widget)
        self.refresh(None)

    # compatibility with callers of the two-plot layout
    @property
    def plot3(self) -> pg.PlotItem:
        """The x plot (first of the 3D plots)."""
        return self.plots[0]

    @property
    def plot2(self) -> pg.PlotItem:
        """The u plot (first of the 2D plots)."""
        return self.plots[3]

    def title(self) -> str:
        return f"Graph (Sensor {self.camera})"

    def frames_between(self, a: float, b: float) -> tuple[int, int]:
        """The frames dragged over, clamped to the take."""
        n = max(self.ctx.project.n_frames - 1, 0)
        return (int(np.clip(round(min(a, b)), 0, n)), int(np.clip(round(max(a, b)), 0, n)))

    def show_drag(self, a: float, b: float, finished: bool) -> None:
        """Show the dragged frames while the mouse is down."""
        for region in self.drag_regions:
            region.setRegion((min(a, b), max(a, b)))
            region.setVisible(not finished)

    def _curves(self, row: int, n: int) -> list[pg.PlotDataItem]:
        store = self.curves[row]
        while len(store) < n:
            item = pg.PlotDataItem()
            self.plots[row].addItem(item)
            store.append(item)
        for item in store[n:]:
            item.setData([], [])
        return store[:n]

    def _bands(self, n: int) -> list[pg.ErrorBarItem]:
        """n +-sigma bands (vertical bars at every frame, translucent, no caps)."""
        while len(self.bands) < n:
            k = len(self.bands) % 3
            r, g, b = AXIS_COLOURS[k]
            item = pg.ErrorBarItem(x=np.zeros(0), y=np.zeros(0), height=np.zeros(0), beam=0,
                                   pen=pg.mkPen((r, g, b, 70), width=3))
            self.plots[k].addItem(item, ignoreBounds=True)
            self.bands.append(item)
        for item in self.bands[n:]:
            item.setData(x=np.zeros(0), y=np.zeros(0), height=np.zeros(0))
        return self.bands[:n]

    def refresh(self, change: Change | None) -> None:
        p = self.ctx.project
        for cur in self.cursors:
            cur.setValue(p.current_frame)
        if change is not None and change.parts <= {"current_frame", "ranges"}:
            return
        cols = p.selected_columns()[:MAX_CURVE_POINTS]
        F = p.n_frames
        x = np.arange(F, dtype=np.float64)
        self.legend.clear()
        single = len(cols) == 1
        about = self.about_mean if self.about_mean is not None else len(cols) > 1
        bands = self._bands(3 * len(cols) if self.recon_data and self.sigma_band else 0)
        for row, (name, unit, dim, k) in enumerate(ROWS):
            shown = self.recon_data if dim == 3 else self.track_data
            self.plots[row].setVisible(shown)
            curves = self._curves(row, len(cols) if shown else 0)
            if not shown:
                continue
            axis = f"{name} - mean" if about else name
            self.plots[row].setLabel("left", axis, units=unit)
            for i, col in enumerate(cols):
                if dim == 3:  # raw or stabilised, as the views show
                    y = display_positions(p, slice(None), [col])[:, 0, k].astype(np.float64)
                elif self.camera < p.n_cameras:
                    y = p.points.obs[:, col, self.camera, k].astype(np.float64)
                else:
                    y = np.full(F, np.nan)
                if about and np.isfinite(y).any():
                    y = y - np.nanmean(y)
                if dim == 3 and bands:
                    sig = p.points.arrays["sigma"][:, col].astype(np.float64)
                    ok = np.isfinite(sig) & np.isfinite(y)
                    bands[3 * i + k].setData(x=x[ok], y=y[ok], height=2 * sig[ok])
                colour = AXIS_COLOURS[k if dim == 3 else k] if single else POINT_COLOURS[
                    i % len(POINT_COLOURS)]
                curves[i].setData(x, y, connect="finite", pen=pg.mkPen(colour, width=1))
                if row == 0 or (row == 3 and not self.recon_data):
                    self.legend.addItem(curves[i], p.point_label(int(col)))
        self.hint.setVisible(len(cols) == 0)
        if len(cols) == 0:
            self.hint.setPos(max(F, 1) / 2, 0)
        if len(p.selected_columns()) > MAX_CURVE_POINTS:
            self.legend.addItem(pg.PlotDataItem(pen=None),
                                f"(first {MAX_CURVE_POINTS} of "
                                f"{len(p.selected_columns())} selected)")
        if change is None or change.parts & {"selection", "point_list", "file"}:
            self.fit()

    def fit(self) -> None:
        """Fit to data."""
        for plot in self.plots:
            plot.enableAutoRange()
            plot.autoRange()

    def center_selection(self, frame: bool = False) -> None:
        self.fit()

    def _toggle(self, name: str, on: bool) -> None:
        setattr(self, name, on)
        self.refresh(None)

    def add_menu_items(self, menu: QMenu) -> None:
        menu.addAction("Fit to data", self.fit)
        for name, title in (("track_data", "Track Data"), ("recon_data", "Recon Data"),
                            ("about_mean", "Plot About Mean"),
                            ("sigma_band", "Uncertainty Band")):
            act = menu.addAction(title)
            act.setCheckable(True)
            on = getattr(self, name)
            act.setChecked(bool(on) if on is not None else
                           len(self.ctx.project.selected_columns()) > 1)
            act.toggled.connect(lambda on, n=name: self._toggle(n, on))
