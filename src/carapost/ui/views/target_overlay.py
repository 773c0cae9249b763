"""Target tracks drawn in a camera view: pattern box, search cross, handles, centres.

- A selected target track on a keyframe: the blue pattern box, the green search cross
  (the comparison region) with white handles at its ends and corners of the box, and a
  green circle at the centre.
- An unselected keyframe: the blue pattern box and a broken yellow circle at the centre.
- A target-tracked frame that is not a keyframe: a broken blue circle at the centre.

Sizes are the Target Tracker's pattern and search sizes (px, image coordinates), or the
sizes the artist gave that track by dragging its handles (``Project.target_sizes``).
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from numpy.typing import NDArray
from PySide6.QtCore import Qt

from carapost.algorithms.codes import SOURCE_KEYFRAME, SOURCE_TARGET
from carapost.algorithms.target_track import TargetTrackerParameters

__all__ = ["TargetOverlay", "box_segments", "circle_polyline", "cross_segments",
           "track_sizes"]

BLUE = (60, 140, 255)
GREEN = (40, 230, 60)
YELLOW = (255, 230, 0)
WHITE = (255, 255, 255)


def _half(centre: NDArray, size: float | NDArray) -> NDArray[np.float64]:
    """Half sizes, one per centre, shaped to scale (N, 1, 1, 1) segment arrays."""
    h = np.broadcast_to(np.asarray(size, dtype=np.float64) / 2.0, (len(centre),))
    return h[:, None, None, None]


def box_segments(centre: NDArray, size: float | NDArray) -> NDArray[np.float64]:
    """Segments (pairs of rows) of squares of side ``size`` (one value or one per
    centre) around each centre (N, 2)."""
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    seg = np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)   # (4, 2, 2)
    return (centre[:, None, None, :] + _half(centre, size) * seg[None]).reshape(-1, 2)


def cross_segments(centre: NDArray, size: float | NDArray) -> NDArray[np.float64]:
    """Segments of a plus-shaped cross spanning ``size`` (one value or one per centre)
    around each centre."""
    seg = np.array([[[-1.0, 0.0], [1.0, 0.0]], [[0.0, -1.0], [0.0, 1.0]]])
    return (centre[:, None, None, :] + _half(centre, size) * seg[None]).reshape(-1, 2)


def circle_polyline(centre: NDArray, radius: float | NDArray, n: int = 24
                    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Circles as one polyline with breaks (``connect`` array) for pyqtgraph."""
    a = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), (len(centre),))
    xy = (centre[:, None, :] + ring[None] * r[:, None, None]).reshape(-1, 2)
    conn = np.ones(len(xy), bool)
    conn[n::n + 1] = False
    return xy, conn


#: Handle offsets in units of half a size: the search cross's four ends, then the
#: pattern box's four corners.
_ENDS = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def track_sizes(project, camera: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pattern and search sizes (px) of every point's target track in ``camera``: the
    Target Tracker's defaults, or the sizes the artist set for that track."""
    d = TargetTrackerParameters()
    n = project.points.count
    pattern = np.full(n, float(d.pattern_size))
    search = np.full(n, float(d.search_size))
    own = [(pid, sz) for (pid, cam), sz in getattr(project, "target_sizes", {}).items()
           if cam == camera]
    if own:
        ids = project.points.ids
        order = np.argsort(ids)
        for pid, (sp, ss) in own:
            k = int(np.searchsorted(ids, pid, sorter=order))
            if k < n and ids[order[k]] == pid:
                pattern[order[k]], search[order[k]] = sp, ss
    return pattern, search


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
        # a run's tracked position not yet in the model (Update 2D View Every Frame):
        # apart from ``items``, so a redraw of the model's tracks leaves it alone
        self.live = _curve(BLUE, 1.5, dashed=True)
        for item in (*self.items, self.live):
            item.setParentItem(parent)
            item.setAcceptedMouseButtons(Qt.MouseButton.NoButton)
            item.setAcceptHoverEvents(False)
            item.hide()

    def show_live(self, xy: NDArray, pattern: NDArray) -> None:
        """Draw positions a running Target Tracker run has just tracked: (n, 2) raw px,
        with their pattern sizes (n,) px (a broken blue circle, as a tracked frame)."""
        if not len(xy):
            self.live.hide()
            return
        pts, conn = circle_polyline(np.asarray(xy, np.float64),
                                    np.asarray(pattern, np.float64) / 4.0)
        self.live.setData(pts[:, 0], pts[:, 1], connect=conn)
        self.live.show()

    def clear_live(self) -> None:
        """The run ended: its result is in the model and drawn from there."""
        self.live.hide()

    def _selected_keys(self, project, frame: int, camera: int
                       ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Columns and positions of the selected points' keyframes in ``camera`` (none
        for a frame or camera outside the project)."""
        pts = project.points
        cols = np.asarray(project.selected_columns(), dtype=np.intp)
        if (not len(cols) or not 0 <= frame < project.n_frames
                or camera >= pts.n_cameras):
            return cols[:0], np.zeros((0, 2))
        obs = pts.obs[frame, cols, camera].astype(np.float64)
        key = pts.keyframe[frame, cols, camera] & np.isfinite(obs[:, 0])
        return cols[key], obs[key]

    def grab(self, project, frame: int, camera: int, xy) -> int | None:
        """The id of the selected keyframe whose pattern box holds image point ``xy``."""
        cols, obs = self._selected_keys(project, frame, camera)
        if not len(cols):
            return None
        pts = project.points
        half = track_sizes(project, camera)[0][cols] / 2.0
        inside = (np.abs(obs - np.asarray(xy, float)) <= half[:, None]).all(axis=1)
        return int(pts.ids[cols[np.flatnonzero(inside)[0]]]) if inside.any() else None

    def grab_handle(self, project, frame: int, camera: int, xy, reach: float
                    ) -> tuple[int, str] | None:
        """The selected keyframe's white handle within ``reach`` (image px) of ``xy``:
        (point id, ``"search"`` for an end of the green cross or ``"pattern"`` for a
        corner of the blue box), or None."""
        cols, obs = self._selected_keys(project, frame, camera)
        if not len(cols):
            return None
        pts = project.points
        pattern, search = track_sizes(project, camera)
        q = np.asarray(xy, dtype=np.float64)
        best: tuple[float, int, str] | None = None
        for k, col in enumerate(cols):
            for kind, offsets, size in (("search", _ENDS, search[col]),
                                        ("pattern", _CORNERS, pattern[col])):
                d = np.hypot(*(obs[k] + offsets * size / 2.0 - q).T).min()
                if d <= reach and (best is None or d < best[0]):
                    best = (float(d), int(col), kind)
        return None if best is None else (int(pts.ids[best[1]]), best[2])

    def draw(self, project, frame: int, camera: int, moved=None, resized=None) -> None:
        """Draw the target tracks of ``camera`` at ``frame``; ``moved`` = (point id,
        (x, y)) draws that point's keyframe where it is being dragged to; ``resized`` =
        (point id, pattern px, search px) draws it with the sizes being dragged."""
        for item in self.items:
            item.hide()
        pts = project.points
        if not pts.count or not 0 <= frame < project.n_frames or camera >= pts.n_cameras:
            return
        src = pts.source[frame, :, camera]
        target = (src == SOURCE_KEYFRAME) | (src == SOURCE_TARGET)
        if not target.any():
            return
        size_p, size_s = track_sizes(project, camera)
        obs = pts.obs[frame, :, camera].astype(np.float64)
        if moved is not None:
            obs[int(pts.index_of([moved[0]])[0])] = moved[1]
        if resized is not None:
            k = int(pts.index_of([resized[0]])[0])
            size_p[k], size_s[k] = float(resized[1]), float(resized[2])
        key = target & pts.keyframe[frame, :, camera] & np.isfinite(obs[:, 0])
        tracked = target & ~key & np.isfinite(obs[:, 0])
        sel = np.zeros(pts.count, bool)
        sel[project.selected_columns()] = True
        r = size_p / 4.0
        if key.any():
            b = box_segments(obs[key], size_p[key])
            self.box.setData(b[:, 0], b[:, 1], connect="pairs")
            self.box.show()
        on = key & sel
        if on.any():
            c = cross_segments(obs[on], size_s[on])
            self.cross.setData(c[:, 0], c[:, 1], connect="pairs")
            xy, conn = circle_polyline(obs[on], r[on])
            self.centre.setData(xy[:, 0], xy[:, 1], connect=conn)
            ends = obs[on][:, None, :] + _ENDS[None] * (size_s[on] / 2.0)[:, None, None]
            corners = obs[on][:, None, :] + _CORNERS[None] * (size_p[on] / 2.0)[:, None, None]
            self.handles.setData(pos=np.concatenate([ends, corners], axis=1).reshape(-1, 2))
            for item in (self.cross, self.centre, self.handles):
                item.show()
        off = key & ~sel
        if off.any():
            xy, conn = circle_polyline(obs[off], r[off])
            self.key_centre.setData(xy[:, 0], xy[:, 1], connect=conn)
            self.key_centre.show()
        if tracked.any():
            xy, conn = circle_polyline(obs[tracked], r[tracked])
            self.tracked.setData(xy[:, 0], xy[:, 1], connect=conn)
            self.tracked.show()
