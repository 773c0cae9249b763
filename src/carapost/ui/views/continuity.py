"""Continuity chart: one bar per point coloured by how many cameras contribute.

The chart is an image, not a scene of rectangles: per-point category codes [P, F] and
per-camera codes [P, C, F] are computed once per model change (only over the changed
frames), then every redraw bins the visible frames down to the widget's width with a
minimum (so a one-frame gap never disappears when zoomed out) and colours the codes
through a lookup table. 300 points x 36,000 frames redraw in a few milliseconds.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from numpy.typing import NDArray
from PySide6.QtCore import QRectF, Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import QMenu, QVBoxLayout

from carapost.model.events import Change
from carapost.model.project import (
    RECON_INTERPOLATED,
    RECON_NONE,
    SOURCE_BLOB,
    SOURCE_KEYFRAME,
    SOURCE_MANUAL,
    SOURCE_NONE,
    SOURCE_PATCH,
    SOURCE_TARGET,
    Project,
)
from carapost.ui.context import ViewContext
from carapost.ui.views import BaseView

# Codes, ordered worst first so a binned minimum keeps the worst state of a bin.
GAP, INTERPOLATED, CAM1, CAM2, CAM3, CAM4 = 0, 1, 2, 3, 4, 5
NONE2D, TARGET0, N_QUALITY = 0, 16, 16
BLOB, PATCH, MANUAL, KEYFRAME = 40, 41, 42, 43

#: Colours of the codes (RGBA).
LUT = np.zeros((256, 4), np.uint8)
LUT[GAP] = (0, 0, 0, 0)
LUT[INTERPOLATED] = (220, 30, 30, 255)  # red
LUT[CAM1] = (255, 140, 0, 255)  # orange
LUT[CAM2] = (240, 220, 0, 255)  # yellow
LUT[CAM3] = (120, 220, 90, 255)  # light green
LUT[CAM4] = (0, 130, 40, 255)  # dark green
LUT[BLOB] = (20, 40, 170, 255)  # dark blue
LUT[PATCH] = (110, 170, 255, 255)  # light blue
LUT[MANUAL] = (170, 90, 220, 255)
LUT[KEYFRAME] = (255, 255, 255, 255)  # white
_q = np.linspace(0.0, 1.0, N_QUALITY)
LUT[TARGET0:TARGET0 + N_QUALITY] = np.stack(
    [255 * (1 - _q), 60 + 180 * _q, 30 + 0 * _q, 255 + 0 * _q], -1).astype(np.uint8)

COLOUR_NAMES = {CAM4: "dark green", CAM3: "light green", CAM2: "yellow", CAM1: "orange",
                INTERPOLATED: "red", GAP: "empty"}


def point_codes(project: Project, frames: tuple[int, int] | None = None,
                columns: NDArray[np.intp] | None = None) -> NDArray[np.uint8]:
    """Continuity code of each point-frame, shape (P', F') for the frames (inclusive)
    and point columns (default all).

    4+ contributing cameras -> CAM4 ... 1 -> CAM1; a 3D position with no contributing
    camera (interpolated, filtered) -> INTERPOLATED; no 3D position -> GAP.
    """
    pts = project.points
    f0, f1 = (0, project.n_frames - 1) if frames is None else frames
    sl = slice(f0, f1 + 1)
    cols = slice(None) if columns is None else np.asarray(columns, dtype=np.intp)
    recon = pts.recon[sl][:, cols]
    measured = (recon != RECON_NONE) & (recon != RECON_INTERPOLATED)
    count = np.zeros(recon.shape, np.uint8)
    for c in range(pts.n_cameras):  # one [F, P] pass per camera: faster than sum(-1)
        count += ((pts.source[sl, :, c] != SOURCE_NONE)
                  & ~np.isnan(pts.obs[sl, :, c, 0]))[:, cols]
    count *= measured
    if pts.n_cameras == 0:  # an imported C3D: measured by a system we know nothing of
        count = (measured * 4).astype(np.uint8)
    present = ~np.isnan(pts.positions[sl, :, 0][:, cols])
    codes = np.where(count > 0, CAM1 - 1 + np.minimum(count, 4), INTERPOLATED)
    codes = np.where(present, codes, GAP).astype(np.uint8)
    return np.ascontiguousarray(codes.T)


def camera_codes(project: Project, column: int) -> NDArray[np.uint8]:
    """Per-camera codes of one point, shape (C, F): source, keyframes, target quality."""
    pts = project.points
    src = pts.source[:, column, :].T
    has = ~np.isnan(pts.obs[:, column, :, 0].T)
    q = np.clip(np.nan_to_num(pts.quality[:, column, :].T.astype(np.float32)), 0, 1)
    codes = np.full(src.shape, NONE2D, np.uint8)
    codes[src == SOURCE_BLOB] = BLOB
    codes[src == SOURCE_PATCH] = PATCH
    codes[src == SOURCE_MANUAL] = MANUAL
    target = src == SOURCE_TARGET
    codes[target] = TARGET0 + np.round(q[target] * (N_QUALITY - 1)).astype(np.uint8)
    codes[(src == SOURCE_KEYFRAME) | pts.keyframe[:, column, :].T] = KEYFRAME
    codes[~has] = NONE2D
    return codes


def bin_min(codes: NDArray[np.uint8], start: int, stop: int, bins: int) -> NDArray[np.uint8]:
    """Columns ``start:stop`` of ``codes`` reduced to at most ``bins`` by minimum."""
    n = stop - start
    if n <= bins:
        return codes[:, start:stop]
    edges = (start + (np.arange(bins) * n) // bins).astype(np.intp)
    return np.minimum.reduceat(codes[:, :stop], edges, axis=1)


class _ViewBox(pg.ViewBox):
    def __init__(self, chart: ContinuityView) -> None:
        super().__init__(invertY=True, enableMenu=False)
        self.chart = chart
        self.setMouseEnabled(x=True, y=False)
        self._range_start: float | None = None

    def mouseClickEvent(self, ev) -> None:
        self.chart.activated.emit()
        if ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.chart.menu_requested.emit(ev.screenPos().toPoint())
            return
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            pos = self.mapSceneToView(ev.scenePos())
            self.chart.click_row(pos.y(), ev.modifiers(), ev.double())

    def mouseDragEvent(self, ev, axis=None) -> None:
        mods = ev.modifiers()
        ctrl = bool(mods & Qt.KeyboardModifier.ControlModifier)
        shift = bool(mods & Qt.KeyboardModifier.ShiftModifier)
        alt = bool(mods & Qt.KeyboardModifier.AltModifier)
        if ev.button() == Qt.MouseButton.LeftButton and ctrl:
            ev.accept()
            pos = self.mapSceneToView(ev.scenePos())
            start = self.mapSceneToView(ev.buttonDownScenePos())
            self.chart.range_drag(start.x(), pos.x(), ev.isFinish())
            return
        if ev.button() == Qt.MouseButton.LeftButton and shift and alt:
            # zoom to the dragged frames
            ev.accept()
            if ev.isFinish():
                a = self.mapSceneToView(ev.buttonDownScenePos()).x()
                b = self.mapSceneToView(ev.scenePos()).x()
                if abs(b - a) >= 1:
                    self.setXRange(min(a, b), max(a, b), padding=0)
            return
        if ev.button() == Qt.MouseButton.LeftButton and not (shift or alt):
            ev.ignore()
            return
        super().mouseDragEvent(ev, axis)

    def wheelEvent(self, ev, axis=None) -> None:
        super().wheelEvent(ev, axis=0)


class ContinuityView(BaseView):
    """The Continuity view (and, with ``single=True``, the Selected Point pane)."""

    kind = "continuity"

    def __init__(self, ctx: ViewContext, parent=None, *, single: bool = False) -> None:
        super().__init__(ctx, parent)
        self.single = single
        self.expanded: set[int] = set()
        self._codes: NDArray[np.uint8] | None = None  # [P, F]
        self._cam_codes: dict[int, NDArray[np.uint8]] = {}
        self._rows: list[tuple[int, int]] = []  # (column, camera or -1)
        self.vb = _ViewBox(self)
        self.plot = pg.PlotWidget(viewBox=self.vb, background=(30, 30, 30))
        self.plot.hideButtons()
        self.plot.getAxis("bottom").setLabel("frame")
        self.image = pg.ImageItem(axisOrder="row-major")
        self.vb.addItem(self.image)
        self.cursor = pg.InfiniteLine(angle=90, pen=pg.mkPen((255, 255, 255), width=1))
        self.vb.addItem(self.cursor, ignoreBounds=True)
        self.active = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(255, 255, 255, 18),
                                          pen=pg.mkPen((200, 200, 200, 90)))
        self.vb.addItem(self.active, ignoreBounds=True)
        self.sel_band = pg.QtWidgets.QGraphicsRectItem()
        self.sel_band.setPen(pg.mkPen(None))
        self.sel_band.setBrush(pg.mkBrush(255, 255, 255, 40))
        self.vb.addItem(self.sel_band, ignoreBounds=True)
        self.sel_items: list = []
        self.drag_region = pg.LinearRegionItem(movable=False, brush=pg.mkBrush(80, 160, 255, 60))
        self.drag_region.hide()
        self.vb.addItem(self.drag_region, ignoreBounds=True)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.plot)
        self.vb.sigXRangeChanged.connect(lambda *_: self.render())
        self.vb.sigResized.connect(self._resized)
        self.vb.sigYRangeChanged.connect(lambda *_: self._update_ticks())
        self.redraw_count = 0
        self.partial_updates = 0  # code updates limited to the changed point-frames
        self.refresh(None)

    def title(self) -> str:
        return "Selected Point" if self.single else "Continuity"

    # -- data ------------------------------------------------------------------------------
    def refresh(self, change: Change | None) -> None:
        p = self.ctx.project
        parts = change.parts if change is not None else None
        data_parts = {"points", "point_list", "frames_range", "file"}
        if parts is None or parts & data_parts or self._codes is None:
            if (parts is not None and parts & data_parts == {"points"}
                    and change.frames is not None and self._codes is not None
                    and self._codes.shape == (p.n_points, p.n_frames)):
                # only some point-frames changed (the journal says which): recompute
                # those codes; the rows stay as they are
                self._update_codes(change.frames, change.points)
                if parts & {"selection", "labels"}:
                    self._build_rows()
            else:
                self._codes = (point_codes(p) if p.n_frames else
                               np.zeros((p.n_points, 0), np.uint8))
                self._cam_codes.clear()
                self._build_rows()
            x_all = parts is None or bool(parts & {"point_list", "frames_range", "file"})
            if x_all:
                self.fit()
        elif parts & {"selection", "labels"}:
            self._build_rows()
        if parts is None or parts & {"ranges", "frames_range", "file"}:
            a, b = p.active_range
            self.active.setRegion((a, b + 1))
        self.cursor.setValue(p.current_frame + 0.5)
        if parts is None or not parts <= {"current_frame"}:
            self.render()

    def _update_codes(self, frames: tuple[int, int], columns: NDArray | None) -> None:
        """Recompute the codes of some frames (inclusive) of some columns (None: all)."""
        p = self.ctx.project
        f0, f1 = max(int(frames[0]), 0), min(int(frames[1]), p.n_frames - 1)
        if f1 < f0:
            return
        if columns is None:
            self._codes[:, f0:f1 + 1] = point_codes(p, (f0, f1))
            self._cam_codes.clear()
        else:
            cols = np.asarray(columns, dtype=np.intp)
            cols = cols[(cols >= 0) & (cols < p.n_points)]
            self._codes[cols, f0:f1 + 1] = point_codes(p, (f0, f1), cols)
            for col in cols:
                self._cam_codes.pop(int(col), None)
        self.partial_updates += 1

    def _build_rows(self) -> None:
        p = self.ctx.project
        C = p.n_cameras
        rows: list[tuple[int, int]] = []
        if self.single:
            cols = p.selected_columns()
            if len(cols) == 1:
                col = int(cols[0])
                rows = [(col, -1)] + [(col, c) for c in range(C)]
        else:
            ids = p.points.ids
            for col in range(p.n_points):
                rows.append((col, -1))
                if int(ids[col]) in self.expanded:
                    rows.extend((col, c) for c in range(C))
        self._rows = rows
        self._row_names = [p.point_label(col) if cam < 0 else f"sensor {cam}"
                           for col, cam in rows]
        self._update_ticks()
        self.vb.setYRange(0, max(len(rows), 1), padding=0)
        self.vb.setLimits(yMin=0, yMax=max(len(rows), 1))

    def _resized(self, *_: object) -> None:
        self._update_ticks()
        self.render()

    def _update_ticks(self) -> None:
        """Row names on the left axis, thinned so they never overlap."""
        names = getattr(self, "_row_names", [])
        (y0, y1) = self.vb.viewRange()[1]
        px_per_row = max(self.vb.height(), 1) / max(y1 - y0, 1e-6)
        step = max(1, int(np.ceil(14 / max(px_per_row, 1e-6))))
        ticks = [(i + 0.5, n) for i, n in enumerate(names) if i % step == 0]
        axis = self.plot.getAxis("left")
        axis.setTicks([ticks, []])
        axis.setWidth(90)

    def row_codes(self, row: tuple[int, int]) -> NDArray[np.uint8]:
        """Codes of one row over every frame."""
        col, cam = row
        if cam < 0:
            assert self._codes is not None
            return self._codes[col]
        if col not in self._cam_codes:
            self._cam_codes[col] = camera_codes(self.ctx.project, col)
        return self._cam_codes[col][cam]

    def render(self) -> None:
        """Redraw the visible frames (binned to the widget width)."""
        p = self.ctx.project
        self.redraw_count += 1
        if not self._rows or p.n_frames == 0 or self._codes is None:
            self.image.clear()
            self._draw_selection()
            return
        (x0, x1), _ = self.vb.viewRange()
        start = int(max(0, np.floor(x0)))
        stop = int(min(p.n_frames, np.ceil(x1) + 1))
        if stop <= start:
            self.image.clear()
            return
        width = max(int(self.vb.width()), 50)
        if all(cam < 0 for _, cam in self._rows) and not self.single:
            cols = np.array([col for col, _ in self._rows], np.intp)
            data = self._codes if len(cols) == self._codes.shape[0] else self._codes[cols]
        else:
            data = np.stack([self.row_codes(r) for r in self._rows])
        binned = bin_min(data, start, stop, width)
        rgba = LUT[binned]
        self.image.setImage(rgba, autoLevels=False)
        self.image.setRect(QRectF(start, 0, stop - start, len(self._rows)))
        self._draw_selection()

    def _draw_selection(self) -> None:
        p = self.ctx.project
        sel = p.selection.points
        ids = p.points.ids
        rows = [i for i, (col, cam) in enumerate(self._rows) if cam < 0
                and col < len(ids) and int(ids[col]) in sel]
        for item in self.sel_items:
            self.vb.removeItem(item)
        self.sel_items = []
        if self.single or not rows:
            return
        for r in rows[:200]:
            item = pg.QtWidgets.QGraphicsRectItem(QRectF(0, r, max(p.n_frames, 1), 1))
            item.setPen(pg.mkPen(None))
            item.setBrush(pg.mkBrush(QColor(255, 255, 255, 45)))
            self.vb.addItem(item, ignoreBounds=True)
            self.sel_items.append(item)

    # -- interaction -------------------------------------------------------------------------
    def row_at(self, y: float) -> tuple[int, int] | None:
        """(column, camera) of the row at view coordinate y."""
        i = int(np.floor(y))
        return self._rows[i] if 0 <= i < len(self._rows) else None

    def click_row(self, y: float, mods, double: bool) -> None:
        """Click selects the point; Ctrl+click toggles it; double-click expands it."""
        row = self.row_at(y)
        p = self.ctx.project
        if row is None:
            if not double and not self.single:
                p.set_selection(points=[])
            return
        pid = int(p.points.ids[row[0]])
        if double and not self.single:
            self.expanded ^= {pid}
            self._build_rows()
            self.render()
            return
        if mods & Qt.KeyboardModifier.ControlModifier:
            p.set_selection(points=set(p.selection.points) ^ {pid})
        else:
            p.set_selection(points={pid})

    def range_drag(self, a: float, b: float, finished: bool) -> None:
        """Ctrl+drag: show the range; on release ask for it to become the active range."""
        n = self.ctx.project.n_frames
        lo = int(np.clip(np.floor(min(a, b)), 0, max(n - 1, 0)))
        hi = int(np.clip(np.floor(max(a, b)), 0, max(n - 1, 0)))
        self.drag_region.setRegion((lo, hi + 1))
        self.drag_region.setVisible(not finished)
        if finished:
            self.range_dragged.emit(lo, hi)

    def collapse_all(self) -> None:
        """Collapse all."""
        self.expanded.clear()
        self._build_rows()
        self.render()

    def expand_all(self) -> None:
        """Expand all."""
        self.expanded = {int(i) for i in self.ctx.project.points.ids}
        self._build_rows()
        self.render()

    def fit(self) -> None:
        """Fit to data: the whole view range and every row."""
        p = self.ctx.project
        a, b = p.view_range if p.n_frames else (0, 1)
        self.vb.setXRange(a, b + 1, padding=0)
        self.vb.setLimits(xMin=0, xMax=max(p.n_frames, 1))
        self.vb.setYRange(0, max(len(self._rows), 1), padding=0)

    def fit_to_selection(self) -> None:
        """Fit to data: the selected points' rows (all rows when nothing is selected)."""
        p = self.ctx.project
        sel = p.selection.points
        if not sel:
            self.fit()
            return
        ids = p.points.ids
        rows = [i for i, (col, cam) in enumerate(self._rows) if int(ids[col]) in sel]
        if rows:
            self.vb.setYRange(min(rows), max(rows) + 1, padding=0)

    def center_selection(self, frame: bool = False) -> None:
        self.fit_to_selection()

    def add_menu_items(self, menu: QMenu) -> None:
        if not self.single:
            menu.addAction("Collapse all", self.collapse_all)
            menu.addAction("Expand all", self.expand_all)
        menu.addAction("Fit to data", self.fit_to_selection)
