"""Process-menu entry points: ``name(project, progress=None) -> Command``.

The main window calls these on a worker thread; every command computes its result
when it is created (the slow part) and the window pushes it on the GUI thread as one
undo entry. Each function acts where the artist is: the current frame, the active
range, the selected points (all points when none is selected).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from carapost.commands.process import (
    BundleCurrentFrame,
    Initialize3D,
    InitializeDefaultBrim,
    SolveBrimAuto,
    SolveBrimManual,
)
from carapost.commands.stack import Command, CommandError
from carapost.model.project import KIND_BRIM, Project

ProgressFn = Callable[[int, int], bool] | None
#: ``get_image(frame, camera) -> grey image`` for the commands that can use images.
ImageFn = Callable[[int, int], NDArray] | None


def initialize_brim_v20(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize Default Calibration Brim [v2.0]."""
    return InitializeDefaultBrim(project, "2.0")


def initialize_brim_v11(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize Default Calibration Brim [v1.1]."""
    return InitializeDefaultBrim(project, "1.1")


def initialize_brim_v10(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize Default Calibration Brim [v1.0]."""
    return InitializeDefaultBrim(project, "1.0")


def solve_brim(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Solve Calibration Brim [Manual] at the current frame.

    With brim points attached to detections this is the manual solve (at least four
    per camera); with none attached and an XCP calibration loaded, the automatic solve
    finds the correspondences itself.
    """
    f = project.current_frame
    brim = np.flatnonzero(project.points.kind == KIND_BRIM)
    if len(brim) and np.any(project.points.detection[f, brim] >= 0):
        return SolveBrimManual(project, f)
    return SolveBrimAuto(project, f)


def initialize_3d(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize 3D at the current frame (seeds: points attached in 2+ cameras)."""
    return Initialize3D(project, project.current_frame)


def bundle_current_frame(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Bundle Current Frame [Unconstrained]."""
    return BundleCurrentFrame(project, project.current_frame)


def _selected_ids(project: Project) -> list[int] | None:
    ids = sorted(project.selection.points)
    return ids or None


def _track(project: Project, direction: int, single: bool, progress: ProgressFn,
           get_image: ImageFn) -> Command:
    from carapost.commands.tracking import TrackCommand

    return TrackCommand(project, direction, single_frame=single,
                        point_ids=_selected_ids(project), progress=progress,
                        get_image=get_image)


def track_forwards_sequence(project: Project, progress: ProgressFn = None,
                            get_image: ImageFn = None) -> Command:
    """Process > Track Forwards [Sequence]: over the active range from the current frame.

    With ``get_image(frame, camera)`` (the window passes its take's images), point-cameras
    without a blob are patch tracked and frames without detections are detected first.
    """
    return _track(project, +1, False, progress, get_image)


def track_backwards_sequence(project: Project, progress: ProgressFn = None,
                             get_image: ImageFn = None) -> Command:
    """Process > Track Backwards [Sequence]."""
    return _track(project, -1, False, progress, get_image)


def track_forwards_frame(project: Project, progress: ProgressFn = None,
                         get_image: ImageFn = None) -> Command:
    """Process > Track Forwards [Single Frame] (Ctrl+W)."""
    return _track(project, +1, True, progress, get_image)


def track_backwards_frame(project: Project, progress: ProgressFn = None,
                          get_image: ImageFn = None) -> Command:
    """Process > Track Backwards [Single Frame]."""
    return _track(project, -1, True, progress, get_image)


def _from_rom(project: Project, brim_only: bool) -> Command:
    from carapost.commands.tracking import InitializeFromRom

    if project.rom is None or project.rom.project is None:
        raise CommandError("Initialize from ROM: no ROM is loaded (Process > Load ROM first)")
    return InitializeFromRom(project, brim_only=brim_only)


def initialize_from_rom(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize from ROM (face and brim)."""
    return _from_rom(project, False)


def initialize_from_rom_brim_only(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize from ROM [Brim Only]."""
    return _from_rom(project, True)


def bundle_sequence(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Bundle Sequence [Unconstrained] over the active range."""
    from carapost.commands.bundle import BundleSequence

    return BundleSequence(project, progress=progress)
