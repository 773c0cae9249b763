"""Target tracks drawn in a camera view: pattern box, search cross, handles, centres.

- A selected target track on a keyframe: the blue pattern box, the green search cross
  (the comparison region) with white handles at its ends and corners of the box, and a
  green circle at the centre.
- An unselected keyframe: the blue pattern box and a broken yellow circle at the centre.
- A target-tracked frame that is not a keyframe: a broken blue circle at the centre.

Sizes are the Target Tracker's pattern and search sizes (px, image coordinates).
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from numpy.typing import NDArray
from PySide6.QtCore import Qt

from carapost.algorithms.codes import SOURCE_KEYFRAME, SOURCE_TARGET
from carapost.algorithms.target_track import TargetTrackerParameters

__all__ = ["TargetOverlay", "box_segments", "circle_polyline", "cross_segments"]

BLUE = (60, 140, 255)
GREEN = (40, 230, 60)
YELLOW = (255, 230, 0)
WHITE = (255, 255, 255)


def box_segments(centre: NDArray, size: float) -> NDArray[np.float64]:
    """Segments (pairs of rows) of squares of side ``size`` around each centre (N, 2)."""
    h = size / 2.0
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    seg = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)   # (4, 2, 2)
    return (centre[:, None, None, :] + seg[None]).reshape(-1, 2)


def cross_segments(centre: NDArray, size: float) -> NDArray[np.float64]:
    """Segments of a plus-shaped cross spanning ``size`` around each centre."""
    h = size / 2.0
    seg = np.array([[[-h, 0], [h, 0]], [[0, -h], [0, h]]])
    return (centre[:, None, None, :] + seg[None]).reshape(-1, 2)


def circle_polyline(centre: NDArray, radius: float, n: int = 24
                    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Circles as one polyline with breaks (``connect`` array) for pyqtgraph."""
    a = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1) * radius
    xy = (centre[:, None, :] + ring[None]).reshape(-1, 2)
    conn = np.ones(len(xy), bool)
    conn[n::n + 1] = False
    return xy, conn


def _curve(colour: tuple[int, int, int], width: float, dashed: bool = False
           ) -> pg.PlotCurveItem:
    pen = pg.mkPen(colour, width=width)
    if dashed:
        pen.setStyle(Qt.PenStyle.DashLine)
    item = pg.PlotCurveItem(pen=pen, antialias=False)
    item.setZValue(7)
    return item


class TargetOverlay:
    """The target-track items of one camera view (children of ``parent``)."""

    def __init__(self, parent) -> None:
        self.box = _curve(BLUE, 1.5)
        self.cross = _curve(GREEN, 1.5)
        self.centre = _curve(GREEN, 1.5)
        self.key_centre = _curve(YELLOW, 1.0, dashed=True)
        self.tracked = _curve(BLUE, 1.5, dashed=True)
        self.handles = pg.ScatterPlotItem(pxMode=True, symbol="s", size=6,
                                          pen=pg.mkPen(WHITE), brush=pg.mkBrush(WHITE))
        self.handles.setZValue(8)
        self.items = (self.box, self.cross, self.centre, self.key_centre, self.tracked,
                      self.handles)
        for item in self.items:
            item.setParentItem(parent)
            item.setAcceptedMouseButtons(Qt.MouseButton.NoButton)
            item.setAcceptHoverEvents(False)
            item.hide()

    def grab(self, project, frame: int, camera: int, xy) -> int | None:
        """The id of the selected keyframe whose pattern box holds image point ``xy``."""
        pts = project.points
        if not pts.count or not 0 <= frame < project.n_frames or camera >= pts.n_cameras:
            return None
        cols = project.selected_columns()
        if not len(cols):
            return None
        obs = pts.obs[frame, cols, camera].astype(np.float64)
        key = pts.keyframe[frame, cols, camera] & np.isfinite(obs[:, 0])
        half = TargetTrackerParameters().pattern_size / 2.0
        inside = key & (np.abs(obs - np.asarray(xy, float)) <= half).all(axis=1)
        return int(pts.ids[cols[np.flatnonzero(inside)[0]]]) if inside.any() else None

    def draw(self, project, frame: int, camera: int, moved=None) -> None:
        """Draw the target tracks of ``camera`` at ``frame``; ``moved`` = (point id,
        (x, y)) draws that point's keyframe where it is being dragged to."""
        for item in self.items:
            item.hide()
        pts = project.points
        if not pts.count or not 0 <= frame < project.n_frames or camera >= pts.n_cameras:
            return
        src = pts.source[frame, :, camera]
        target = (src == SOURCE_KEYFRAME) | (src == SOURCE_TARGET)
        if not target.any():
            return
        try:
            params = TargetTrackerParameters()
            size_p, size_s = float(params.pattern_size), float(params.search_size)
        except ValueError:  # pragma: no cover - defaults are valid
            return
        obs = pts.obs[frame, :, camera].astype(np.float64)
        if moved is not None:
            obs[int(pts.index_of([moved[0]])[0])] = moved[1]
        key = target & pts.keyframe[frame, :, camera] & np.isfinite(obs[:, 0])
        tracked = target & ~key & np.isfinite(obs[:, 0])
        sel = np.zeros(pts.count, bool)
        sel[project.selected_columns()] = True
        r = size_p / 4.0
        if key.any():
            b = box_segments(obs[key], size_p)
            self.box.setData(b[:, 0], b[:, 1], connect="pairs")
            self.box.show()
        on = key & sel
        if on.any():
            c = cross_segments(obs[on], size_s)
            self.cross.setData(c[:, 0], c[:, 1], connect="pairs")
            xy, conn = circle_polyline(obs[on], r)
            self.centre.setData(xy[:, 0], xy[:, 1], connect=conn)
            h = size_s / 2.0
            ends = (obs[on][:, None, :] + np.array([[-h, 0], [h, 0], [0, -h], [0, h]])[None])
            hp = size_p / 2.0
            corners = obs[on][:, None, :] + np.array(
                [[-hp, -hp], [hp, -hp], [hp, hp], [-hp, hp]])[None]
            self.handles.setData(pos=np.concatenate([ends, corners], axis=1).reshape(-1, 2))
            for item in (self.cross, self.centre, self.handles):
                item.show()
        off = key & ~sel
        if off.any():
            xy, conn = circle_polyline(obs[off], r)
            self.key_centre.setData(xy[:, 0], xy[:, 1], connect=conn)
            self.key_centre.show()
        if tracked.any():
            xy, conn = circle_polyline(obs[tracked], r)
            self.tracked.setData(xy[:, 0], xy[:, 1], connect=conn)
            self.tracked.show()
