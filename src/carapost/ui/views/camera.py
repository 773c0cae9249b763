"""Camera (Sensor N) view: the video frame with detections, points, projections, errors.

Drawing is vectorised per frame: every kind of overlay is one graphics item whose data
is replaced (ellipses of all detections are one polyline with breaks), so scrubbing
with a hundred markers and hundreds of detections costs a handful of array copies.
Everything is drawn in raw image pixels (OpenCV convention, pixel centres at integers)
inside one group item that carries the sensor's display rotation.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from numpy.typing import NDArray
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QPainterPath, QPen
from PySide6.QtWidgets import QGraphicsPathItem, QGraphicsRectItem, QLabel, QMenu, QVBoxLayout

from carapost.algorithms.codes import RECON_INTERPOLATED
from carapost.model.events import Change
from carapost.ui.context import OPTION_TITLES_2D, ViewContext
from carapost.ui.views import BaseView
from carapost.ui.views.camera_image import CameraImageMixin
from carapost.ui.views.geometry import (
    cross_segments,
    crossed_circle,
    ellipse_polyline,
    points_in_polygon,
    rotation_transform,
)
from carapost.ui.views.overlays import declutter, rom_overlay
from carapost.ui.views.scatter import Scatter as _Scatter
from carapost.ui.views.target_overlay import TargetOverlay

pg.setConfigOptions(imageAxisOrder="row-major", antialias=False)

RED = (230, 40, 40)
BLUE = (60, 140, 255)
YELLOW = (255, 230, 0)
ORANGE = (255, 150, 0)
GREEN = (40, 220, 90)
SELECTED = (255, 255, 255)
_PICK_PX = 10.0


def _curve(colour: tuple[int, int, int], width: float = 1.0, z: float = 0) -> pg.PlotCurveItem:
    item = pg.PlotCurveItem(pen=pg.mkPen(colour, width=width), antialias=False)
    item.setZValue(z)
    return item


class _ViewBox(pg.ViewBox):
    """ViewBox whose mouse handling follows the guide's camera-view bindings."""

    def __init__(self, view: CameraView) -> None:
        super().__init__(lockAspect=True, invertY=True, enableMenu=False)
        self.view = view
        self.setBackgroundColor(QColor(60, 60, 60))

    def mouseClickEvent(self, ev) -> None:
        self.view.activated.emit()
        if ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.view.menu_requested.emit(ev.screenPos().toPoint())
            return
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            self.view.click(ev.scenePos(), ev.modifiers(), ev.double())

    def mouseDragEvent(self, ev, axis=None) -> None:
        mods = ev.modifiers()
        shift = bool(mods & Qt.KeyboardModifier.ShiftModifier)
        alt = bool(mods & Qt.KeyboardModifier.AltModifier)
        if ev.button() == Qt.MouseButton.LeftButton and not (shift != alt):
            # plain drag: rubber band; Shift+Alt: lasso; measurement mode: a line
            ev.accept()
            self.view.drag(ev, lasso=shift and alt)
            return
        # Shift/Alt+left or middle: pan; right: zoom (pyqtgraph's own handling)
        super().mouseDragEvent(ev, axis)


class CameraView(CameraImageMixin, BaseView):
    """One camera: ``camera`` is its index in the take."""

    kind = "sensor"

    def __init__(self, ctx: ViewContext, camera: int = 0, parent=None) -> None:
        super().__init__(ctx, parent)
        self.camera = camera
        self.measuring = False
        self._measure: tuple[QPointF, QPointF] | None = None
        self._image_shape: tuple[int, int] | None = None
        self._rotation = 0
        self._fitted = False
        self._drawn_frame = -1

        self.gv = pg.GraphicsView(background=(40, 40, 40))
        self.vb = _ViewBox(self)
        self.gv.setCentralItem(self.vb)
        self.group = pg.ItemGroup()
        self.vb.addItem(self.group)
        self.image = pg.ImageItem(axisOrder="row-major")
        self.image.setParentItem(self.group)
        self.image.setPos(-0.5, -0.5)
        self.border = QGraphicsRectItem()
        self.border.setParentItem(self.group)
        self.border.setPen(pg.mkPen((150, 150, 150), style=Qt.PenStyle.DashLine))
        self.det_ellipses = _curve(RED, 1.0, 2)
        self.det_cross = _curve(RED, 1.0, 2)
        self.det_selected = _curve(SELECTED, 2.0, 3)
        self.preview = _curve(GREEN, 1.0, 2)
        self.errors = _curve(YELLOW, 1.0, 4)
        self.sticks = _curve((255, 255, 0), 1.0, 1)
        self.measure_line = _curve((0, 255, 255), 2.0, 10)
        self.points = _Scatter(pxMode=True, symbol="o", size=14,
                                         pen=pg.mkPen(BLUE, width=2), brush=None)
        self.points.setZValue(5)
        self.selected = _Scatter(pxMode=True, symbol="o", size=18,
                                           pen=pg.mkPen(SELECTED, width=2), brush=None)
        self.selected.setZValue(6)
        self.proj_conn = _Scatter(pxMode=True, symbol="+", size=9,
                                            pen=pg.mkPen(YELLOW, width=1.5), brush=None)
        self.proj_unconn = _Scatter(pxMode=True, symbol="+", size=9,
                                              pen=pg.mkPen(ORANGE, width=1.5), brush=None)
        self.rom = _Scatter(pxMode=True, symbol="o", size=6,
                                      pen=None, brush=pg.mkBrush(150, 200, 255, 160))
        # interpolated 3D samples: a small crossed circle at their projection
        self.interp = _Scatter(pxMode=True, symbol=crossed_circle(), size=11,
                               pen=pg.mkPen(RED, width=1.5), brush=None)
        self.interp.setZValue(5)
        for item in (self.det_ellipses, self.det_cross, self.det_selected, self.preview,
                     self.errors, self.sticks, self.measure_line, self.points, self.selected,
                     self.proj_conn, self.proj_unconn, self.rom, self.interp, self.image,
                     self.border):
            item.setParentItem(self.group)
            # overlays never take the mouse: clicks and drags belong to the view box
            item.setAcceptedMouseButtons(Qt.MouseButton.NoButton)
            item.setAcceptHoverEvents(False)
        self.targets = TargetOverlay(self.group)
        self._labels: list[pg.TextItem] = []
        self.band = QGraphicsRectItem()
        self.band.setPen(pg.mkPen((255, 255, 255), style=Qt.PenStyle.DashLine))
        self.band.setBrush(pg.mkBrush(255, 255, 255, 30))
        self.band.setZValue(20)
        self.band.hide()
        self.vb.addItem(self.band, ignoreBounds=True)
        self.lasso = QGraphicsPathItem()
        self.lasso.setPen(pg.mkPen((255, 255, 255), style=Qt.PenStyle.DashLine))
        self.lasso.setZValue(20)
        self.lasso.hide()
        self.vb.addItem(self.lasso, ignoreBounds=True)
        self._lasso_pts: list[tuple[float, float]] = []
        self._drag_origin: QPointF | None = None

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.gv)
        self.header = QLabel(self.gv)
        self.header.setStyleSheet("color: white; background: rgba(0,0,0,120); padding: 2px;")
        self.header.move(4, 4)
        # why there is no image (missing or damaged video), over the view's lower left
        self.notice = QLabel(self.gv)
        self.notice.setStyleSheet("color: #ffb0a0; background: rgba(0,0,0,160); padding: 3px;")
        self.notice.setWordWrap(True)
        self.notice.hide()
        self._current_image: NDArray | None = None
        self._image_frame: int | None = None  # frame of the image shown
        self._stretched = False  # the image is a proxy's, scaled to the original's size
        self.report = QLabel(self.gv)
        self.report.setStyleSheet("color: #8ff; background: rgba(0,0,0,140); padding: 2px;")
        self.report.move(4, 26)
        self.report.hide()
        self.gv.scene().sigMouseMoved.connect(self._mouse_moved)
        # the zoom decides whether a playback proxy is detailed enough (`_tell_scale`)
        self._init_image_scale()
        self.refresh(None)

    # -- geometry ----------------------------------------------------------------------------
    def title(self) -> str:
        p = self.ctx.project
        name = p.take.cameras[self.camera].name if self.camera < p.n_cameras else "?"
        return f"Sensor {self.camera} ({name})"

    def image_size(self) -> tuple[int, int]:
        """(width, height) of this camera's images."""
        p = self.ctx.project
        if self._image_shape is not None:
            return self._image_shape[1], self._image_shape[0]
        if self.camera < p.n_cameras:
            return tuple(p.take.cameras[self.camera].image_size)  # type: ignore[return-value]
        return (640, 480)

    def _update_rotation(self) -> None:
        p = self.ctx.project
        rot = p.take.cameras[self.camera].rotation if self.camera < p.n_cameras else 0
        w, h = self.image_size()
        self.group.setTransform(rotation_transform(rot, w, h))
        self.border.setRect(QRectF(-0.5, -0.5, w, h))
        if rot != self._rotation:
            self._rotation = rot
            self.fit()

    def displayed_rect(self) -> QRectF:
        """The rotated image's rectangle in view coordinates."""
        w, h = self.image_size()
        return self.group.transform().mapRect(QRectF(-0.5, -0.5, w, h))

    def fit(self) -> None:
        """Fit To Window."""
        self.vb.setRange(self.displayed_rect(), padding=0.02)

    def actual_size(self) -> None:
        """Actual Size: one image pixel per screen pixel, keeping the centre."""
        centre = self.vb.viewRect().center()
        size = self.vb.size()
        self.vb.setRange(QRectF(centre.x() - size.width() / 2, centre.y() - size.height() / 2,
                                size.width(), size.height()), padding=0)

    def to_image(self, scene_pos: QPointF) -> QPointF:
        """Scene position -> raw image pixel coordinates."""
        return self.group.mapFromScene(scene_pos)

    def image_scale(self) -> float:
        """Screen pixels per image pixel."""
        px = self.vb.viewPixelSize()
        return 1.0 / max(px[0], 1e-9)

    # -- drawing -----------------------------------------------------------------------------
    def set_camera(self, camera: int) -> None:
        self.camera = camera
        self._image_shape = None
        self._fitted = False
        self.refresh(None)

    def refresh(self, change: Change | None) -> None:
        p = self.ctx.project
        self.header.setText(self.title() + self._mode_text())
        self.header.adjustSize()
        if p.n_cameras == 0 or p.n_frames == 0 or self.camera >= p.n_cameras:
            for item in self._overlay_items():
                item.hide()
            self.image.clear()
            return
        frame = p.current_frame
        if change is not None and change.parts <= {"selection"} and frame == self._drawn_frame:
            self._draw_overlays(frame)  # the image did not change
            return
        self._draw_image(frame)
        self._update_rotation()
        if not self._fitted and self.vb.width() > 10:
            self.fit()
            self._fitted = True
        self._draw_overlays(frame)
        self._drawn_frame = frame
        if self.ctx.lock_to_point:
            self.center_selection(frame=False)

    def image_landed(self, frame: int) -> None:
        """The decoded image of ``frame`` arrived: show it. The overlays of the current
        frame are drawn already (they do not wait for images), so only the image is
        replaced, unless the Blob Preview, which is computed from the image, is on."""
        if frame != self._drawn_frame or self.ctx.options.blob_preview or not self._fitted:
            self.refresh(None)
            return
        self._draw_image(frame)
        self._update_rotation()

    def _mode_text(self) -> str:
        sel = self.ctx.project.selection.cameras
        parts = []
        if self.camera in sel:
            parts.append("selected")
        if self.measuring:
            parts.append("Measure")
        mode = {"add": "Add Target Track", "edit": "Edit Target Track"}.get(
            getattr(self.ctx, "point_mode", ""))
        if mode:
            parts.append(mode)
        return ("  [" + ", ".join(parts) + "]") if parts else ""

    def _overlay_items(self) -> list:
        return [self.det_ellipses, self.det_cross, self.det_selected, self.preview,
                self.errors, self.sticks, self.points, self.selected, self.proj_conn,
                self.proj_unconn, self.rom, self.interp]

    def _set_notice(self, text: str | None) -> None:
        if not text:
            self.notice.hide()
            return
        self.notice.setText(f"No image: {text}")
        self.notice.setFixedWidth(max(self.gv.width() - 8, 120))
        self.notice.adjustSize()
        self.notice.move(4, max(self.gv.height() - self.notice.height() - 4, 24))
        self.notice.show()

    @property
    def image_frame(self) -> int | None:
        """Take frame of the image on screen (None while none, or while a newer
        frame's image is being decoded)."""
        return self._image_frame

    def _draw_overlays(self, frame: int) -> None:
        ctx, p, opts, c = self.ctx, self.ctx.project, self.ctx.options, self.camera
        pts = p.points
        # detections: red ellipse + cross
        det = p.detections.get(frame, c)
        n_det = len(det["centre"])
        if opts.detections and n_det:
            centre = det["centre"].astype(np.float64)
            axes = det["axes"].astype(np.float64)
            xy, conn = ellipse_polyline(centre, axes, det["angle"].astype(np.float64))
            self.det_ellipses.setData(xy[:, 0], xy[:, 1], connect=conn)
            cr = cross_segments(centre, np.maximum(axes[:, 1], 1.5) * 0.6)
            self.det_cross.setData(cr[:, 0], cr[:, 1], connect="pairs")
            self.det_ellipses.show()
            self.det_cross.show()
        else:
            self.det_ellipses.hide()
            self.det_cross.hide()
        sel_det = [k for (f, cc, k) in p.selection.detections if f == frame and cc == c
                   and k < n_det]
        if sel_det and n_det:
            k = np.asarray(sel_det)
            xy, conn = ellipse_polyline(det["centre"][k].astype(np.float64),
                                        det["axes"][k].astype(np.float64) + 2,
                                        det["angle"][k].astype(np.float64))
            self.det_selected.setData(xy[:, 0], xy[:, 1], connect=conn)
            self.det_selected.show()
        else:
            self.det_selected.hide()
        # blob preview
        self.preview.hide()
        if (opts.blob_preview and self._current_image is not None
                and self._image_frame == frame and not self._stretched):
            prev = ctx.blob_preview(frame, c, self._current_image)
            if prev is not None and len(prev.centre):
                xy, conn = ellipse_polyline(prev.centre.astype(np.float64),
                                            prev.axes.astype(np.float64) + 1.0,
                                            prev.angle.astype(np.float64))
                self.preview.setData(xy[:, 0], xy[:, 1], connect=conn)
                self.preview.show()
        # points (2D tracks) as blue rings
        P = pts.count
        obs = pts.obs[frame, :, c].astype(np.float64) if P and c < pts.n_cameras else \
            np.zeros((0, 2))
        valid = ~np.isnan(obs[:, 0]) if P else np.zeros(0, bool)
        if opts.points and valid.any():
            self.points.set_positions(obs[valid])
            self.points.show()
        else:
            self.points.hide()
        sel_cols = p.selected_columns()
        uv = ctx.projections(frame)
        proj = uv[:, c] if uv is not None and c < uv.shape[1] else None
        sel_xy = []
        if len(sel_cols):
            for col in sel_cols:
                if valid[col]:
                    sel_xy.append(obs[col])
                elif proj is not None and not np.isnan(proj[col, 0]):
                    sel_xy.append(proj[col])
        if sel_xy:
            self.selected.set_positions(np.array(sel_xy))
            self.selected.show()
        else:
            self.selected.hide()
        # projections and errors
        self.proj_conn.hide()
        self.proj_unconn.hide()
        self.errors.hide()
        if proj is not None and opts.projections:
            has = ~np.isnan(proj[:, 0])
            conn = has & valid
            unconn = has & ~valid
            if opts.connected and conn.any():
                self.proj_conn.set_positions(proj[conn])
                self.proj_conn.show()
            if opts.unconnected and unconn.any():
                self.proj_unconn.set_positions(proj[unconn])
                self.proj_unconn.show()
        if proj is not None and opts.errors:
            conn = ~np.isnan(proj[:, 0]) & valid
            if conn.any():
                seg = np.empty((int(conn.sum()), 2, 2))
                seg[:, 0], seg[:, 1] = proj[conn], obs[conn]
                seg = seg.reshape(-1, 2)
                self.errors.setData(seg[:, 0], seg[:, 1], connect="pairs")
                self.errors.show()
        # sticks between 2D positions (observation, else projection)
        self.sticks.hide()
        if opts.sticks and p.sticks and P:
            where = obs.copy()
            if proj is not None:
                miss = np.isnan(where[:, 0])
                where[miss] = proj[miss]
            segs = []
            id_to_col = {int(i): k for k, i in enumerate(pts.ids)}
            for s in p.sticks:
                a, b = id_to_col.get(s.a), id_to_col.get(s.b)
                if a is not None and b is not None:
                    segs.append((where[a], where[b]))
            if segs:
                seg = np.array(segs).reshape(-1, 2)
                ok = ~np.isnan(seg).any(axis=1).reshape(-1, 2).any(axis=1)
                seg = seg.reshape(-1, 2, 2)[ok].reshape(-1, 2)
                if len(seg):
                    self.sticks.setData(seg[:, 0], seg[:, 1], connect="pairs")
                    self.sticks.show()
        # interpolated samples (no camera measured them): crossed circles
        self.interp.hide()
        if proj is not None and opts.points and P:
            fill = (pts.recon[frame] == RECON_INTERPOLATED) & ~np.isnan(proj[:, 0])
            if fill.any():
                self.interp.set_positions(proj[fill])
                self.interp.show()
        # ROM points: the loaded ROM's frame projected through this frame's camera (the
        # Initialize from ROM troubleshooting compares them with the detections)
        rom_xy = rom_overlay(p, frame, c)
        if rom_xy is not None and len(rom_xy):
            self.rom.set_positions(rom_xy)
            self.rom.show()
        else:
            self.rom.hide()
        self.targets.draw(p, frame, c)
        # labels
        self._draw_labels(obs, valid, proj)

    def _draw_labels(self, obs: NDArray, valid: NDArray, proj: NDArray | None) -> None:
        cols = self.ctx.labelled_columns() if len(valid) else np.zeros(0, np.intp)
        p = self.ctx.project
        size = self.ctx.label_mode()[3]
        used = 0
        places: list[tuple[int, NDArray]] = []
        for col in cols:
            if valid[col]:
                places.append((int(col), obs[col]))
            elif proj is not None and not np.isnan(proj[col, 0]):
                places.append((int(col), proj[col]))
        keep = self._declutter(places, size)
        for col, xy in places:
            if col not in keep:
                continue
            if used >= len(self._labels):
                item = pg.TextItem(color=(255, 255, 255), anchor=(-0.15, 1.0))
                item.setParentItem(self.group)
                item.setZValue(8)
                self._labels.append(item)
            item = self._labels[used]
            item.setText(p.point_label(int(col)))
            font = item.textItem.font()
            if font.pointSize() != size:
                font.setPointSize(size)
                item.setFont(font)
            item.setPos(float(xy[0]), float(xy[1]))
            item.show()
            used += 1
        for item in self._labels[used:]:
            item.hide()

    def _declutter(self, places: list[tuple[int, NDArray]], size: int) -> set[int]:
        """Labels to draw (see `carapost.ui.views.overlays.declutter`)."""
        p = self.ctx.project

        def to_view(xy: NDArray) -> tuple[float, float]:
            at = self.gv.mapFromScene(self.group.mapToScene(QPointF(float(xy[0]),
                                                                      float(xy[1]))))
            return float(at.x()), float(at.y())

        vp = self.gv.viewport()
        return declutter(places, to_view, p.point_label,
                         {int(c) for c in p.selected_columns()}, size,
                         (vp.width(), vp.height()))

    # -- selection ---------------------------------------------------------------------------
    def _pickables(self) -> tuple[NDArray, NDArray]:
        """(point positions [P,2], detection centres [N,2]) in image px at this frame."""
        p = self.ctx.project
        f, c = p.current_frame, self.camera
        if p.n_points:
            xy = p.points.obs[f, :, c].astype(np.float64)
            uv = self.ctx.projections(f)
            if uv is not None:
                miss = np.isnan(xy[:, 0])
                xy[miss] = uv[miss, c]
        else:
            xy = np.zeros((0, 2))
        dets = p.detections.centres(f, c).astype(np.float64) if p.n_frames else np.zeros((0, 2))
        return xy, dets

    def pick(self, image_xy: tuple[float, float]) -> tuple[str, int] | None:
        """Nearest point (``("point", id)``) or detection (``("detection", k)``) in reach."""
        p = self.ctx.project
        props = p.properties
        reach = _PICK_PX / max(self.image_scale(), 1e-6)
        pts, dets = self._pickables()
        q = np.asarray(image_xy, np.float64)
        best: tuple[float, tuple[str, int]] | None = None
        if props["select_points"] and len(pts):
            d = np.hypot(*(pts - q).T)
            d[np.isnan(d)] = np.inf
            k = int(np.argmin(d))
            if d[k] <= reach:
                best = (float(d[k]) * 0.8, ("point", int(p.points.ids[k])))  # points win ties
        if props["select_detections"] and len(dets):
            d = np.hypot(*(dets - q).T)
            k = int(np.argmin(d))
            if d[k] <= reach and (best is None or d[k] < best[0]):
                best = (float(d[k]), ("detection", k))
        return None if best is None else best[1]

    def click(self, scene_pos: QPointF, mods, double: bool) -> None:
        """Click: select what is under the mouse (Ctrl toggles, Shift selects the sensor)."""
        p = self.ctx.project
        if getattr(self.ctx, "point_mode", ""):   # Add / Edit Target Track
            q = self.to_image(scene_pos)
            self.ctx.point_clicked.emit(self.camera, q.x(), q.y())
            return
        if mods & Qt.KeyboardModifier.ShiftModifier and not mods & Qt.KeyboardModifier.AltModifier:
            if p.properties["select_sensors"]:
                cams = set(p.selection.cameras)
                cams ^= {self.camera}
                p.set_selection(cameras=cams)
            return
        q = self.to_image(scene_pos)
        hit = self.pick((q.x(), q.y()))
        toggle = bool(mods & Qt.KeyboardModifier.ControlModifier)
        points = set(p.selection.points) if toggle else set()
        dets = set(p.selection.detections) if toggle else set()
        if hit is not None:
            kind, ident = hit
            if kind == "point":
                points ^= {ident}
            else:
                dets ^= {(p.current_frame, self.camera, ident)}
        p.set_selection(points=points, detections=dets)

    def _grab_size_handle(self, scene_pos: QPointF, image_pos: QPointF):
        """A white handle of a selected keyframe under the mouse: (point id, "pattern" or
        "search", the keyframe's position), or None."""
        p = self.ctx.project
        f = p.current_frame
        # the handles are drawn 6 screen px wide: grab them within about that
        reach = abs(self.to_image(scene_pos + QPointF(6.0, 0.0)).x() - image_pos.x())
        hit = self.targets.grab_handle(p, f, self.camera, (image_pos.x(), image_pos.y()),
                                       max(reach, 0.75))
        if hit is None:
            return None
        col = int(p.points.index_of([hit[0]])[0])
        return hit[0], hit[1], p.points.obs[f, col, self.camera].astype(float)

    def _drag_size(self, ev) -> None:
        """Dragging a handle: the pattern box or search cross grows or shrinks about the
        keyframe (drawn as it goes; one History entry on release)."""
        from carapost.ui.views.target_overlay import track_sizes

        p = self.ctx.project
        pid, kind, centre = self._size_drag
        q = self.to_image(ev.scenePos())
        size = 2.0 * max(abs(q.x() - centre[0]), abs(q.y() - centre[1]))
        col = int(p.points.index_of([pid])[0])
        pattern, search = (float(v[col]) for v in track_sizes(p, self.camera))
        if kind == "pattern":
            pattern = max(size, 5.0)
            search = max(search, pattern)
        else:
            search = max(size, 5.0)
            pattern = min(pattern, search)
        self.targets.draw(p, p.current_frame, self.camera, resized=(pid, pattern, search))
        if ev.isFinish():
            self._size_drag = None
            self.ctx.target_resized.emit(self.camera, pid, kind,
                                         pattern if kind == "pattern" else search)

    def select_in(self, inside_points: NDArray, inside_dets: NDArray, mods) -> None:
        """Select the points/detections flagged inside a rubber band or lasso."""
        p = self.ctx.project
        props = p.properties
        toggle = bool(mods & Qt.KeyboardModifier.ControlModifier)
        points = set(p.selection.points) if toggle else set()
        dets = set(p.selection.detections) if toggle else set()
        if props["select_points"]:
            points |= {int(i) for i in p.points.ids[inside_points]}
        if props["select_detections"]:
            f, c = p.current_frame, self.camera
            dets |= {(f, c, int(k)) for k in np.flatnonzero(inside_dets)}
        p.set_selection(points=points, detections=dets)

    def drag(self, ev, lasso: bool) -> None:
        """Rubber band, lasso or measurement drag; dragging a selected keyframe moves it
        (one History entry, on release)."""
        f, p = self.ctx.project.current_frame, self.ctx.project
        if ev.isStart():
            d = self.to_image(ev.buttonDownScenePos())
            self._size_drag = self._grab_size_handle(ev.buttonDownScenePos(), d)
            pid = (None if self._size_drag is not None
                   else self.targets.grab(p, f, self.camera, (d.x(), d.y())))
            self._key_drag = None if pid is None else (pid, d, p.points.obs[
                f, int(p.points.index_of([pid])[0]), self.camera].astype(float))
        if getattr(self, "_size_drag", None) is not None:
            self._drag_size(ev)
            return
        if getattr(self, "_key_drag", None) is not None:
            pid, d, orig = self._key_drag
            q = self.to_image(ev.scenePos())
            xy = (orig[0] + q.x() - d.x(), orig[1] + q.y() - d.y())
            self.targets.draw(p, f, self.camera, (pid, xy))
            if ev.isFinish():
                self._key_drag = None
                self.ctx.keyframe_moved.emit(self.camera, pid, *xy)
            return
        pos = self.vb.mapSceneToView(ev.scenePos())
        if ev.isStart():
            down = self.vb.mapSceneToView(ev.buttonDownScenePos())
            self._drag_origin = down
            self._lasso_pts = [(down.x(), down.y())]
        origin = self._drag_origin or pos
        if self.measuring:
            a, b = self.to_image(ev.buttonDownScenePos()), self.to_image(ev.scenePos())
            self._measure = (a, b)
            self.measure_line.setData([a.x(), b.x()], [a.y(), b.y()])
            self.measure_line.show()
            length = math.hypot(b.x() - a.x(), b.y() - a.y())
            self.report.setText(f"Length: {length:.1f} px")
            self.report.adjustSize()
            self.report.show()
            return
        if lasso:
            self._lasso_pts.append((pos.x(), pos.y()))
            path = QPainterPath(QPointF(*self._lasso_pts[0]))
            for x, y in self._lasso_pts[1:]:
                path.lineTo(x, y)
            path.closeSubpath()
            self.lasso.setPath(path)
            self.lasso.show()
        else:
            self.band.setRect(QRectF(origin, pos).normalized())
            self.band.show()
        if ev.isFinish():
            self.band.hide()
            self.lasso.hide()
            pts, dets = self._pickables()
            to_view = self.group.transform()

            def view_xy(a: NDArray) -> NDArray:
                if len(a) == 0:
                    return a.reshape(0, 2)
                m = np.array([[to_view.m11(), to_view.m12()], [to_view.m21(), to_view.m22()]])
                return a @ m + np.array([to_view.dx(), to_view.dy()])

            vp, vd = view_xy(pts), view_xy(dets)
            if lasso:
                poly = np.array(self._lasso_pts)
                in_p = points_in_polygon(vp, poly) if len(vp) else np.zeros(0, bool)
                in_d = points_in_polygon(vd, poly) if len(vd) else np.zeros(0, bool)
            else:
                r = QRectF(origin, pos).normalized()

                def inside(a: NDArray) -> NDArray:
                    if len(a) == 0:
                        return np.zeros(0, bool)
                    return ((a[:, 0] >= r.left()) & (a[:, 0] <= r.right())
                            & (a[:, 1] >= r.top()) & (a[:, 1] <= r.bottom()))

                in_p, in_d = inside(vp), inside(vd)
            self.select_in(in_p, in_d, ev.modifiers())

    def _mouse_moved(self, scene_pos: QPointF) -> None:
        if not self.ctx.options.pixel_report or self._image_shape is None:
            if not self.measuring:
                self.report.hide()
            return
        q = self.to_image(scene_pos)
        x, y = int(round(q.x())), int(round(q.y()))
        # grey levels are the original's (a proxy's pixels are averages)
        img = None if self._stretched else getattr(self, "_current_image", None)
        grey = ""
        if img is not None and 0 <= y < img.shape[0] and 0 <= x < img.shape[1]:
            grey = f"  grey {int(img[y, x])}"
        self.report.setText(f"x {q.x():.1f}  y {q.y():.1f}{grey}")
        self.report.adjustSize()
        self.report.show()

    # -- navigation --------------------------------------------------------------------------
    def center_selection(self, frame: bool = False) -> None:
        """Center / Frame Selection in this camera."""
        pts, _ = self._pickables()
        cols = self.ctx.project.selected_columns()
        if len(cols) == 0 or len(pts) == 0:
            return
        xy = pts[cols]
        xy = xy[~np.isnan(xy[:, 0])]
        if len(xy) == 0:
            return
        t = self.group.transform()
        mapped = [t.map(QPointF(float(x), float(y))) for x, y in xy]
        xs = [m.x() for m in mapped]
        ys = [m.y() for m in mapped]
        if frame:
            pad = 40.0
            rect = QRectF(min(xs) - pad, min(ys) - pad, max(xs) - min(xs) + 2 * pad,
                          max(ys) - min(ys) + 2 * pad)
            self.vb.setRange(rect, padding=0)
        else:
            cur = self.vb.viewRect()
            cx, cy = sum(xs) / len(xs), sum(ys) / len(ys)
            self.vb.setRange(QRectF(cx - cur.width() / 2, cy - cur.height() / 2,
                                    cur.width(), cur.height()), padding=0)

    def start_measurement(self) -> None:
        """Start Measurement: the next left drag draws a line and reports its length."""
        self.measuring = True
        self.refresh(None)

    def clear_measurement(self) -> None:
        """Clear Measurement."""
        self.measuring = False
        self._measure = None
        self.measure_line.hide()
        self.report.hide()
        self.refresh(None)

    def measurement_length(self) -> float | None:
        """Length (px) of the current measurement line."""
        if self._measure is None:
            return None
        a, b = self._measure
        return math.hypot(b.x() - a.x(), b.y() - a.y())

    def add_menu_items(self, menu: QMenu) -> None:
        menu.addAction("Fit To Window", self.fit)
        menu.addAction("Actual Size", self.actual_size)
        menu.addSeparator()
        menu.addAction("Start Measurement", self.start_measurement)
        menu.addAction("Clear Measurement", self.clear_measurement)
        menu.addAction("Center Selection", lambda: self.center_selection(False))
        menu.addAction("Frame Selection", lambda: self.center_selection(True))
        menu.addSeparator()
        self.add_option_items(menu, OPTION_TITLES_2D)

    def resizeEvent(self, ev) -> None:
        super().resizeEvent(ev)
        if not self._fitted and self.ctx.project.n_cameras:
            self.fit()
            self._fitted = True

    def set_pen_width(self, width: float) -> None:
        """Overlay line width (screenshots at high DPI)."""
        for item in (self.det_ellipses, self.det_cross, self.errors):
            item.setPen(QPen(item.opts["pen"].color(), width))
