"""The camera views' markers: a pyqtgraph scatter that is cheap to move and to draw.

Each camera view shows its points, selection, projections and interpolated samples as
`Scatter` items in pixel mode (markers of a fixed screen size); every frame moves them
and every paint draws them, four views at up to 60 frames/s, so what pyqtgraph does in
Python per call counts.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from numpy.typing import NDArray
from PySide6.QtCore import QRectF


class Scatter(pg.ScatterPlotItem):
    """A scatter that never takes clicks (picking is done by the view, vectorised) and
    computes its bounding rectangle once per change.

    Qt asks for an item's bounding rectangle four or more times per paint; pyqtgraph
    recomputes it each time (data bounds, then the pixel size through the device
    transform, in Python), which cost more than drawing the markers. Every change of
    data, style or view transform replaces ``self.bounds`` with a new list, so the
    rectangle computed for the current list is still right.
    """

    _rect_for: tuple[object, QRectF] | None = None

    def boundingRect(self) -> QRectF:
        cached = self._rect_for
        if cached is not None and cached[0] is self.bounds:
            return QRectF(cached[1])
        rect = super().boundingRect()
        self._rect_for = (self.bounds, QRectF(rect))
        return rect

    def set_positions(self, pos: NDArray) -> None:
        """``setData(pos=pos)`` for markers that all look alike, cheaply when their
        number is unchanged (the common case from one frame to the next).

        ``setData`` rebuilds the point table and looks every marker up in the symbol
        atlas in Python; with the same count and style only the coordinates change, so
        they are written into the table in place.
        """
        pos = np.asarray(pos, np.float64).reshape(-1, 2)
        data = self.data
        if len(pos) == 0 or data is None or len(data) != len(pos):
            self.setData(pos=pos)
            return
        data["x"] = pos[:, 0]
        data["y"] = pos[:, 1]
        self.prepareGeometryChange()
        self.informViewBoundsChanged()
        self.bounds = [None, None]
        self.invalidate()

    @pg.debug.warnOnException  # an exception raised in a paint takes Qt down
    def paint(self, painter, option, widget) -> None:
        """Draw the markers from pyqtgraph's symbol atlas, as pyqtgraph does in pixel
        mode, without its per-paint culling and wrappers.

        pyqtgraph computes which markers lie in view (the pixel size through the device
        transform, per-marker half sizes), maps the points with a general transform
        function and wraps the call in a profiler and an exception guard, all in Python:
        about three quarters of a camera view's marker drawing. Markers out of view are
        clipped by Qt at no cost worth that, so here the points are mapped to device
        pixels with the painter's affine transform in two vectorised lines and drawn
        as one pixmap-fragment batch. Anything else (export, no atlas, a composition
        mode) takes pyqtgraph's own path.
        """
        opts = self.opts
        data = self.data
        if (not opts["pxMode"] or not opts["useCache"] or self._exportOpts is not False
                or opts.get("compositionMode") is not None or data is None or len(data) == 0):
            super().paint(painter, option, widget)
            return
        atlas = self.fragmentAtlas
        dpr = atlas.devicePixelRatio()
        if widget is not None and widget.devicePixelRatioF() != dpr:
            super().paint(painter, option, widget)  # re-renders the atlas for the screen
            return
        t = painter.transform()
        x, y = data["x"], data["y"]
        frags_xy = np.empty((len(data), 2))
        frags_xy[:, 0] = t.m11() * x + t.m21() * y + t.dx()
        frags_xy[:, 1] = t.m12() * x + t.m22() * y + t.dy()
        np.clip(frags_xy, -2.0 ** 30, 2.0 ** 30, out=frags_xy)  # Qt crashes beyond
        painter.resetTransform()
        self._pixmapFragments.resize(len(data))
        frags = self._pixmapFragments.ndarray()
        frags[:, 0:2] = frags_xy
        rects = data["sourceRect"]  # the markers' places in the atlas
        for k, name in enumerate(("x", "y", "w", "h")):
            frags[:, 2 + k] = rects[name]
        frags[:, 6:10] = [1 / dpr, 1 / dpr, 0.0, 1.0]  # scale x, y, rotation, opacity
        painter.drawPixmapFragments(*self._pixmapFragments.drawargs(), atlas.pixmap)

    def mouseClickEvent(self, ev) -> None:
        ev.ignore()
