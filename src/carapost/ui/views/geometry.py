"""Vectorised drawing geometry of the camera views: ellipse outlines, crosses, lasso
containment, the interpolated-sample symbol and the display rotation."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from PySide6.QtCore import QPointF
from PySide6.QtGui import QPainterPath, QTransform

_ELLIPSE_SEGMENTS = 16


def ellipse_polyline(centre: NDArray, axes: NDArray, angle: NDArray,
                     segments: int = _ELLIPSE_SEGMENTS) -> tuple[NDArray, NDArray]:
    """Outline of N ellipses as one polyline with breaks.

    Parameters
    ----------
    centre : ndarray, shape (N, 2)
    axes : ndarray, shape (N, 2)
        Semi-axes (px), major first.
    angle : ndarray, shape (N,)
        Major-axis direction (radians).

    Returns
    -------
    xy : ndarray, shape (N * (segments + 1), 2)
    connect : ndarray of bool, shape (N * (segments + 1),)
        False at the last vertex of each ellipse (no line to the next one).
    """
    n = len(centre)
    t = np.linspace(0.0, 2 * np.pi, segments + 1)
    a = np.asarray(axes[:, 0], np.float64)[:, None]
    b = np.asarray(axes[:, 1], np.float64)[:, None]
    th = np.asarray(angle, np.float64)[:, None]
    ct, st = np.cos(th), np.sin(th)
    ex, ey = a * np.cos(t), b * np.sin(t)
    x = centre[:, 0:1] + ex * ct - ey * st
    y = centre[:, 1:2] + ex * st + ey * ct
    xy = np.stack([x, y], axis=-1).reshape(-1, 2)
    connect = np.ones((n, segments + 1), dtype=bool)
    connect[:, -1] = False
    return xy, connect.reshape(-1)


def cross_segments(centre: NDArray, size: NDArray | float) -> NDArray:
    """Two segments per centre (a '+'), as pairs of vertices, shape (4N, 2)."""
    n = len(centre)
    s = np.broadcast_to(np.asarray(size, np.float64), (n,))
    out = np.empty((n, 4, 2))
    out[:, 0] = centre - np.stack([s, 0 * s], -1)
    out[:, 1] = centre + np.stack([s, 0 * s], -1)
    out[:, 2] = centre - np.stack([0 * s, s], -1)
    out[:, 3] = centre + np.stack([0 * s, s], -1)
    return out.reshape(-1, 2)


def points_in_polygon(xy: NDArray, poly: NDArray) -> NDArray[np.bool_]:
    """Even-odd rule containment of points (N, 2) in a polygon (M, 2), vectorised."""
    x, y = xy[:, 0:1], xy[:, 1:2]
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        crosses = ((y0 > y) != (y1 > y)) & (x < (x1 - x0) * (y - y0) / (y1 - y0) + x0)
    return (crosses.sum(axis=1) % 2 == 1) & ~np.isnan(xy[:, 0])


def crossed_circle() -> QPainterPath:
    """The marker symbol of an interpolated sample: a unit circle with a cross in it."""
    path = QPainterPath()
    path.addEllipse(QPointF(0, 0), 0.5, 0.5)
    r = 0.5 / math.sqrt(2)
    path.moveTo(-r, -r)
    path.lineTo(r, r)
    path.moveTo(-r, r)
    path.lineTo(r, -r)
    return path


def rotation_transform(rotation: int, width: int, height: int) -> QTransform:
    """Image pixels -> displayed coordinates for a clockwise display rotation (deg)."""
    t = QTransform()
    r = rotation % 360
    if r == 90:
        t.translate(height, 0)
        t.rotate(90)
    elif r == 180:
        t.translate(width, height)
        t.rotate(180)
    elif r == 270:
        t.translate(0, width)
        t.rotate(270)
    return t
