"""Graph view: 3D x/y/z (mm) and 2D x/y (px, in the chosen sensor) of the selected points
against frame; red = x, green = y, blue = z. With Uncertainty Band on, each 3D curve
carries a translucent band of +-1 sigma (the sample's estimated error, where known)."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMenu, QVBoxLayout

from carapost.model.events import Change
from carapost.model.stabilization import display_positions
from carapost.ui.context import ViewContext
from carapost.ui.views import BaseView

AXIS_COLOURS = ((230, 50, 50), (50, 200, 60), (70, 120, 255))
MAX_CURVE_POINTS = 8  # selected points drawn at most (5 curves each)


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
        if ev.button() == Qt.MouseButton.LeftButton and mods & Qt.KeyboardModifier.ControlModifier:
            ev.accept()
            if ev.isFinish():
                a = self.mapSceneToView(ev.buttonDownScenePos()).x()
                b = self.mapSceneToView(ev.scenePos()).x()
                self.graph.range_dragged.emit(int(round(min(a, b))), int(round(max(a, b))))
            return
        super().mouseDragEvent(ev, axis)


class GraphView(BaseView):
    """Graph of the selected points' coordinates."""

    kind = "graph"

    def __init__(self, ctx: ViewContext, camera: int = 0, parent=None) -> None:
        super().__init__(ctx, parent)
        self.camera = camera
        self.track_data = True
        self.recon_data = True
        self.sigma_band = True
        self.layout_widget = pg.GraphicsLayoutWidget()
        self.layout_widget.setBackground((30, 30, 30))
        self.vb3 = _ViewBox(self)
        self.vb2 = _ViewBox(self)
        self.plot3 = self.layout_widget.addPlot(row=0, col=0, viewBox=self.vb3)
        self.plot2 = self.layout_widget.addPlot(row=1, col=0, viewBox=self.vb2)
        self.plot3.setLabel("left", "3D", units="mm")
        self.plot2.setLabel("left", "2D", units="px")
        self.plot2.setLabel("bottom", "frame")
        self.plot2.setXLink(self.plot3)
        for plot in (self.plot3, self.plot2):
            plot.hideButtons()
            plot.showGrid(x=True, y=True, alpha=0.15)
        self.cursors = [pg.InfiniteLine(angle=90, pen=pg.mkPen((255, 255, 255, 150)))
                        for _ in range(2)]
        self.plot3.addItem(self.cursors[0], ignoreBounds=True)
        self.plot2.addItem(self.cursors[1], ignoreBounds=True)
        self.curves3: list[pg.PlotDataItem] = []
        self.bands: list[pg.ErrorBarItem] = []
        self.curves2: list[pg.PlotDataItem] = []
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.layout_widget)
        self.refresh(None)

    def title(self) -> str:
        return f"Graph (Sensor {self.camera})"

    def _curves(self, plot: pg.PlotItem, store: list, n: int) -> list:
        while len(store) < n:
            k = len(store) % 3
            item = pg.PlotDataItem(pen=pg.mkPen(AXIS_COLOURS[k], width=1))
            plot.addItem(item)
            store.append(item)
        for item in store[n:]:
            item.setData([], [])
        return store[:n]

    def _bands(self, n: int) -> list:
        """n +-sigma bands (vertical bars at every frame, translucent, no caps)."""
        while len(self.bands) < n:
            r, g, b = AXIS_COLOURS[len(self.bands) % 3]
            item = pg.ErrorBarItem(x=np.zeros(0), y=np.zeros(0), height=np.zeros(0), beam=0,
                                   pen=pg.mkPen((r, g, b, 70), width=3))
            self.plot3.addItem(item, ignoreBounds=True)
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
        c3 = self._curves(self.plot3, self.curves3, 3 * len(cols) if self.recon_data else 0)
        c2 = self._curves(self.plot2, self.curves2, 2 * len(cols) if self.track_data else 0)
        n_band = 3 * len(cols) if self.recon_data and self.sigma_band else 0
        bands = self._bands(n_band)
        for i, col in enumerate(cols):
            if self.recon_data:
                pos = display_positions(p, slice(None), [col])[:, 0].astype(np.float64)
                for k in range(3):
                    c3[3 * i + k].setData(x, pos[:, k], connect="finite")
                if n_band:
                    sig = p.points.arrays["sigma"][:, col].astype(np.float64)
                    ok = np.isfinite(sig) & np.isfinite(pos[:, 0])
                    for k in range(3):
                        bands[3 * i + k].setData(x=x[ok], y=pos[ok, k], height=2 * sig[ok])
            if self.track_data and self.camera < p.n_cameras:
                obs = p.points.obs[:, col, self.camera].astype(np.float64)
                for k in range(2):
                    c2[2 * i + k].setData(x, obs[:, k], connect="finite")
        self.plot3.setVisible(self.recon_data)
        self.plot2.setVisible(self.track_data)
        if change is None or change.parts & {"selection", "point_list", "file"}:
            self.fit()

    def fit(self) -> None:
        """Fit to data."""
        for plot in (self.plot3, self.plot2):
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
                            ("sigma_band", "Uncertainty Band")):
            act = menu.addAction(title)
            act.setCheckable(True)
            act.setChecked(getattr(self, name))
            act.toggled.connect(lambda on, n=name: self._toggle(n, on))
