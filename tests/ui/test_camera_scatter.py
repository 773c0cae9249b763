"""The camera views' markers keep pyqtgraph's bounding rectangle exactly, computed once
per change of data, style or zoom instead of at every call."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtCore import QRectF

from carapost.ui.views.camera import _Scatter


def _reference(item: _Scatter) -> QRectF:
    item.bounds = [None, None]  # what pyqtgraph computes from scratch
    return pg.ScatterPlotItem.boundingRect(item)


def _same(a: QRectF, b: QRectF) -> bool:
    return all(x == pytest.approx(y, abs=1e-9) for x, y in
               ((a.left(), b.left()), (a.top(), b.top()), (a.width(), b.width()),
                (a.height(), b.height())))


def test_the_cached_rectangle_follows_data_style_and_zoom(qtbot):
    gv = pg.GraphicsView()
    qtbot.addWidget(gv)
    vb = pg.ViewBox(lockAspect=True, invertY=True)
    gv.setCentralItem(vb)
    item = _Scatter(pxMode=True, symbol="o", size=14, pen=pg.mkPen("b", width=2), brush=None)
    vb.addItem(item)
    gv.resize(400, 300)
    gv.show()
    qtbot.waitExposed(gv)
    rng = np.random.default_rng(1)
    item.setData(pos=rng.uniform(0, 1000, (20, 2)))
    vb.setRange(QRectF(0, 0, 1000, 800), padding=0)
    first = item.boundingRect()
    assert item.boundingRect() == first  # cached: same answer
    assert _same(first, _reference(item))
    item.setData(pos=rng.uniform(200, 400, (5, 2)))  # new data
    assert _same(item.boundingRect(), _reference(item))
    before = item.boundingRect()  # cached for this zoom
    vb.setRange(QRectF(0, 0, 100, 80), padding=0)  # zoomed in: less padding in data units
    qtbot.wait(10)
    zoomed = item.boundingRect()
    assert not _same(zoomed, before)  # the padding in data units changed
    assert _same(zoomed, _reference(item))
    item.boundingRect()
    item.setSize(40)  # a larger marker pads more
    larger = item.boundingRect()
    assert larger.width() > zoomed.width()
    assert _same(larger, _reference(item))


def test_moving_markers_in_place_draws_what_set_data_draws(qtbot):
    rng = np.random.default_rng(4)
    first, second = rng.uniform(20, 380, (12, 2)), rng.uniform(20, 380, (12, 2))
    grabs = []
    for moved in (False, True):
        gv = pg.GraphicsView()
        qtbot.addWidget(gv)
        vb = pg.ViewBox(lockAspect=True, invertY=True)
        gv.setCentralItem(vb)
        item = _Scatter(pxMode=True, symbol="+", size=9, pen=pg.mkPen("y", width=1.5),
                        brush=None)
        vb.addItem(item)
        gv.resize(300, 300)
        vb.setRange(QRectF(0, 0, 400, 400), padding=0)
        gv.show()
        qtbot.waitExposed(gv)
        if moved:
            item.set_positions(first)
            gv.grab()
            item.set_positions(second)  # same count: moved in place
        else:
            item.setData(pos=second)
        x, y = item.getData()
        np.testing.assert_array_equal(np.c_[x, y], second)
        assert _same(item.boundingRect(), _reference(item))
        grabs.append(gv.grab().toImage())
    assert grabs[0] == grabs[1]  # the same pixels
    item.set_positions(second[:5])  # another count: rebuilt
    assert len(item.getData()[0]) == 5
    item.set_positions(np.zeros((0, 2)))
    assert len(item.getData()[0]) == 0


@pytest.mark.parametrize("symbol, rotated", [("o", False), ("+", True)])
def test_the_lean_paint_draws_what_pyqtgraph_draws(qtbot, symbol, rotated):
    """Same pixels as pyqtgraph's own paint, markers partly out of view included, in a
    rotated and zoomed view."""
    from PySide6.QtGui import QTransform

    rng = np.random.default_rng(7)
    pos = rng.uniform(-60, 460, (40, 2))  # some beyond the view's edges
    grabs, drawn = [], []
    for cls in (pg.ScatterPlotItem, _Scatter):
        gv = pg.GraphicsView()
        qtbot.addWidget(gv)
        vb = pg.ViewBox(lockAspect=True, invertY=True)
        gv.setCentralItem(vb)
        group = pg.ItemGroup()
        vb.addItem(group)
        if rotated:  # a sensor's display rotation, as the camera view sets it
            group.setTransform(QTransform().translate(400, 0).rotate(90))
        item = cls(pxMode=True, symbol=symbol, size=12, pen=pg.mkPen("c", width=2),
                   brush=None)
        item.setParentItem(group)
        item.setData(pos=pos)
        gv.resize(320, 260)
        vb.setRange(QRectF(50, 40, 300, 240), padding=0)
        gv.show()
        qtbot.waitExposed(gv)
        image = gv.grab().toImage()
        grabs.append(image)
        drawn.append(sum(image.pixelColor(x, y).green() > 150 and
                         image.pixelColor(x, y).red() < 100
                         for x in range(0, image.width(), 2)
                         for y in range(0, image.height(), 2)))
    assert drawn[0] > 50  # markers were drawn at all
    assert grabs[0] == grabs[1]
