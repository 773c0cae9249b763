"""The Process items as a table of ``prepare`` functions over a bare project.

The window, the CLI, ``carapost process`` and scripts go through
:class:`carapost.Session` (``session.prepare(action, ...)``, ``job.compute``,
``session.apply``), which calls the same ``prepare_*`` functions of
:mod:`carapost.commands.process`, :mod:`~carapost.commands.tracking`,
:mod:`~carapost.commands.rom` and :mod:`~carapost.commands.bundle`. This module keeps
the older hook-named form for code that holds a project without a session:

    job = menu.prepare("track_forwards_sequence", project, get_image=frames.require)
    stack.push(ApplyResult(job.compute(progress)))

``JOBS[hook](project, get_image=None) -> Job`` validates and snapshots what the item
acts on (the current frame, the active range, the selected points, all points when none
is selected). Items that change the project without an algorithm (the default brims)
have no job: ``prepare`` returns the command itself (:func:`is_command` tells).

The functions named after the hooks (``initialize_3d(project, progress)`` ...) prepare
and compute in one call and return the command to push.
"""

from __future__ import annotations

from collections.abc import Callable

from numpy.typing import NDArray

from carapost.commands.bundle import prepare_bundle_sequence
from carapost.commands.process import (
    InitializeDefaultBrim,
    SolveBrimAuto,
    SolveBrimManual,
    prepare_bundle_frame,
    prepare_detect_blobs,
    prepare_initialize_3d,
    prepare_solve_brim,
)
from carapost.commands.recipe import ApplyResult, Job
from carapost.commands.rom import prepare_rom_initialisation
from carapost.commands.stack import Command, CommandError
from carapost.commands.tracking import prepare_tracking
from carapost.model.project import Project

ProgressFn = Callable[[int, int], bool] | None
#: ``get_image(frame, camera) -> grey image`` for the items that can use images.
ImageFn = Callable[[int, int], NDArray] | None


def _selected_ids(project: Project) -> list[int] | None:
    ids = sorted(project.selection.points)
    return ids or None


def _tracking(direction: int, single: bool) -> Callable[..., Job]:
    def prepare_item(project: Project, get_image: ImageFn = None) -> Job:
        return prepare_tracking(project, direction, single_frame=single,
                                point_ids=_selected_ids(project), get_image=get_image)
    return prepare_item


def _from_rom(brim_only: bool) -> Callable[..., Job]:
    def prepare_item(project: Project, get_image: ImageFn = None) -> Job:
        if project.rom is None or project.rom.project is None:
            raise CommandError("Initialize from ROM: no ROM is loaded (Process > Load ROM "
                               "first)")
        return prepare_rom_initialisation(project, brim_only=brim_only)
    return prepare_item


def _brim(version: str) -> Callable[..., Command]:
    def prepare_item(project: Project, get_image: ImageFn = None) -> Command:
        return InitializeDefaultBrim(project, version)
    return prepare_item


def _detect(which: str) -> Callable[..., Job]:
    def prepare_item(project: Project, get_image: ImageFn = None) -> Job:
        f = project.current_frame
        frames = (f, f) if which == "current" else project.active_range
        title = "Current Frame" if which == "current" else "Active Range"
        return prepare_detect_blobs(project, frames, get_image=get_image,
                                    description=f"Detect Blobs [{title}]")
    return prepare_item


#: hook -> ``prepare(project, get_image=None)``: a Job, or a Command for the items
#: without an algorithm. ``get_image`` is ignored by the items that use no images.
JOBS: dict[str, Callable[..., Job | Command]] = {
    "detect_blobs_current": _detect("current"),
    "detect_blobs_range": _detect("range"),
    "initialize_brim_v20": _brim("2.0"),
    "initialize_brim_v11": _brim("1.1"),
    "initialize_brim_v10": _brim("1.0"),
    "solve_brim": lambda project, get_image=None: prepare_solve_brim(project),
    "initialize_3d": lambda project, get_image=None: prepare_initialize_3d(
        project, project.current_frame),
    "bundle_current_frame": lambda project, get_image=None: prepare_bundle_frame(
        project, project.current_frame),
    "bundle_sequence": lambda project, get_image=None: prepare_bundle_sequence(project),
    "track_forwards_sequence": _tracking(+1, False),
    "track_backwards_sequence": _tracking(-1, False),
    "track_forwards_frame": _tracking(+1, True),
    "track_backwards_frame": _tracking(-1, True),
    "initialize_from_rom": _from_rom(False),
    "initialize_from_rom_brim_only": _from_rom(True),
}

#: the items that use ``get_image`` (patch tracking, detection of frames with none)
USES_IMAGES = frozenset({"detect_blobs_current", "detect_blobs_range",
                         "track_forwards_sequence", "track_backwards_sequence",
                         "track_forwards_frame", "track_backwards_frame"})


def prepare(hook: str, project: Project, get_image: ImageFn = None) -> Job | Command:
    """Prepare the Process item ``hook`` (calling thread): a Job, or a Command to push.

    Raises
    ------
    KeyError
        No such item.
    CommandError
        The item refuses (nothing to act on); the message says why.
    """
    return JOBS[hook](project, get_image=get_image)


def is_command(prepared: Job | Command) -> bool:
    """Whether ``prepare`` gave a command to push directly (no worker needed)."""
    return isinstance(prepared, Command)


def run(hook: str, project: Project, progress: ProgressFn = None,
        get_image: ImageFn = None) -> Command:
    """Prepare and compute ``hook`` in one call; the command to push."""
    prepared = prepare(hook, project, get_image)
    if isinstance(prepared, Command):
        return prepared
    return ApplyResult(prepared.compute(progress))


# -- the older one-call form: ``name(project, progress=None) -> Command`` -------------------
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
    manual = prepare_solve_brim(project, f).mode == "manual"  # cheap: a snapshot
    return SolveBrimManual(project, f) if manual else SolveBrimAuto(project, f)


def initialize_3d(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize 3D at the current frame (seeds: points attached in 2+ cameras)."""
    return run("initialize_3d", project, progress)


def bundle_current_frame(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Bundle Current Frame [Unconstrained]."""
    return run("bundle_current_frame", project, progress)


def track_forwards_sequence(project: Project, progress: ProgressFn = None,
                            get_image: ImageFn = None) -> Command:
    """Process > Track Forwards [Sequence]: over the active range from the current frame.

    With ``get_image(frame, camera)`` (the window passes its take's images), point-cameras
    without a blob are patch tracked and frames without detections are detected first.
    """
    return run("track_forwards_sequence", project, progress, get_image)


def track_backwards_sequence(project: Project, progress: ProgressFn = None,
                             get_image: ImageFn = None) -> Command:
    """Process > Track Backwards [Sequence]."""
    return run("track_backwards_sequence", project, progress, get_image)


def track_forwards_frame(project: Project, progress: ProgressFn = None,
                         get_image: ImageFn = None) -> Command:
    """Process > Track Forwards [Single Frame] (Ctrl+W)."""
    return run("track_forwards_frame", project, progress, get_image)


def track_backwards_frame(project: Project, progress: ProgressFn = None,
                          get_image: ImageFn = None) -> Command:
    """Process > Track Backwards [Single Frame]."""
    return run("track_backwards_frame", project, progress, get_image)


def initialize_from_rom(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize from ROM (face and brim)."""
    return run("initialize_from_rom", project, progress)


def initialize_from_rom_brim_only(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Initialize from ROM [Brim Only]."""
    return run("initialize_from_rom_brim_only", project, progress)


def bundle_sequence(project: Project, progress: ProgressFn = None) -> Command:
    """Process > Bundle Sequence [Unconstrained] over the active range."""
    return run("bundle_sequence", project, progress)
