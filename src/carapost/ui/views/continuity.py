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
from PySide6.QtGui import QColor, QFontMetrics
from PySide6.QtWidgets import QHBoxLayout, QLabel, QMenu, QScrollBar, QToolTip

from carapost.model.events import Change
from carapost.model.project import (
    KIND_BRIM,
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
#: A brim dot with a 3D position: solved from the brim model at every frame, not tracked.
BRIM = 6
#: Row of the collapsed calibration brim (in place of a column).
BRIM_HEADER = -1
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
LUT[BRIM] = (70, 130, 190, 255)  # steel blue: the brim model, not tracking
LUT[BLOB] = (20, 40, 170, 255)  # dark blue
LUT[PATCH] = (110, 170, 255, 255)  # light blue
LUT[MANUAL] = (170, 90, 220, 255)
LUT[KEYFRAME] = (255, 255, 255, 255)  # white
_q = np.linspace(0.0, 1.0, N_QUALITY)
LUT[TARGET0:TARGET0 + N_QUALITY] = np.stack(
    [255 * (1 - _q), 60 + 180 * _q, 30 + 0 * _q, 255 + 0 * _q], -1).astype(np.uint8)

COLOUR_NAMES = {CAM4: "dark green", CAM3: "light green", CAM2: "yellow", CAM1: "orange",
                INTERPOLATED: "red", GAP: "empty", BRIM: "steel blue (brim model)"}


def point_codes(project: Project, frames: tuple[int, int] | None = None,
                columns: NDArray[np.intp] | None = None) -> NDArray[np.uint8]:
    """Continuity code of each point-frame, shape (P', F') for the frames (inclusive)
    and point columns (default all).

    4+ contributing cameras -> CAM4 ... 1 -> CAM1; a 3D position with no contributing
    camera (interpolated, filtered) -> INTERPOLATED; no 3D position -> GAP. Brim dots
    with a 3D position are BRIM: their 3D comes from the brim model in every frame (a
    brim with 2D at one frame only is not "interpolated" at the others).
    """
    pts = project.points
    f0, f1 = (0, project.n_frames - 1) if frames is None else frames
    sl = slice(f0, f1 + 1)
    cols = (np.arange(len(pts.kind)) if columns is None
            else np.asarray(columns, dtype=np.intp))
    brim = pts.kind[cols] == KIND_BRIM
    present = ~np.isnan(pts.positions[sl, :, 0][:, cols])
    codes = np.where(present, BRIM, GAP).astype(np.uint8)  # [F', P']
    # Brim dots need only their presence: counting their cameras (a pass over the
    # observations, the bulk of the work on a long take) would be thrown away.
    track = np.flatnonzero(~brim)
    if track.size:
        tcols = cols[track] if columns is not None or brim.any() else slice(None)
        recon = pts.recon[sl][:, tcols]
        measured = (recon != RECON_NONE) & (recon != RECON_INTERPOLATED)
        count = np.zeros(recon.shape, np.uint8)
        for c in range(pts.n_cameras):  # one [F, P] pass per camera: faster than sum(-1)
            count += ((pts.source[sl, :, c] != SOURCE_NONE)
                      & ~np.isnan(pts.obs[sl, :, c, 0]))[:, tcols]
        count *= measured
        if pts.n_cameras == 0:  # an imported C3D: measured by a system we know nothing of
            count = (measured * 4).astype(np.uint8)
        tracked = np.where(count > 0, CAM1 - 1 + np.minimum(count, 4), INTERPOLATED)
        codes[:, track] = np.where(present[:, track], tracked, GAP)
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
        mods = ev.modifiers()
        steps = ev.delta() / 120.0
        if mods & Qt.KeyboardModifier.ControlModifier:  # zoom the rows
            ev.accept()
            self.chart.zoom_rows(0.8 ** steps, self.mapSceneToView(ev.scenePos()).y())
        elif mods & Qt.KeyboardModifier.ShiftModifier:  # scroll the rows
            ev.accept()
            self.chart.scroll_rows(-3 * steps)
        else:  # zoom the frames
            super().wheelEvent(ev, axis=0)


class ContinuityView(BaseView):
    """The Continuity view (and, with ``single=True``, the Selected Point pane)."""

    kind = "continuity"

    def __init__(self, ctx: ViewContext, parent=None, *, single: bool = False) -> None:
        super().__init__(ctx, parent)
        self.single = single
        self.expanded: set[int] = set()
        self.brim_expanded = False  # the brim dots collapse under one header row
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
        # rows that do not fit at a legible height scroll (Shift+wheel or the scroll bar;
        # Ctrl+wheel zooms the rows)
        self.scroll = QScrollBar(Qt.Orientation.Vertical)
        self.scroll.valueChanged.connect(self._scrolled)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(0)
        layout.addWidget(self.plot, 1)
        layout.addWidget(self.scroll)
        self.plot.scene().sigMouseMoved.connect(self._hover)
        # the Selected Point pane with no (or several) points: say so, no fake axis
        self.hint = QLabel(self)
        self.hint.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.hint.setWordWrap(True)
        self.hint.setStyleSheet("color: #b4b4b4; background: #1e1e1e;")
        self.hint.hide()
        self.vb.sigXRangeChanged.connect(lambda *_: self.render())
        self.vb.sigResized.connect(self._resized)
        self.vb.sigYRangeChanged.connect(self._y_changed)
        self.redraw_count = 0
        self.partial_updates = 0  # code updates limited to the changed point-frames
        self._live: dict[int, tuple[int, int]] = {}  # column -> frames drawn from a run
        self.live_draws = 0  # redraws of a Target Tracker run in progress
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
        if self._rows or not self.single:  # else the hint covers the chart
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
            brim = np.flatnonzero(p.points.kind == KIND_BRIM)
            self._brim_cols = brim
            shown = [c for c in range(p.n_points) if p.points.kind[c] != KIND_BRIM]
            if brim.size:
                shown.append(BRIM_HEADER)
                if self.brim_expanded:
                    shown.extend(int(c) for c in brim)
            for col in shown:
                rows.append((col, -1))
                if col >= 0 and int(ids[col]) in self.expanded:
                    rows.extend((col, c) for c in range(C))
        self._rows = rows
        self._row_names = [self._row_name(col, cam) for col, cam in rows]
        self.vb.setLimits(yMin=0, yMax=max(len(rows), 1))
        (y0, _) = self.vb.viewRange()[1]
        self._show_rows(y0, self.rows_that_fit())

    def _show_hint(self) -> None:
        """Selected Point pane: a sentence instead of an empty chart."""
        n = len(self.ctx.project.selection.points)
        text = ("" if self._rows else "Select one point to see its continuity in each "
                "camera" if n == 0 else f"{n} points are selected: select one point to see "
                "its continuity in each camera")
        self.hint.setText(text)
        self.hint.setVisible(bool(text))
        if text:  # over the chart (hiding it would resize the pane)
            self.hint.setGeometry(self.rect())
            self.hint.raise_()

    def resizeEvent(self, ev) -> None:  # keep the hint over the whole pane
        super().resizeEvent(ev)
        if self.hint.isVisible():
            self.hint.setGeometry(self.rect())

    def _y_changed(self, *_: object) -> None:
        self._update_ticks()
        self.render()

    def _row_name(self, col: int, cam: int) -> str:
        if col == BRIM_HEADER:
            n = len(getattr(self, "_brim_cols", ()))
            return f"{'▾' if self.brim_expanded else '▸'} Calibration brim ({n})"
        if cam >= 0:
            return f"   sensor {cam}"
        return self.ctx.project.point_label(col)

    def _resized(self, *_: object) -> None:
        (y0, _) = self.vb.viewRange()[1]
        self._show_rows(y0, self.rows_that_fit())
        self.render()

    #: Smallest row height at which every row's name is drawn (px).
    ROW_PX = 18
    #: Widest names column (px); longer names are elided.
    MAX_NAME_PX = 190

    def rows_that_fit(self) -> float:
        """Rows shown at a legible height (at least one; every row in the Selected Point
        pane)."""
        if self.single:
            return float(max(len(self._rows), 1))
        return max(1.0, float(max(self.vb.height(), 1) // self.ROW_PX))

    def _show_rows(self, top: float, count: float) -> None:
        """Show ``count`` rows from row ``top`` (clamped), and update the scroll bar."""
        n = max(len(self._rows), 1)
        count = float(np.clip(count, 1.0, n))
        top = float(np.clip(top, 0.0, n - count))
        self.vb.setYRange(top, top + count, padding=0)
        self.scroll.blockSignals(True)
        self.scroll.setRange(0, int(np.ceil(n - count)))
        self.scroll.setPageStep(max(int(count), 1))
        self.scroll.setValue(int(round(top)))
        self.scroll.blockSignals(False)
        self.scroll.setVisible(n - count > 0.5)
        self._update_ticks()

    def _scrolled(self, value: int) -> None:
        (y0, y1) = self.vb.viewRange()[1]
        self._show_rows(float(value), y1 - y0)

    def scroll_rows(self, rows: float) -> None:
        """Scroll by ``rows`` (positive: down)."""
        (y0, y1) = self.vb.viewRange()[1]
        self._show_rows(y0 + rows, y1 - y0)

    def zoom_rows(self, factor: float, about: float) -> None:
        """Show ``factor`` times as many rows, keeping row ``about`` in place."""
        (y0, y1) = self.vb.viewRange()[1]
        count = (y1 - y0) * factor
        self._show_rows(about - (about - y0) * factor, count)

    def _hover(self, scene_pos) -> None:
        """Tooltip: point, frame and the cameras contributing there."""
        if not self.vb.sceneBoundingRect().contains(scene_pos):
            return
        pos = self.vb.mapSceneToView(scene_pos)
        row = self.row_at(pos.y())
        p = self.ctx.project
        f = int(np.floor(pos.x()))
        if row is None or not 0 <= f < p.n_frames:
            QToolTip.hideText()
            return
        QToolTip.showText(self.plot.mapToGlobal(self.plot.mapFromScene(scene_pos)),
                          self.describe(row, f), self.plot)

    def describe(self, row: tuple[int, int], frame: int) -> str:
        """What the chart shows at a row and frame, in words (the tooltip)."""
        p = self.ctx.project
        col, cam = row
        if col == BRIM_HEADER:
            return (f"Calibration brim: {len(getattr(self, '_brim_cols', ()))} dots, solved "
                    f"from the brim model at every frame (frame {frame}); double-click to "
                    "show them")
        name = p.point_label(col)
        pts = p.points
        if p.points.kind[col] == KIND_BRIM:
            return f"{name} (brim), frame {frame}: from the brim model"
        seen = [c for c in range(p.n_cameras) if not np.isnan(pts.obs[frame, col, c, 0])
                and pts.source[frame, col, c] != SOURCE_NONE]
        if cam >= 0:
            return f"{name}, sensor {cam}, frame {frame}: " + (
                "observed" if cam in seen else "no observation")
        if np.isnan(pts.positions[frame, col, 0]):
            return f"{name}, frame {frame}: no 3D (gap)"
        code = int(self.row_codes(row)[frame])
        what = COLOUR_NAMES.get(code, "")
        cams = ", ".join(str(c) for c in seen) or "none"
        return f"{name}, frame {frame}: {what}; cameras {cams}"

    def _update_ticks(self) -> None:
        """Row names on the left axis, thinned so they never overlap."""
        names = getattr(self, "_row_names", [])
        (y0, y1) = self.vb.viewRange()[1]
        px_per_row = max(self.vb.height(), 1) / max(y1 - y0, 1e-6)
        step = max(1, int(np.ceil(self.ROW_PX / max(px_per_row, 1e-6) - 1e-6)))
        axis = self.plot.getAxis("left")
        # the names column fits the longest name up to a limit; longer ones are elided in
        # the middle (pyqtgraph would drop a name wider than the axis); the tooltip has
        # the whole name
        fm = QFontMetrics(axis.style.get("tickFont") or self.plot.font())
        widest = max((fm.horizontalAdvance(n) for n in names), default=40)
        width = int(min(max(widest + 16, 70), self.MAX_NAME_PX))
        ticks = [(i + 0.5, fm.elidedText(n, Qt.TextElideMode.ElideMiddle, width - 16))
                 for i, n in enumerate(names) if i % step == 0]
        # every row's name (pyqtgraph otherwise drops names once 80 % of the axis is text)
        axis.setStyle(textFillLimits=[(0, 1.0)])
        axis.setTicks([ticks, []])
        axis.setWidth(width)

    # -- a Target Tracker run drawn as it goes -----------------------------------------------
    def show_live(self, column: int, camera: int, frames: NDArray, scores: NDArray) -> None:
        """Draw frames a Target Tracker run has tracked but not yet written to the model
        (Update Timeline Every Frame): the camera's row coloured by score, the point's row
        counting the camera. :meth:`clear_live` (or the run's result) puts the model's
        codes back."""
        p = self.ctx.project
        fr = np.asarray(frames, dtype=np.intp)
        if (self._codes is None or not len(fr) or not 0 <= column < p.n_points
                or not 0 <= camera < p.n_cameras
                or self._codes.shape != (p.n_points, p.n_frames)):
            return
        fr = fr[(fr >= 0) & (fr < p.n_frames)]
        self.row_codes((column, camera))          # the camera codes of the column, cached
        cams = self._cam_codes[column]
        q = np.clip(np.nan_to_num(np.asarray(scores, np.float64)[:len(fr)]), 0, 1)
        cams[camera, fr] = TARGET0 + np.round(q * (N_QUALITY - 1)).astype(np.uint8)
        if p.points.kind[column] != KIND_BRIM:
            count = (cams[:, fr] != NONE2D).sum(axis=0)
            self._codes[column, fr] = CAM1 - 1 + np.minimum(count, 4)
        lo, hi = self._live.get(column, (int(fr.min()), int(fr.max())))
        self._live[column] = (min(lo, int(fr.min())), max(hi, int(fr.max())))
        self.live_draws += 1
        self.render()

    def clear_live(self) -> None:
        """Forget what :meth:`show_live` drew: the model's codes of those frames again."""
        live, self._live = self._live, {}
        for column, span in live.items():
            if self._codes is not None and column < self._codes.shape[0]:
                self._update_codes(span, np.array([column]))
        if live:
            self.render()

    def row_codes(self, row: tuple[int, int]) -> NDArray[np.uint8]:
        """Codes of one row over every frame."""
        col, cam = row
        if col == BRIM_HEADER:
            assert self._codes is not None
            brim = getattr(self, "_brim_cols", np.zeros(0, np.intp))
            if brim.size == 0 or self._codes.shape[1] == 0:
                return np.zeros(self._codes.shape[1], np.uint8)
            return self._codes[brim].min(axis=0)  # worst state of any brim dot
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
        if self.single:
            self._show_hint()
        if not self._rows or p.n_frames == 0 or self._codes is None:
            self.image.clear()
            self._draw_selection()
            return
        (x0, x1), (y0, y1) = self.vb.viewRange()
        start = int(max(0, np.floor(x0)))
        stop = int(min(p.n_frames, np.ceil(x1) + 1))
        # only the rows in view: 300 points scroll at the cost of the ~40 shown
        r0 = int(np.clip(np.floor(y0), 0, len(self._rows) - 1))
        r1 = int(np.clip(np.ceil(y1), r0 + 1, len(self._rows)))
        if stop <= start:
            self.image.clear()
            return
        width = max(int(self.vb.width()), 50)
        rows = self._rows[r0:r1]
        if all(cam < 0 and col >= 0 for col, cam in rows) and not self.single:
            cols = np.array([col for col, _ in rows], np.intp)
            if r0 == 0 and len(cols) == self._codes.shape[0]:
                data = self._codes[:, start:stop]
            else:
                data = self._codes[cols, start:stop]
        else:
            data = np.stack([self.row_codes(r)[start:stop] for r in rows])
        binned = bin_min(data, 0, stop - start, width)
        rgba = LUT[binned]
        self.image.setImage(rgba, autoLevels=False)
        self.image.setRect(QRectF(start, r0, stop - start, r1 - r0))
        self._draw_selection()

    def _draw_selection(self) -> None:
        p = self.ctx.project
        sel = p.selection.points
        ids = p.points.ids
        rows = [i for i, (col, cam) in enumerate(self._rows) if cam < 0
                and 0 <= col < len(ids) and int(ids[col]) in sel]
        for item in self.sel_items:
            self.vb.removeItem(item)
        self.sel_items = []
        if self.single or not rows:
            return
        for r in rows[:200]:
            item = pg.QtWidgets.QGraphicsRectItem(QRectF(0, r, max(p.n_frames, 1), 1))
            # a clear band with an outline: the selected row stands out among 300
            pen = pg.mkPen(QColor(255, 255, 255, 200), width=1)
            pen.setCosmetic(True)
            item.setPen(pen)
            item.setBrush(pg.mkBrush(QColor(255, 255, 255, 70)))
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
        if row[0] == BRIM_HEADER:
            if double:
                self.brim_expanded = not self.brim_expanded
                self._build_rows()
                self.render()
            else:
                brim = [int(p.points.ids[c]) for c in getattr(self, "_brim_cols", ())]
                p.set_selection(points=brim)
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
        self.brim_expanded = False
        self._build_rows()
        self.render()

    def expand_all(self) -> None:
        """Expand all."""
        self.expanded = {int(i) for i in self.ctx.project.points.ids}
        self.brim_expanded = True
        self._build_rows()
        self.render()

    def fit(self) -> None:
        """Fit to data: the whole view range and every row."""
        p = self.ctx.project
        a, b = p.view_range if p.n_frames else (0, 1)
        self.vb.setXRange(a, b + 1, padding=0)
        self.vb.setLimits(xMin=0, xMax=max(p.n_frames, 1))
        self._show_rows(0, self.rows_that_fit())

    def fit_to_selection(self) -> None:
        """Fit to data: the selected points' rows (all rows when nothing is selected)."""
        p = self.ctx.project
        sel = p.selection.points
        if not sel:
            self.fit()
            return
        ids = p.points.ids
        rows = [i for i, (col, cam) in enumerate(self._rows)
                if col >= 0 and int(ids[col]) in sel]
        if rows:
            self._show_rows(min(rows), max(max(rows) + 1 - min(rows), 1))

    def center_selection(self, frame: bool = False) -> None:
        self.fit_to_selection()

    def add_menu_items(self, menu: QMenu) -> None:
        if not self.single:
            menu.addAction("Collapse all", self.collapse_all)
            menu.addAction("Expand all", self.expand_all)
        menu.addAction("Fit to data", self.fit_to_selection)
