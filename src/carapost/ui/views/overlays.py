"""Overlays of the camera views: the loaded ROM's markers, and labels that never pile up."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import project as project_points
from carapost.model.project import Project

__all__ = ["declutter", "rom_overlay"]


def rom_overlay(project: Project, frame: int, camera: int) -> NDArray | None:
    """Raw-pixel positions of the loaded ROM's points (at its ROM Frame Index) in one
    camera at one frame, or None without a ROM or cameras."""
    rom = project.rom.project if project.rom is not None else None
    intr = project.calibration.intrinsics
    if rom is None or intr is None or not rom.n_frames or camera >= project.n_cameras:
        return None
    try:
        rf = int(project.properties["rom_frame_index"])
    except (KeyError, TypeError, ValueError):
        rf = 0
    if not 0 <= rf < rom.n_frames:
        return None
    X = rom.points.positions[rf].astype(np.float64)
    X = X[np.isfinite(X).all(-1)]
    R, t = project.calibration.R[frame], project.calibration.t[frame]
    if not len(X) or not np.isfinite(R[camera]).all():
        return None
    uv, depth = project_points(X, R, t, intr)
    uv, depth = uv[:, camera], depth[:, camera]
    ok = np.isfinite(uv).all(-1) & (depth > 0)
    return uv[ok]


def declutter(places: list[tuple[int, NDArray]], to_view: Callable[[NDArray], tuple[float, float]],
              label_of: Callable[[int], str], selected: set[int], size: int,
              viewport: tuple[int, int]) -> set[int]:
    """Labels to draw: inside the visible region and not over an earlier one (the
    selected points' labels first), so Point Labels: All stays readable.

    Parameters
    ----------
    places : list of (column, image xy)
        Where each label would go (raw pixels).
    to_view : callable
        Raw pixels -> viewport pixels.
    label_of : callable
        Column -> label text.
    selected : set of int
        Columns whose labels go first.
    size : int
        Font size (pt).
    viewport : (int, int)
        Width and height of the view (px).

    Returns
    -------
    set of int
        The columns whose labels are drawn.
    """
    vw, vh = viewport
    char_w, line_h = 0.62 * size * 1.35, 1.6 * size * 1.35  # pt -> px, roughly
    boxes: list[tuple[float, float, float, float]] = []
    keep: set[int] = set()
    for col, xy in sorted(places, key=lambda cp: cp[0] not in selected):
        x, y = to_view(xy)
        if not (0 <= x < vw and 0 <= y < vh):
            continue  # outside the zoomed region
        box = (x, y - line_h, x + char_w * len(label_of(col)) + 6, y)
        if any(box[0] < b[2] and b[0] < box[2] and box[1] < b[3] and b[1] < box[3]
               for b in boxes):
            continue
        boxes.append(box)
        keep.add(col)
    return keep
