"""Pure drawing helpers: continuity codes and binning, ellipses, lasso, rotation."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from carapost.model.project import (
    KIND_BRIM,
    RECON_INTERPOLATED,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    SOURCE_PATCH,
    SOURCE_TARGET,
    new_project,
)
from carapost.ui.views import continuity as cont
from carapost.ui.views.camera import (
    cross_segments,
    ellipse_polyline,
    points_in_polygon,
    rotation_transform,
)


def test_point_codes_count_contributing_cameras():
    p = new_project(6, 4)
    p.points.append(2)
    pts = p.points
    pts.positions[:, :] = 1.0
    pts.recon[:] = RECON_TRIANGULATED
    for f, n in enumerate([4, 3, 2, 1, 0]):
        pts.obs[f, 0, :n] = 5.0
        pts.source[f, 0, :n] = SOURCE_BLOB
    pts.recon[4, 0] = RECON_INTERPOLATED
    pts.positions[5, 0] = np.nan
    # a source without an observation does not count; a 5th camera would cap at CAM4
    pts.source[:, 1, :] = SOURCE_BLOB
    codes = cont.point_codes(p)
    assert codes.shape == (2, 6)
    assert codes[0].tolist() == [cont.CAM4, cont.CAM3, cont.CAM2, cont.CAM1,
                                 cont.INTERPOLATED, cont.GAP]
    assert (codes[1] == cont.INTERPOLATED).all()
    assert cont.point_codes(p, (1, 2))[0].tolist() == [cont.CAM3, cont.CAM2]


def test_point_codes_of_brim_dots_and_of_a_column_subset():
    """Brim dots are BRIM wherever they have 3D, whatever their 2D; a subset of columns
    (brim and face mixed, in any order) gives the rows of the full chart."""
    p = new_project(3, 2)
    p.points.append(1)
    p.points.append(1, kind=KIND_BRIM)
    p.points.append(1)
    pts = p.points
    pts.positions[:, :] = 1.0
    pts.recon[:] = RECON_TRIANGULATED
    pts.obs[:, :, 0] = 5.0
    pts.source[:, :, 0] = SOURCE_BLOB
    pts.obs[1, 2, 1] = 5.0
    pts.source[1, 2, 1] = SOURCE_BLOB
    pts.positions[2, 1] = np.nan
    full = cont.point_codes(p)
    assert full[1].tolist() == [cont.BRIM, cont.BRIM, cont.GAP]
    assert full[2].tolist() == [cont.CAM1, cont.CAM2, cont.CAM1]
    sub = cont.point_codes(p, (1, 2), np.array([2, 1]))
    assert np.array_equal(sub, full[[2, 1], 1:3])


def test_camera_codes_sources_and_quality():
    p = new_project(4, 2)
    p.points.append(1)
    pts = p.points
    pts.obs[:, 0, :] = 1.0
    pts.source[:, 0, 0] = [SOURCE_BLOB, SOURCE_PATCH, SOURCE_TARGET, SOURCE_TARGET]
    pts.quality[:, 0, 0] = [1, 1, 1.0, 0.0]
    pts.keyframe[0, 0, 1] = True
    pts.source[:, 0, 1] = SOURCE_BLOB
    pts.obs[3, 0, 1] = np.nan
    codes = cont.camera_codes(p, 0)
    assert codes[0].tolist() == [cont.BLOB, cont.PATCH, cont.TARGET0 + cont.N_QUALITY - 1,
                                 cont.TARGET0]
    assert codes[1].tolist() == [cont.KEYFRAME, cont.BLOB, cont.BLOB, cont.NONE2D]
    # a good target track is greener than a poor one
    good, poor = cont.LUT[codes[0, 2]], cont.LUT[codes[0, 3]]
    assert good[1] > poor[1] and good[0] < poor[0]


def test_bin_min_keeps_single_frame_gaps():
    rng = np.random.default_rng(0)
    codes = rng.integers(2, 6, size=(3, 36000)).astype(np.uint8)
    codes[1, 12345] = cont.GAP
    out = cont.bin_min(codes, 0, 36000, 1000)
    assert out.shape == (3, 1000)
    assert out[1].min() == cont.GAP and out[0].min() >= 2
    assert out[1, 12345 * 1000 // 36000] == cont.GAP
    small = cont.bin_min(codes, 10, 20, 1000)
    assert np.array_equal(small, codes[:, 10:20])


def test_ellipse_polyline_lies_on_the_ellipses():
    centre = np.array([[10.0, 20.0], [50.0, 60.0]])
    axes = np.array([[5.0, 2.0], [3.0, 3.0]])
    angle = np.array([0.3, 0.0])
    xy, connect = ellipse_polyline(centre, axes, angle, segments=16)
    assert xy.shape == (34, 2) and connect.sum() == 32 and not connect[16]
    d = xy[:17] - centre[0]
    c, s = np.cos(-0.3), np.sin(-0.3)
    u, v = d[:, 0] * c - d[:, 1] * s, d[:, 0] * s + d[:, 1] * c
    assert np.allclose((u / 5) ** 2 + (v / 2) ** 2, 1)
    assert np.allclose(np.hypot(*(xy[17:] - centre[1]).T), 3)
    seg = cross_segments(centre, 2.0)
    assert seg.shape == (8, 2) and np.allclose(seg[0], [8, 20])


def test_points_in_polygon_and_nan():
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    pts = np.array([[5, 5], [15, 5], [-1, -1], [9.9, 0.1], [np.nan, 3]])
    assert points_in_polygon(pts, square).tolist() == [True, False, False, True, False]


@pytest.mark.parametrize("rot,corner", [(0, (0, 0)), (90, (720, 0)), (180, (1280, 720)),
                                        (270, (0, 1280))])
def test_rotation_transform_is_clockwise(rot, corner):
    from PySide6.QtCore import QPointF

    t = rotation_transform(rot, 1280, 720)
    m = t.map(QPointF(0, 0))
    assert (m.x(), m.y()) == pytest.approx(corner)


def test_pyside_refcount_workaround_applied():
    import PySide6

    import carapost.ui  # noqa: F401  (applies it)

    affected = sys.version_info < (3, 12) and PySide6.__version__.startswith("6.12.")
    if not affected:
        pytest.skip("this PySide6/Python pair does not need the workaround")
    assert sys.getrefcount(None) > 2**39 and sys.getrefcount(True) > 2**39
