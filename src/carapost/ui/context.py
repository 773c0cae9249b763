"""State the views share: the project, images, display options and per-frame caches."""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PySide6.QtCore import QObject, Signal

from carapost.model.events import Change
from carapost.model.project import Project, new_project
from carapost.ui.frames import FrameSource

log = logging.getLogger("carapost.ui")


@dataclass
class DisplayOptions:
    """What the views draw (the toggles of the 2D and 3D context menus)."""

    border: bool = True
    image: bool = True
    detections: bool = True
    points: bool = True
    projections: bool = True
    connected: bool = True
    unconnected: bool = True
    errors: bool = True
    blob_preview: bool = False
    pixel_report: bool = False
    rom: bool = True
    sticks: bool = True
    # 3D view
    face_points: bool = True
    brim_points: bool = True
    recon_colours: bool = True
    cameras: bool = True
    rays: bool = True

    def to_dict(self) -> dict[str, bool]:
        """Plain dict for settings."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def update(self, values: dict[str, Any]) -> None:
        """Set known fields from a dict (unknown keys are ignored)."""
        for f in fields(self):
            if f.name in values:
                v = values[f.name]
                setattr(self, f.name, v in (True, "true", "True", 1, "1"))


#: Names shown in the 2D context menu for each option.
OPTION_TITLES_2D = (
    ("border", "Border"), ("image", "Image"), ("detections", "Detections"),
    ("points", "Points"), ("projections", "Projections"), ("connected", "Connected"),
    ("unconnected", "Unconnected"), ("errors", "Errors"), ("blob_preview", "Blob Preview"),
    ("pixel_report", "Pixel Report"), ("rom", "ROM"), ("sticks", "Sticks"),
)
OPTION_TITLES_3D = (
    ("face_points", "Face Points"), ("brim_points", "Calibration Brim Points"),
    ("recon_colours", "Reconstruction Type Colors"), ("cameras", "Cameras"),
    ("rays", "Rays"), ("rom", "ROM"), ("sticks", "Sticks"),
)


class ViewContext(QObject):
    """Shared by every view of one window (and its floating workspaces).

    Signals
    -------
    changed(Change)
        The model changed (coalesced, GUI thread).
    options_changed()
        Display options, pre-selection, active camera or lock changed.
    """

    changed = Signal(object)
    options_changed = Signal()
    frame_ready = Signal(int, int)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.project: Project = new_project(0, 0)
        self.frames: FrameSource = FrameSource()
        self.options = DisplayOptions()
        self.preselected: int | None = None  # point id under the mouse
        self.active_camera: int | None = None
        self.lock_to_point = False
        self.show_stabilized = False
        self._proj_cache: dict[int, NDArray[np.float64] | None] = {}
        self._preview_cache: dict[tuple[int, int], Any] = {}
        self.changed.connect(self._invalidate)

    # -- caches ------------------------------------------------------------------------------
    def set_project(self, project: Project, frames: FrameSource) -> None:
        """Switch to another project."""
        self.frames.close()
        self.project = project
        self.frames = frames
        self._proj_cache.clear()
        self._preview_cache.clear()
        self.preselected = None
        self.active_camera = None

    def _invalidate(self, change: Change) -> None:
        if change.parts & {"points", "point_list", "cameras", "frames_range", "file"}:
            self._proj_cache.clear()
        if change.parts & {"properties", "cameras", "frames_range", "file"}:
            self._preview_cache.clear()

    def projections(self, frame: int) -> NDArray[np.float64] | None:
        """Every point projected into every camera at ``frame``: [P, C, 2] px, NaN if none."""
        if frame in self._proj_cache:
            return self._proj_cache[frame]
        p = self.project
        cal = p.calibration
        out = None
        if (cal.intrinsics is not None and p.n_points and 0 <= frame < p.n_frames
                and cal.intrinsics.n_cameras == p.n_cameras):
            from carapost.algorithms.camera import project as project_points

            uv, _ = project_points(p.points.positions[frame].astype(np.float64),
                                   cal.R[frame], cal.t[frame], cal.intrinsics)
            out = uv
        if len(self._proj_cache) > 64:
            self._proj_cache.clear()
        self._proj_cache[frame] = out
        return out

    def blob_preview(self, frame: int, camera: int, image: NDArray[np.uint8]) -> Any:
        """Blobs Detect Blobs would find in this image (cached per frame and camera)."""
        key = (frame, camera)
        if key in self._preview_cache:
            return self._preview_cache[key]
        try:
            from carapost.algorithms.blobs import preview_blobs

            result = preview_blobs(image, self.blob_parameters())
        except Exception as exc:
            log.warning("blob preview failed: %s", exc)
            result = None
        if len(self._preview_cache) > 32:
            self._preview_cache.clear()
        self._preview_cache[key] = result
        return result

    def blob_parameters(self) -> Any:
        """BlobParameters from the project's Blob Parameters properties."""
        from carapost.algorithms.blobs import BlobParameters
        from carapost.algorithms.params import from_mapping

        return from_mapping(BlobParameters, self.project.properties)

    def point_column(self, point_id: int | None) -> int | None:
        """Column of a point id (None if it does not exist)."""
        if point_id is None:
            return None
        hit = np.flatnonzero(self.project.points.ids == point_id)
        return int(hit[0]) if len(hit) else None

    def label_mode(self) -> tuple[bool, bool, bool, int]:
        """(all, selected, pre-selected, font size) from the Display properties."""
        props = self.project.properties
        return (bool(props["point_labels_all"]), bool(props["point_labels_selected"]),
                bool(props["point_labels_preselected"]), int(props["label_font_size"]))

    def labelled_columns(self) -> NDArray[np.intp]:
        """Columns whose label should be drawn now."""
        p = self.project
        show_all, show_sel, show_pre, _ = self.label_mode()
        if show_all:
            return np.arange(p.n_points)
        cols: set[int] = set()
        if show_sel:
            cols.update(int(c) for c in p.selected_columns())
        if show_pre and self.preselected is not None:
            c = self.point_column(self.preselected)
            if c is not None:
                cols.add(c)
        return np.array(sorted(cols), dtype=np.intp)

    def notify_options(self) -> None:
        """Tell views that display options changed."""
        self.options_changed.emit()
