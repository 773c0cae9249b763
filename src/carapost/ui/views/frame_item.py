"""The camera image item: a gray frame drawn at the least cost per frame.

Qt paints a scaled 8-bit gray (or indexed) image by converting it pixel by pixel
inside the paint; a 32-bit RGB image it scales directly. Converting the frame once
with OpenCV (which releases the GIL) and painting that is about three times cheaper
than painting the gray image: 0.17 ms + 0.23 ms instead of 1.27 ms for 1280x720 into a
quarter of a 1920x1080 window (2.12 ms with pyqtgraph's indexed path for levels);
docs/benchmarks.md "Playback and GUI responsiveness". At 60 frames/s and four views
that is ~3.5 ms of the 16.7 ms the GUI thread has per frame.
"""

from __future__ import annotations

import cv2
import numpy as np
import pyqtgraph as pg
from PySide6.QtGui import QImage


class GrayImageItem(pg.ImageItem):
    """`pg.ImageItem` that draws 2-D uint8 images through a 32-bit RGB copy.

    ``image`` stays the gray array that was set (levels and lookup tables are not
    used for it: the camera views show the pixels as they are). Any other image goes
    through pyqtgraph's own rendering.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._rgb32: np.ndarray | None = None

    def render(self) -> None:
        img = self.image
        if (img is None or img.ndim != 2 or img.dtype != np.uint8 or self.levels is not None
                or self.lut is not None or self.axisOrder != "row-major" or self.autoDownsample):
            self._rgb32 = None
            super().render()
            return
        h, w = img.shape
        buf = self._rgb32
        if buf is None or buf.shape[:2] != (h, w):
            buf = self._rgb32 = np.empty((h, w, 4), np.uint8)
        # gray -> B=G=R, alpha 255: the byte order of QImage.Format_RGB32 (0xffRRGGBB)
        cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_GRAY2BGRA, dst=buf)
        self.qimage = QImage(buf.data, w, h, buf.strides[0], QImage.Format.Format_RGB32)
        self._renderRequired = False
        self._unrenderable = False
