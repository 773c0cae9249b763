"""Colours and legend of the 3D view's Uncertainty option.

With Uncertainty on, each face point of the current frame is drawn in the colour of its
sample's sigma (the estimated 3D error, mm): blue for a well-determined sample through
green and yellow to red at `SIGMA_FULL_SCALE_MM` and above; grey where the sigma is
unknown (single-sensor, interpolated or edited samples). Zoomed in far enough that
``2 sigma`` is larger than the dot, a translucent disc of that radius is drawn too, so
the size of the doubt can be read against the face.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QLinearGradient, QPainter, QPen

__all__ = ["SIGMA_FULL_SCALE_MM", "UNKNOWN_COLOUR", "draw_sigma_legend", "sigma_rgb"]

#: Sigma (mm) drawn in the ramp's last colour: half a millimetre, the error beyond which
#: a facial sample is visibly wrong on a retargeted face.
SIGMA_FULL_SCALE_MM = 0.5
UNKNOWN_COLOUR = QColor(140, 140, 140)

# Ramp stops (fraction of full scale -> RGB): blue, green, yellow, red.
_STOPS = np.array([0.0, 0.33, 0.66, 1.0])
_RGB = np.array([[60, 120, 255], [40, 210, 90], [250, 220, 40], [235, 40, 40]], float)


def sigma_rgb(sigma_mm: NDArray) -> NDArray[np.uint8]:
    """RGB (N, 3) of each sigma (N,) on the ramp; NaN gives the unknown grey.

    >>> sigma_rgb(np.array([0.0, 0.5, 2.0, np.nan])).tolist()
    [[60, 120, 255], [235, 40, 40], [235, 40, 40], [140, 140, 140]]
    """
    s = np.asarray(sigma_mm, dtype=np.float64)
    x = np.clip(np.nan_to_num(s, nan=0.0) / SIGMA_FULL_SCALE_MM, 0.0, 1.0)
    rgb = np.stack([np.interp(x, _STOPS, _RGB[:, k]) for k in range(3)], -1)
    rgb[~np.isfinite(s)] = (UNKNOWN_COLOUR.red(), UNKNOWN_COLOUR.green(), UNKNOWN_COLOUR.blue())
    return np.rint(rgb).astype(np.uint8)


def draw_sigma_legend(painter: QPainter, right: float, top: float) -> None:
    """A colour bar with its range above it, its upper right corner at (right, top) px
    (the frame text of the views is at the bottom left)."""
    w, h = 120.0, 10.0
    rect = QRectF(right - w, top + painter.fontMetrics().height() + 2, w, h)
    grad = QLinearGradient(rect.left(), 0, rect.right(), 0)
    for stop, rgb in zip(_STOPS, _RGB, strict=True):
        grad.setColorAt(float(stop), QColor(*(int(v) for v in rgb)))
    painter.setPen(Qt.PenStyle.NoPen)
    painter.setBrush(grad)
    painter.drawRect(rect)
    painter.setBrush(Qt.BrushStyle.NoBrush)
    painter.setPen(QPen(QColor(200, 200, 200)))
    painter.drawText(QPointF(rect.left(), rect.top() - 4), "sigma 0")
    label = f"{SIGMA_FULL_SCALE_MM:g} mm"
    painter.drawText(QPointF(rect.right() - painter.fontMetrics().horizontalAdvance(label),
                             rect.top() - 4), label)
