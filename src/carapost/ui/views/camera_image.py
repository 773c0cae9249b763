"""How a camera view draws its camera's image: the original, or while playing a
(smaller) playback proxy stretched over the original's pixels.

`CameraImageMixin` is part of `carapost.ui.views.camera.CameraView`. It tells the frame
source how large the view shows the image (`FrameSource.set_view_scale`), so a view
zoomed in beyond Actual Size gets the original while playing, and draws what the source
has without waiting for a decoder.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from PySide6.QtCore import QRectF

if TYPE_CHECKING:
    from carapost.ui.context import ViewContext


def _forget_view(ctx: ViewContext, key: int):
    """A slot for a view's ``destroyed``: its zoom no longer counts (the view object is
    gone by then, so the slot holds only the context and the key)."""

    def forget() -> None:
        try:
            for camera in range(ctx.project.n_cameras):
                ctx.frames.set_view_scale(camera, None, key)
        except RuntimeError:  # the context is gone too (window closing)
            pass

    return forget


class CameraImageMixin:
    """The image drawing of a camera view (see the module docstring)."""

    ctx: Any
    camera: int
    image: Any
    vb: Any
    border: Any

    def _init_image_scale(self) -> None:
        self._item_scaled = False  # the image item carries a proxy's stretch
        self._scale = 0.0
        self._told: tuple[int, int, float] | None = None  # (source, camera, scale) told
        self.vb.sigTransformChanged.connect(self._zoomed)
        self.destroyed.connect(_forget_view(self.ctx, id(self)))  # type: ignore[attr-defined]

    def _zoomed(self, *_: object) -> None:
        self._scale = self.image_scale()
        self._tell_scale()

    def _tell_scale(self) -> None:
        """Tell the frame source how large this view shows its camera's images (once
        per change of zoom, camera or source): zoomed in beyond Actual Size, playback
        shows the original."""
        src = self.ctx.frames
        told = (id(src), self.camera, round(self._scale, 3))
        if told != self._told:
            if self._told is not None and self._told[:2] != told[:2]:
                src.set_view_scale(self._told[1], None, id(self))
            src.set_view_scale(self.camera, self._scale, id(self))
            self._told = told

    def _draw_image(self, frame: int) -> None:
        opts = self.ctx.options
        img = None
        note = None
        proxy = False
        if opts.image:
            src = self.ctx.frames
            self._tell_scale()
            img, proxy = src.display(frame, self.camera)
            if src.asynchronous:
                note = src.message(frame, self.camera)
            if img is None and src.asynchronous:
                # Decoded on the frame service's threads: keep the previous image until
                # ``frame_ready`` brings this one (the GUI never waits for a decoder).
                src.request(frame, self.camera)
                # a decoder reading ahead may have cached it between the two calls,
                # and then no signal follows: look once more
                img, proxy = src.display(frame, self.camera)
            if img is None and src.asynchronous:
                if note is None and self._current_image is not None:
                    self._image_frame = None
                    self._set_notice(None)
                    return
            elif img is None:
                img = src.image(frame, self.camera)
        if img is None:
            self.image.hide()
        else:
            # No levels: a uint8 image becomes a Grayscale8 QImage over the array itself,
            # which Qt scales cheapest. Levels (even 0-255) make pyqtgraph build a
            # 256-colour table in Python and paint an indexed image, every frame: 4x
            # the cost (0.16 against 0.04 ms for 1280x720 into 700x394, measured with a
            # new image per frame; an RGB32 copy costs more than it saves).
            self.image.setImage(img, autoLevels=False,
                                levels=None if img.dtype == np.uint8 else (0, 255))
            if proxy:
                # a playback proxy (smaller than the original): stretched over the
                # original's pixels, so the overlays and image coordinates stay put
                width, height = self.image_size()
                self.image.setRect(QRectF(0, 0, width, height))
                self._item_scaled = True
            else:
                self._image_shape = img.shape[:2]
                if self._item_scaled:
                    self.image.resetTransform()
                    self._item_scaled = False
            self.image.show()
        self.border.setVisible(opts.border or img is None)
        self._current_image = img
        self._stretched = proxy and img is not None
        self._image_frame = frame if img is not None and note is None else None
        self._set_notice(note)

    @property
    def showing_proxy(self) -> bool:
        """Whether the image on screen is a playback proxy's (not the original)."""
        return self._stretched
