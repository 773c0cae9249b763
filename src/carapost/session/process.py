"""The Process actions of a `carapost.Session`, on the processing-command recipe.

Every Process action is three steps (:mod:`carapost.commands.recipe`):
``prepare_<action>(...)`` validates and snapshots on the calling thread and returns a
:class:`~carapost.commands.recipe.Job` that holds no reference to the project;
``job.compute(progress)`` runs the algorithm anywhere (the window: its worker thread);
:meth:`ProcessActions.apply` pushes the result as one History entry. The synchronous
method of each action (``detect_blobs``, ``track``, ...) is ``run(prepare_<action>(...),
progress)``, so a script, ``carapost process`` and the window share one path::

    job = session.prepare("detect_blobs", frames="current")
    result = job.compute(progress)       # worker thread
    session.apply(result)                # one History entry
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.commands.recipe import ApplyResult, Job, Result
from carapost.commands.stack import Command, CommandError, CommandStack
from carapost.model.project import Project

log = logging.getLogger("carapost.session")

__all__ = ["PROCESS_ACTIONS", "ImageFn", "ProcessActions", "ProgressFn", "one_of"]

#: ``progress(done, total) -> bool``; returning False cancels.
ProgressFn = Callable[[int, int], bool]
#: ``get_image(frame, camera) -> grey image`` [H, W] uint8.
ImageFn = Callable[[int, int], NDArray[np.uint8]]
#: The Process actions of :meth:`ProcessActions.prepare` (each has ``prepare_<action>``
#: and a synchronous method of the same name).
PROCESS_ACTIONS = ("detect_blobs", "solve_brim", "initialize_3d", "bundle_current_frame",
                   "bundle_sequence", "track", "track_take", "initialize_from_rom",
                   "stabilize", "interpolate_gaps", "filter_trajectories",
                   "label_from_template")


def one_of(value: str, choices: Sequence[str], what: str) -> str:
    """``value`` lower-cased when it is one of ``choices``, else a CommandError naming
    ``what`` and the choices."""
    v = str(value).strip().lower()
    if v not in choices:
        raise CommandError(f"{what} must be one of {', '.join(map(repr, choices))}, "
                           f"got {value!r}")
    return v


class ProcessActions:
    """The Process menu of a `carapost.Session` (mixed into it; see the module).

    Attributes
    ----------
    project : Project
    stack : CommandStack
    """

    project: Project
    stack: CommandStack

    # it uses the Session's push, frame_range, image_source, get_image and has_images

    # ====================================================================================
    # Process: prepare (snapshot, caller's thread) -> compute (any thread) -> apply
    # ====================================================================================
    def prepare(self, action: str, /, **options: Any) -> Job:
        """Step 1 of a Process action: validate and snapshot, on the calling thread.

        ``session.prepare("track", direction="backwards")`` is
        ``session.prepare_track(direction="backwards")``; ``action`` is one of
        :data:`PROCESS_ACTIONS` and ``options`` are those of the synchronous method of
        that name (without ``progress``). The job holds no reference to the project:
        run ``job.compute(progress)`` anywhere (the window: its worker thread), then
        :meth:`apply` the result::

            job = session.prepare("detect_blobs", frames="current")
            result = job.compute(progress)       # worker thread
            session.apply(result)                # one History entry

        Image actions (``detect_blobs``, ``track``, ``track_take``) take ``get_image``
        too: an image source for the thread that computes (default: the session's).

        Raises
        ------
        CommandError
            Unknown action, or the action refuses (the message says why).
        """
        if action not in PROCESS_ACTIONS:
            raise CommandError(f"prepare: {action!r} is not a Process action (one of "
                               f"{', '.join(PROCESS_ACTIONS)})")
        return getattr(self, f"prepare_{action}")(**options)

    def apply(self, result: Result) -> ApplyResult | None:
        """Step 3: push a computed result as one History entry (``ApplyResult``).

        A cancelled job's result is pushed too (what was finished is kept, as in the
        window) and logged; one cancelled before it finished anything changes nothing
        and adds no History entry (returns None).
        """
        if not isinstance(result, Result):
            raise TypeError(f"apply needs a Result, got {type(result).__name__}")
        if result.cancelled and result.changes_nothing():
            log.info("%s: cancelled before anything was finished; nothing changed",
                     result.description)
            return None
        command = ApplyResult(result)
        if result.cancelled:
            log.warning("%s: cancelled; the finished part is kept", result.description)
            if "cancelled" not in command.description:  # the History says so
                command.description += " (cancelled: partial)"
        return self.stack.push(command)  # type: ignore[return-value]

    def run(self, job: Job, progress: ProgressFn | None = None) -> ApplyResult | None:
        """Steps 2 and 3 here: ``apply(job.compute(progress))``. Every synchronous
        Process method is ``run(prepare_<action>(...), progress)``."""
        return self.apply(job.compute(progress))

    def prepare_detect_blobs(self, frames: str | Sequence[int] = "current",
                             cameras: Iterable[int] | None = None, *, workers: int = 2,
                             get_image: ImageFn | None = None,
                             processes: bool | None = None) -> Job:
        """Prepare :meth:`detect_blobs` (see :meth:`prepare`)."""
        from carapost.commands.process import prepare_detect_blobs

        rng = self.frame_range(frames, "Detect Blobs")
        images = get_image if get_image is not None else self.image_source("Detect Blobs")
        cams = None if cameras is None else [int(c) for c in cameras]
        title = {"current": "Current Frame", "active": "Active Range"}.get(
            frames.strip().lower() if isinstance(frames, str) else "")
        return prepare_detect_blobs(self.project, rng, cams, images, workers,
                                    f"Detect Blobs [{title}]" if title else None, processes)

    def detect_blobs(self, frames: str | Sequence[int] = "current",
                     cameras: Iterable[int] | None = None, *,
                     progress: ProgressFn | None = None, workers: int = 2,
                     processes: bool | None = None) -> ApplyResult | None:
        """Process > Detect Blobs [Current Frame] / [Active Range] with the Blob Parameters.

        Parameters
        ----------
        frames : {"current", "active", "all"} or (first, last) or a contiguous run
        cameras : iterable of int, optional
            Default: the explicitly selected cameras, or all.
        progress : callable, optional
            ``progress(done, total)`` over the images; False cancels (the finished
            images are kept).
        workers : int
            Detector processes or threads.
        processes : bool, optional
            Detect in worker processes (True) or on threads (False); default: processes
            for batches of 16 images or more. The results are the same either way.
        """
        return self.run(self.prepare_detect_blobs(frames, cameras, workers=workers,
                                                  processes=processes), progress)

    def load_rom(self, path: str | Path) -> Command:
        """Process > Load ROM: keep a ``.cara`` project to initialise this take from."""
        from carapost.commands.rom import LoadRom

        return self.push(LoadRom(self.project, path))

    def prepare_initialize_from_rom(self, brim_only: bool = False,
                                    frame: int | None = None) -> Job:
        """Prepare :meth:`initialize_from_rom` (see :meth:`prepare`)."""
        from carapost.commands.rom import prepare_rom_initialisation

        return prepare_rom_initialisation(self.project, brim_only=brim_only, frame=frame)

    def initialize_from_rom(self, brim_only: bool = False, frame: int | None = None, *,
                            progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Initialize from ROM (``brim_only``: [Brim Only]) at the current frame."""
        return self.run(self.prepare_initialize_from_rom(brim_only, frame), progress)

    def initialize_default_brim(self, version: str = "2.0") -> Command:
        """Process > Initialize Default Calibration Brim [v2.0 / v1.1 / v1.0]."""
        from carapost.commands.process import InitializeDefaultBrim

        return self.push(InitializeDefaultBrim(self.project, version))

    def prepare_solve_brim(self, frame: int | None = None, method: str = "auto",
                           correspondences: Mapping[int, Sequence[tuple[int, int]]]
                           | None = None) -> Job:
        """Prepare :meth:`solve_brim` (see :meth:`prepare`)."""
        from carapost.commands.process import (
            prepare_solve_brim,
            prepare_solve_brim_auto,
            prepare_solve_brim_manual,
        )

        how = one_of(method, ("auto", "manual", "automatic"), "Solve Calibration Brim: "
                      "method")
        p = self.project
        f = p.current_frame if frame is None else int(frame)
        if how == "manual" or (how == "auto" and correspondences is not None):
            return prepare_solve_brim_manual(p, f, correspondences)
        if correspondences is not None:
            raise CommandError("Solve Calibration Brim [Automatic]: correspondences are "
                               "for the manual solve")
        return prepare_solve_brim(p, f) if how == "auto" else prepare_solve_brim_auto(p, f)

    def solve_brim(self, frame: int | None = None, method: str = "auto",
                   correspondences: Mapping[int, Sequence[tuple[int, int]]] | None = None,
                   *, progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Solve Calibration Brim at ``frame`` (default: the current frame).

        Parameters
        ----------
        method : {"auto", "manual", "automatic"}
            "manual": from the brim points attached to detections (or
            ``correspondences``); "automatic": matches found from the XCP rig
            geometry; "auto" (the menu's rule): manual when brim points are attached
            at the frame, else automatic.
        """
        return self.run(self.prepare_solve_brim(frame, method, correspondences), progress)

    def prepare_initialize_3d(self, frame: int | None = None,
                              seeds: Sequence[Sequence[int]] | None = None) -> Job:
        """Prepare :meth:`initialize_3d` (see :meth:`prepare`)."""
        from carapost.commands.process import prepare_initialize_3d

        return prepare_initialize_3d(self.project, frame, seeds)

    def initialize_3d(self, frame: int | None = None,
                      seeds: Sequence[Sequence[int]] | None = None, *,
                      progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Initialize 3D at ``frame`` (default: the current frame)."""
        return self.run(self.prepare_initialize_3d(frame, seeds), progress)

    def prepare_bundle_current_frame(self, frame: int | None = None) -> Job:
        """Prepare :meth:`bundle_current_frame` (see :meth:`prepare`)."""
        from carapost.commands.process import prepare_bundle_frame

        return prepare_bundle_frame(self.project, frame)

    def bundle_current_frame(self, frame: int | None = None, *,
                             progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Bundle Current Frame [Unconstrained]."""
        return self.run(self.prepare_bundle_current_frame(frame), progress)

    def prepare_bundle_sequence(self, frames: str | Sequence[int] = "active") -> Job:
        """Prepare :meth:`bundle_sequence` (see :meth:`prepare`)."""
        from carapost.commands.bundle import prepare_bundle_sequence

        rng = self.frame_range(frames, "Bundle Sequence [Unconstrained]")
        return prepare_bundle_sequence(self.project, rng)

    def bundle_sequence(self, frames: str | Sequence[int] = "active", *,
                        progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Bundle Sequence [Unconstrained] (over the active range by default)."""
        return self.run(self.prepare_bundle_sequence(frames), progress)

    def prepare_track(self, direction: str | int = "forwards", *, single_frame: bool = False,
                      point_ids: Iterable[int] | None = None, frame: int | None = None,
                      use_images: bool = True, get_image: ImageFn | None = None) -> Job:
        """Prepare :meth:`track` (see :meth:`prepare`)."""
        from carapost.commands.tracking import prepare_tracking

        if isinstance(direction, str):
            d = one_of(direction, ("forwards", "backwards"), "Track: direction")
            step = 1 if d == "forwards" else -1
        elif int(direction) in (1, -1):
            step = int(direction)
        else:
            raise CommandError(f"Track: direction must be 'forwards' or 'backwards', got "
                               f"{direction!r}")
        ids = sorted(self.project.selection.points) if point_ids is None else \
            [int(i) for i in point_ids]
        if get_image is None and use_images and self.has_images:
            get_image = self.get_image
        return prepare_tracking(self.project, step, single_frame=single_frame,
                                point_ids=ids or None, frame=frame,
                                get_image=get_image if use_images else None)

    def track(self, direction: str | int = "forwards", *, single_frame: bool = False,
              point_ids: Iterable[int] | None = None, frame: int | None = None,
              use_images: bool = True, progress: ProgressFn | None = None) -> ApplyResult | None:
        """Process > Track Forwards / Backwards [Sequence] or [Single Frame] (Ctrl+W).

        Parameters
        ----------
        direction : {"forwards", "backwards"} or {+1, -1}
        single_frame : bool
            One frame on instead of the rest of the active range.
        point_ids : iterable of int, optional
            Default: the selected points, or all when none is selected (as the menu).
        frame : int, optional
            Start frame (default: the current frame).
        use_images : bool
            Give the tracker the images (patch tracking of point-cameras without a
            blob, detection of frames without detections), as the window does when
            the take has videos.
        """
        return self.run(self.prepare_track(direction, single_frame=single_frame,
                                           point_ids=point_ids, frame=frame,
                                           use_images=use_images), progress)

    def prepare_track_take(self, frame: int | None = None, *, find_markers: bool = True,
                           use_images: bool = False, get_image: ImageFn | None = None) -> Job:
        """Prepare :meth:`track_take` (see :meth:`prepare`)."""
        from carapost.commands.tracking import prepare_take_tracking

        if use_images and get_image is None:
            get_image = self.image_source("Track Take")
        return prepare_take_tracking(self.project, frame, find_markers=find_markers,
                                     get_image=get_image if use_images else None)

    def track_take(self, frame: int | None = None, *, find_markers: bool = True,
                   use_images: bool = False, progress: ProgressFn | None = None
                   ) -> ApplyResult | None:
        """Track the whole take from an initialised frame, finding missed markers.

        What ``carapost process`` does after Initialize 3D (forwards, then backwards).
        ``use_images`` turns on patch tracking (slower: every image is decoded again).
        """
        return self.run(self.prepare_track_take(frame, find_markers=find_markers,
                                                use_images=use_images), progress)
