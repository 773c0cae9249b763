"""3D view drawn with QPainter through an orbit camera (works offscreen and under Xvfb).

OpenGL gets no context on Qt's offscreen platform, so the 3D view projects the scene
itself: a weak-perspective orbit camera (yaw, pitch, distance, target, pan) applied to
a few hundred points is a couple of small numpy products per repaint.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from PySide6.QtCore import QPoint, QPointF, Qt
from PySide6.QtGui import QColor, QFont, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QMenu

from carapost.algorithms.camera import camera_centres
from carapost.model.events import Change
from carapost.model.project import (
    KIND_BRIM,
    RECON_FILTERED,
    RECON_INTERPOLATED,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
)
from carapost.model.stabilization import (
    display_positions,
    has_processing,
    processed_transforms,
)
from carapost.ui.context import OPTION_TITLES_3D, ViewContext
from carapost.ui.views import BaseView
from carapost.ui.views.sigma_colours import draw_sigma_legend, sigma_rgb

RECON_COLOURS = {
    RECON_TRIANGULATED: QColor(255, 230, 0),  # matched detections: yellow
    RECON_SINGLE_SENSOR: QColor(255, 150, 0),  # one sensor / patch: orange
    RECON_INTERPOLATED: QColor(230, 40, 40),  # predicted / interpolated: red
    RECON_FILTERED: QColor(255, 240, 150),
}
BRIM_COLOUR = QColor(120, 220, 230)
ROM_COLOUR = QColor(160, 200, 255, 170)
CAMERA_COLOUR = QColor(200, 200, 200)


def orbit_rotation(yaw_deg: float, pitch_deg: float) -> NDArray[np.float64]:
    """World -> view rotation of the orbit camera (yaw about y, then pitch about x)."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    return rx @ ry


class View3D(BaseView):
    """The 3D view."""

    kind = "3d"

    def __init__(self, ctx: ViewContext, parent=None) -> None:
        super().__init__(ctx, parent)
        self.yaw, self.pitch = 0.0, 0.0
        self.target = np.zeros(3)
        self.scale = 2.0  # screen px per mm at the target
        self.pan = np.zeros(2)
        self.perspective = 600.0  # mm from the eye to the target
        self._press: QPoint | None = None
        self._last: QPoint | None = None
        self._moved = False
        self._screen: NDArray[np.float64] = np.zeros((0, 2))
        self._fitted = False
        self.setMinimumSize(100, 100)
        self.setMouseTracking(False)

    def title(self) -> str:
        return "3D"

    def refresh(self, change: Change | None) -> None:
        if (not self._fitted and self.ctx.project.n_points) or (
                change is not None and change.parts & {"file", "point_list"}):
            self.fit(selection=False)
            self._fitted = True
        if self.ctx.lock_to_point:
            self.center_selection(False)
        self.update()

    # -- camera ------------------------------------------------------------------------------
    def to_screen(self, X: NDArray) -> tuple[NDArray, NDArray]:
        """World points (N, 3) -> screen pixels (N, 2) and depth (N,) (larger = nearer)."""
        R = orbit_rotation(self.yaw, self.pitch)
        v = (np.asarray(X, np.float64) - self.target) @ R.T
        s = self.scale * self.perspective / np.maximum(self.perspective - v[:, 2], 1.0)
        cx, cy = self.width() / 2 + self.pan[0], self.height() / 2 + self.pan[1]
        xy = np.stack([cx + s * v[:, 0], cy - s * v[:, 1]], -1)
        return xy, v[:, 2]

    def _frame_points(self) -> tuple[NDArray, NDArray, NDArray]:
        p = self.ctx.project
        if p.n_frames == 0 or p.n_points == 0:
            return np.zeros((0, 3)), np.zeros(0, np.int8), np.zeros(0, bool)
        f = p.current_frame
        X = display_positions(p, f).astype(np.float64)  # raw, or Show Stabilized
        return X, p.points.recon[f], ~np.isnan(X[:, 0])

    def _camera_centres(self) -> NDArray:
        p = self.ctx.project
        cal = p.calibration
        if p.n_cameras == 0 or p.n_frames == 0 or not cal.solved.any():
            return np.zeros((0, 3))
        f = p.current_frame if cal.solved[p.current_frame] else int(np.flatnonzero(cal.solved)[0])
        centres = camera_centres(cal.R[f], cal.t[f])
        if p.show_stabilized and has_processing(p):  # the cameras move with the helmet
            T = processed_transforms(p, p.current_frame, p.current_frame)[0]
            centres = centres @ T[:3, :3].T + T[:3, 3]
        return centres

    def fit(self, selection: bool = True) -> None:
        """Fit to Points: the selected points, or every point when none is selected."""
        X, _, present = self._frame_points()
        cols = self.ctx.project.selected_columns() if selection else []
        use = present.copy()
        if len(cols) and present[cols].any():
            use[:] = False
            use[cols] = present[cols]
        if not use.any():
            cams = self._camera_centres()
            if len(cams) == 0:
                self.update()
                return
            pts = cams
        else:
            pts = X[use]
        lo, hi = pts.min(0), pts.max(0)
        self.target = (lo + hi) / 2
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 10.0)
        self.scale = 0.42 * min(max(self.width(), 100), max(self.height(), 100)) / radius
        self.pan[:] = 0
        self.update()

    def center_selection(self, frame: bool = False) -> None:
        X, _, present = self._frame_points()
        cols = self.ctx.project.selected_columns()
        if not len(cols) or not present[cols].any():
            return
        if frame:
            self.fit()
            return
        self.target = X[cols][present[cols]].mean(0)
        self.pan[:] = 0
        self.update()

    # -- painting ----------------------------------------------------------------------------
    def paintEvent(self, ev) -> None:
        painter = QPainter(self)
        painter.setRenderHint(QPainter.RenderHint.Antialiasing, True)
        painter.fillRect(self.rect(), QColor(25, 25, 30))
        try:
            self._paint(painter)
        finally:
            painter.end()

    def _paint(self, painter: QPainter) -> None:
        ctx, p, opts = self.ctx, self.ctx.project, self.ctx.options
        X, recon, present = self._frame_points()
        xy, depth = self.to_screen(X) if len(X) else (np.zeros((0, 2)), np.zeros(0))
        self._screen = np.where(present[:, None], xy, np.nan) if len(X) else xy
        kind = p.points.kind
        sel_cols = set(int(c) for c in p.selected_columns())
        self._draw_axes(painter)
        # cameras
        cams = self._camera_centres()
        if opts.cameras and len(cams):
            self._draw_cameras(painter, cams)
        # rays of the selected points to every camera that sees them
        if opts.rays and len(cams) and sel_cols:
            painter.setPen(QPen(QColor(255, 255, 255, 90), 1))
            f = p.current_frame
            cam_xy, _ = self.to_screen(cams)
            for col in sel_cols:
                if not present[col]:
                    continue
                seen = ~np.isnan(p.points.obs[f, col, :, 0])
                for c in np.flatnonzero(seen):
                    if c < len(cam_xy):
                        painter.drawLine(QPointF(*cam_xy[c]), QPointF(*xy[col]))
        # sticks
        if opts.sticks and p.sticks and len(X):
            id_to_col = {int(i): k for k, i in enumerate(p.points.ids)}
            for s in p.sticks:
                a, b = id_to_col.get(s.a), id_to_col.get(s.b)
                if a is None or b is None or not (present[a] and present[b]):
                    continue
                painter.setPen(QPen(QColor(*s.colour), 1.5))
                painter.drawLine(QPointF(*xy[a]), QPointF(*xy[b]))
        # ROM points
        if opts.rom and p.rom is not None and getattr(p.rom, "project", None) is not None:
            rp = p.rom.project
            fi = int(min(max(p.properties.get("rom_frame_index", 0), 0), rp.n_frames - 1))
            R = rp.points.positions[fi].astype(np.float64)
            R = R[~np.isnan(R[:, 0])]
            if len(R):
                rxy, _ = self.to_screen(R)
                self._dots(painter, rxy, ROM_COLOUR, 4)
        # points, far to near by colour group
        if len(X):
            face = present & (kind != KIND_BRIM)
            brim = present & (kind == KIND_BRIM)
            if opts.brim_points and brim.any():
                self._dots(painter, xy[brim], BRIM_COLOUR, 6)
            if opts.face_points and face.any():
                if opts.uncertainty:
                    self._draw_sigma(painter, xy, face)
                elif opts.recon_colours:
                    for code, colour in RECON_COLOURS.items():
                        m = face & (recon == code)
                        if m.any():
                            self._dots(painter, xy[m], colour, 7)
                    other = face & ~np.isin(recon, list(RECON_COLOURS))
                    if other.any():
                        self._dots(painter, xy[other], RECON_COLOURS[RECON_TRIANGULATED], 7)
                else:
                    self._dots(painter, xy[face], RECON_COLOURS[RECON_TRIANGULATED], 7)
            painter.setPen(QPen(QColor(255, 255, 255), 2))
            painter.setBrush(Qt.BrushStyle.NoBrush)
            for col in sel_cols:
                if present[col]:
                    painter.drawEllipse(QPointF(*xy[col]), 7, 7)
            # labels
            cols = ctx.labelled_columns()
            size = ctx.label_mode()[3]
            painter.setPen(QColor(255, 255, 255))
            painter.setFont(QFont(painter.font().family(), size))
            for col in cols:
                if present[col]:
                    painter.drawText(QPointF(xy[col, 0] + 6, xy[col, 1] - 6),
                                     p.point_label(int(col)))
        painter.setPen(QColor(200, 200, 200))
        painter.setFont(QFont(painter.font().family(), 9))
        n_present = int(present.sum()) if len(X) else 0
        painter.drawText(8, self.height() - 8,
                         f"frame {p.current_frame}   {n_present} of {p.n_points} points")

    def _draw_sigma(self, painter: QPainter, xy: NDArray, face: NDArray) -> None:
        """Face points coloured by their sample's sigma, a 2-sigma disc where it is larger
        than the dot, the selected points' sigma beside them, and the colour bar."""
        p = self.ctx.project
        f = p.current_frame
        sig = p.points.arrays["sigma"][f].astype(np.float64)
        rgb = sigma_rgb(sig)
        radius = 2.0 * np.nan_to_num(sig) * self.scale  # px, at the target's depth
        painter.setPen(Qt.PenStyle.NoPen)
        for col in np.flatnonzero(face & (radius > 3.5)):
            painter.setBrush(QColor(*(int(v) for v in rgb[col]), 60))
            painter.drawEllipse(QPointF(*xy[col]), radius[col], radius[col])
        painter.setBrush(Qt.BrushStyle.NoBrush)
        cols = np.flatnonzero(face)
        for key in np.unique(rgb[cols], axis=0):
            m = cols[(rgb[cols] == key).all(-1)]
            self._dots(painter, xy[m], QColor(*(int(v) for v in key)), 7)
        painter.setPen(QColor(230, 230, 230))
        painter.setFont(QFont(painter.font().family(), 9))
        for col in p.selected_columns():
            if face[col]:
                text = f"{sig[col]:.3f} mm" if np.isfinite(sig[col]) else "sigma unknown"
                painter.drawText(QPointF(xy[col, 0] + 8, xy[col, 1] + 14), text)
        draw_sigma_legend(painter, self.width() - 10.0, 8.0)

    def _dots(self, painter: QPainter, xy: NDArray, colour: QColor, size: float) -> None:
        pen = QPen(colour, size)
        pen.setCapStyle(Qt.PenCapStyle.RoundCap)
        painter.setPen(pen)
        painter.drawPoints(QPolygonF([QPointF(float(x), float(y)) for x, y in xy]))

    def _draw_axes(self, painter: QPainter) -> None:
        o = np.zeros((1, 3))
        axes = np.eye(3) * 20.0
        oxy, _ = self.to_screen(o)
        axy, _ = self.to_screen(axes)
        for k, colour in enumerate((QColor(220, 60, 60), QColor(60, 200, 60),
                                    QColor(80, 120, 255))):
            painter.setPen(QPen(colour, 1.5))
            painter.drawLine(QPointF(*oxy[0]), QPointF(*axy[k]))

    def _draw_cameras(self, painter: QPainter, cams: NDArray) -> None:
        p = self.ctx.project
        cal = p.calibration
        f = p.current_frame
        painter.setPen(QPen(CAMERA_COLOUR, 1))
        for c, centre in enumerate(cams):
            R = cal.R[f, c]
            # a small frustum: 4 corners 20 mm in front of the camera
            corners = np.array([[-1, -0.6, 2], [1, -0.6, 2], [1, 0.6, 2], [-1, 0.6, 2]]) * 10.0
            world = centre + corners @ R  # R.T @ corner for each row
            pts, _ = self.to_screen(np.vstack([centre, world]))
            for k in range(4):
                painter.drawLine(QPointF(*pts[0]), QPointF(*pts[k + 1]))
                painter.drawLine(QPointF(*pts[k + 1]), QPointF(*pts[(k + 1) % 4 + 1]))
            painter.drawText(QPointF(*pts[0]) + QPointF(4, -4), f"{c}")

    # -- interaction -------------------------------------------------------------------------
    def mousePressEvent(self, ev) -> None:
        self.activated.emit()
        self._press = ev.position().toPoint()
        self._last = self._press
        self._moved = False

    def mouseMoveEvent(self, ev) -> None:
        if self._last is None:
            return
        pos = ev.position().toPoint()
        d = pos - self._last
        if (pos - self._press).manhattanLength() > 3:
            self._moved = True
        self._last = pos
        buttons = ev.buttons()
        if buttons & Qt.MouseButton.MiddleButton or (
                buttons & Qt.MouseButton.LeftButton and buttons & Qt.MouseButton.RightButton):
            self.pan += (d.x(), d.y())
        elif buttons & Qt.MouseButton.RightButton:
            self.scale *= math.exp(-0.01 * d.y())
        elif buttons & Qt.MouseButton.LeftButton:
            self.yaw += 0.5 * d.x()
            self.pitch = float(np.clip(self.pitch + 0.5 * d.y(), -89, 89))
        self.update()

    def mouseReleaseEvent(self, ev) -> None:
        if not self._moved:
            if ev.button() == Qt.MouseButton.RightButton:
                self.menu_requested.emit(ev.globalPosition().toPoint())
            elif ev.button() == Qt.MouseButton.LeftButton:
                self.click(ev.position(), ev.modifiers())
        self._last = None

    def wheelEvent(self, ev) -> None:
        self.scale *= math.exp(ev.angleDelta().y() / 600.0)
        self.update()

    def click(self, pos: QPointF, mods) -> None:
        """Select the nearest point on screen (Ctrl toggles)."""
        p = self.ctx.project
        toggle = bool(mods & Qt.KeyboardModifier.ControlModifier)
        points = set(p.selection.points) if toggle else set()
        if len(self._screen) and p.properties["select_points"]:
            d = np.hypot(self._screen[:, 0] - pos.x(), self._screen[:, 1] - pos.y())
            d[np.isnan(d)] = np.inf
            k = int(np.argmin(d))
            if d[k] < 10:
                points ^= {int(p.points.ids[k])}
        p.set_selection(points=points)

    def add_menu_items(self, menu: QMenu) -> None:
        menu.addAction("Fit to Points", self.fit)
        menu.addAction("Center Selection", lambda: self.center_selection(False))
        menu.addAction("Frame Selection", lambda: self.center_selection(True))
        menu.addSeparator()
        self.add_option_items(menu, OPTION_TITLES_3D)
