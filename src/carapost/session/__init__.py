"""The scripting session: a project, its undo stack and its images, driven like the menus.

A `Session` holds one `Project`, the `CommandStack` of its History and a source of
camera images (the take's videos, opened on first use). It has one method per File,
Edit and Process action of the main window. The window itself holds a Session per open
project and every menu item calls it, so a script's History matches the window's and
every action undoes as one step::

    from carapost import Session

    s = Session.import_take("shoot/Speech01_cam0.mkv")
    s.detect_blobs("all")
    s.solve_brim(frame=0)
    s.initialize_3d(frame=0)
    s.track()                      # forwards over the active range
    s.save("Speech01.cara")
    s.export_c3d("Speech01.c3d")   # Export Range, Include Brim Points, ... of the project
    print([h.description for h in s.history()])
    s.undo()

Bad input raises :class:`~carapost.commands.stack.CommandError` (the action refused;
the project is unchanged) or :class:`~carapost.io.errors.CaraFileError` (a file is
missing or unreadable; the message names it). Processing methods take an optional
``progress(done, total) -> bool`` callback; returning False cancels, and what was
finished is kept as one History entry, as in the window.

Process actions follow the recipe of :mod:`carapost.commands.recipe` in two public
steps, which the window uses to compute on its worker thread::

    job = s.prepare("detect_blobs", frames="current")   # or s.prepare_detect_blobs(...)
    result = job.compute(progress)                      # any thread, no project access
    s.apply(result)                                     # one History entry

``s.detect_blobs(...)`` is ``s.run(s.prepare_detect_blobs(...), progress)``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.commands import edit
from carapost.commands import file as file_commands
from carapost.commands.stack import Command, CommandError, CommandStack, HistoryEntry
from carapost.export import ExportOptions
from carapost.model.project import Project, new_project
from carapost.session.gapfill import GapFillActions
from carapost.session.labelling import LabellingActions
from carapost.session.process import (
    PROCESS_ACTIONS,
    ImageFn,
    ProcessActions,
    ProgressFn,
    one_of,
)
from carapost.session.quality import QualityActions
from carapost.session.script import ScriptActions
from carapost.session.stabilise import StabiliseActions
from carapost.session.target import TargetActions
from carapost.session.target_sizes import TargetSizeActions

log = logging.getLogger("carapost.session")

__all__ = ["PROCESS_ACTIONS", "ImageFn", "ProgressFn", "RelocateCallback", "Session",
           "read_take"]

#: Called with (camera name or "take", missing path); returns a replacement or None.
RelocateCallback = Callable[[str, str], "str | None"]


def read_take(path: str | Path, *, relocate: RelocateCallback | None = None,
              take_brim: bool = True) -> Project:
    """Import Camera Files: a new project from one file (or the folder) of a take.

    See `carapost.io.take_import.import_take` for the files a take is made of. When the
    take carries its brim model (``<take>_brim.csv``) and ``take_brim`` is true, the
    project starts with those brim points, ready for Solve Calibration Brim (not a
    History entry: the imported project is the start of the History). ``carapost
    process`` passes False: it chooses the brim model itself (``--brim``, the take's,
    or one triangulated from the take) once the blobs are found.

    Raises
    ------
    CaraFileError
        Missing or unreadable camera files, metadata, calibration, labels or brim file.
    """
    from carapost.commands.process import SetBrimModel
    from carapost.io.take_import import import_take, read_brim_csv

    project = import_take(path, relocate=relocate)
    project.script = [{"import": {"take_brim": bool(take_brim)}}]  # session/script.py
    brim_file = project.take.metadata.get("brim_file")
    if brim_file and take_brim:
        labels, xyz = read_brim_csv(brim_file)
        SetBrimModel(labels, xyz, description="Calibration brim of the take").do(project)
        log.info("Brim model of the take: %d dots from %s", len(xyz), brim_file)
    return project


class Session(ScriptActions, ProcessActions, QualityActions, StabiliseActions,
              TargetActions, GapFillActions, LabellingActions,
              TargetSizeActions):
    """A project with its undo History and images, with one method per menu action.

    The Process methods and the two-step form (`prepare`, `apply`, `run`) come from
    :class:`carapost.session.process.ProcessActions`.

    Parameters
    ----------
    project : Project, optional
        The project (default: an empty one, as File > Clear leaves).
    get_image : callable, optional
        ``get_image(frame, camera) -> grey image``. Default: the take's videos, opened
        on first use (`carapost.io.video.TakeFrames`, which raises `CaraFileError` for
        a missing video).

    Attributes
    ----------
    project : Project
    stack : CommandStack
    """

    def __init__(self, project: Project | None = None, *,
                 get_image: ImageFn | None = None) -> None:
        self.project = project if project is not None else new_project(0, 0)
        self.stack = CommandStack(self.project)
        self._get_image = get_image
        self._frames: Any = None
        #: The autosave copy found newer than the file at `open` (None: none was).
        self.newer_autosave: Path | None = None

    # ====================================================================================
    # construction, images, closing
    # ====================================================================================
    @classmethod
    def open(cls, path: str | Path, *, relocate: RelocateCallback | None = None,
             get_image: ImageFn | None = None, source: str | Path | None = None,
             recover: bool | None = None) -> Session:
        """File > Open: a session on a ``.cara`` project (a fresh History).

        Videos that moved are looked for beside the project, then ``relocate(camera,
        missing_path)`` is asked (see `relocate_files` to fix them afterwards).
        ``source``: read this file instead (the recovered autosave copy of ``path``); the
        project belongs to ``path`` and stays modified until it is saved.
        ``recover``: what to do when an autosave copy newer than ``path`` exists (the
        program stopped before saving): True opens the copy, False opens ``path``
        silently, None (the default) opens ``path``, warns (`NewerAutosaveWarning`) and
        sets ``session.newer_autosave`` to the copy's path.
        """
        from carapost.session.recovery import open_with_recovery

        return open_with_recovery(cls, path, relocate=relocate, get_image=get_image,
                                  source=source, recover=recover)

    @classmethod
    def import_take(cls, path: str | Path, *, relocate: RelocateCallback | None = None,
                    get_image: ImageFn | None = None, take_brim: bool = True) -> Session:
        """File > Import Camera Files: a session on a new project made from a take.

        Builds exactly the project the window's File > Import and ``carapost gui
        take.json`` build (`read_take`, brim model of the take included unless
        ``take_brim`` is False).
        """
        return cls(read_take(path, relocate=relocate, take_brim=take_brim),
                   get_image=get_image)

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the video files (the session stays usable; they reopen when needed)."""
        if self._frames is not None:
            self._frames.close()
            self._frames = None

    def set_image_source(self, get_image: ImageFn | None) -> None:
        """Use ``get_image(frame, camera)`` for images (None: the take's videos)."""
        self.close()
        self._get_image = get_image

    @property
    def has_images(self) -> bool:
        """Whether images can come from somewhere (a source given, or camera videos)."""
        return self._get_image is not None or any(
            cam.video_path for cam in self.project.take.cameras)

    def get_image(self, frame: int, camera: int) -> NDArray[np.uint8]:
        """The grey image of ``camera`` at take frame ``frame``.

        Raises
        ------
        CaraFileError
            The camera's video is missing or unreadable.
        """
        if self._get_image is not None:
            return self._get_image(frame, camera)
        if self._frames is None:
            from carapost.io.video import TakeFrames

            self._frames = TakeFrames(self.project.take, strict=True)
        return self._frames.get(frame, camera)

    def image_source(self, what: str) -> ImageFn:
        """The session's ``get_image``; ``CommandError("<what>: no image source")`` when
        there are no images at all."""
        if not self.has_images:
            raise CommandError(f"{what}: no image source (the take has no camera videos)")
        return self.get_image

    # ====================================================================================
    # History, state, selection
    # ====================================================================================
    def push(self, command: Command) -> Command:
        """Push any command as one History entry (it was validated when it was built)."""
        if not isinstance(command, Command):
            raise TypeError(f"push needs a Command, got {type(command).__name__}")
        return self.stack.push(command)

    def group(self, description: str) -> AbstractContextManager[Any]:
        """Make every action inside the ``with`` block one History entry.

        ``with s.group("Clean Up Lips"): s.delete_selected(); s.merge()`` undoes and
        redoes as one step; if an action inside raises, the ones before it are undone and
        the exception propagates (see `carapost.commands.stack.CommandStack.group`).
        """
        return self.stack.group(description)

    def undo(self) -> bool:
        """Edit > Undo; False when there is nothing to undo."""
        return self.stack.undo()

    def redo(self) -> bool:
        """Edit > Redo; False when there is nothing to redo."""
        return self.stack.redo()

    def goto(self, position: int) -> None:
        """History pane click: undo or redo until ``position`` entries are applied."""
        self.stack.goto(position)

    def history(self) -> list[HistoryEntry]:
        """The History entries, oldest first (undone ones flagged)."""
        return self.stack.history()

    def clear_history(self) -> int:
        """Edit > Clear History; returns the bytes freed."""
        return self.stack.clear()

    @property
    def current_frame(self) -> int:
        """The current frame (setting it is navigation, not a History entry)."""
        return int(self.project.current_frame)

    @current_frame.setter
    def current_frame(self, frame: int) -> None:
        p = self.project
        f = int(frame)
        if not 0 <= f < max(p.n_frames, 1):
            raise CommandError(f"frame {f} is outside the take (0-{max(p.n_frames - 1, 0)})")
        p.set_current_frame(f)

    def select(self, points: Iterable[int] | None = None,
               detections: Iterable[Sequence[int]] | None = None,
               cameras: Iterable[int] | None = None) -> None:
        """Replace parts of the selection (None keeps that part; ``[]`` clears it).

        Parameters
        ----------
        points : iterable of int
            Point ids.
        detections : iterable of (frame, camera, index)
        cameras : iterable of int
            Explicitly selected cameras (the Shift+click of the sensor views).
        """
        p = self.project
        if points is not None:
            points = [int(i) for i in points]
            unknown = sorted(set(points) - set(p.points.ids.tolist()))
            if unknown:
                raise CommandError(f"select: there is no point {unknown}")
        if cameras is not None:
            cameras = [int(c) for c in cameras]
            if any(not 0 <= c < p.n_cameras for c in cameras):
                raise CommandError(f"select: no camera {cameras} (cameras 0-"
                                   f"{p.n_cameras - 1})")
        p.set_selection(points=points, detections=detections, cameras=cameras)

    def frame_range(self, frames: str | Sequence[int] | None, what: str) -> tuple[int, int]:
        """(first, last) of "current", "active", "all", (first, last) or a contiguous run."""
        p = self.project
        if p.n_frames < 1:
            raise CommandError(f"{what}: the project has no frames")
        if frames is None or isinstance(frames, str):
            which = one_of(frames or "current", ("current", "active", "all"),
                            f"{what}: frames")
            if which == "current":
                return (p.current_frame, p.current_frame)
            if which == "active":
                return tuple(int(v) for v in p.active_range)  # type: ignore[return-value]
            return (0, p.n_frames - 1)
        seq = [int(f) for f in frames]
        if len(seq) == 2 and seq[0] <= seq[1]:
            a, b = seq
        elif seq and seq == list(range(seq[0], seq[0] + len(seq))):
            a, b = seq[0], seq[-1]
        else:
            raise CommandError(f"{what}: frames must be 'current', 'active', 'all', "
                               "(first, last) or a contiguous run of frames")
        if not 0 <= a <= b < p.n_frames:
            raise CommandError(f"{what}: frames {a}-{b} are outside the take "
                               f"(0-{p.n_frames - 1})")
        return a, b

    def set_active_range(self, first: int, last: int) -> Command:
        """Set the active range (Ctrl+drag on the timebar), inclusive frames."""
        a, b = int(first), int(last)
        return self.stack.push(edit.SetRange(self.project, "active_range", (a, b),
                                             f"Set Active Range {a}-{b}"))

    def reset_active_range(self) -> Command:
        """View > Reset Active Range (Ctrl+3): the whole take."""
        return self.stack.push(edit.SetRange.reset_active(self.project))

    def set_range_bound(self, which: str) -> Command:
        """View > Set Active Range Start / End (Ctrl+1 / Ctrl+2) at the current frame,
        Set View Range to Active Range, Reset View Range: ``which`` is "active_start",
        "active_end", "view_to_active" or "reset_view"."""
        ctor = getattr(edit.SetRange, one_of(which, ("active_start", "active_end",
                                                      "view_to_active", "reset_view"),
                                              "Set range"))
        return self.stack.push(ctor(self.project))

    def set_view_range(self, first: int, last: int) -> Command:
        """Set the view range, inclusive frames."""
        a, b = int(first), int(last)
        return self.stack.push(edit.SetRange(self.project, "view_range", (a, b),
                                             f"Set View Range {a}-{b}"))

    # ====================================================================================
    # Properties
    # ====================================================================================
    def set_property(self, section: str, key: str, value: Any) -> Command:
        """Change one property (the Properties pane), as one History entry.

        Parameters
        ----------
        section : str
            Section title as in the Properties pane (``"Blob Parameters"``).
        key : str
            The property's key (``"blob_min_radius"``) or its label (``"Blob Min
            Radius"``).
        value
            New value; checked against the property's type and range.
        """
        from carapost.model.properties import UnknownPropertyError, specs_in_section

        try:
            specs = specs_in_section(section)
        except UnknownPropertyError as exc:
            raise CommandError(f"Set property: {exc}") from None
        by_label = {s.label.lower(): s.key for s in specs}
        keys = {s.key for s in specs}
        k = key if key in keys else by_label.get(str(key).lower())
        if k is None:
            raise CommandError(f"Set property: section {section!r} has no property "
                               f"{key!r} (it has {', '.join(sorted(keys))})")
        return self.set_properties({k: value})

    def set_properties(self, values: Mapping[str, Any]) -> Command:
        """Change several properties (by key) as one History entry, all or nothing."""
        return self.stack.push(edit.SetProperties(self.project, values))

    def restore_properties_to_defaults(self) -> Command:
        """Edit > Restore Properties To Defaults."""
        return self.stack.push(edit.RestorePropertiesToDefaults())

    def read_blob_parameters_from_take(self) -> Command:
        """Edit > Read Blob Parameters From Take Files."""
        return self.stack.push(edit.RevertBlobParameters(self.project))

    # ====================================================================================
    # File
    # ====================================================================================
    def save(self, path: str | Path | None = None) -> Path:
        """File > Save / Save As (``.cara`` appended when missing); returns the path.

        Without ``path`` the project is saved where it was opened or last saved.
        """
        from carapost.io.cara import save_project

        if path is None:
            if not self.project.path:
                raise CommandError("Save: the project has not been saved before; give a "
                                   "path")
            path = self.project.path
        written = save_project(self.project, path)
        self.stack.mark_clean()
        return Path(written)

    def import_xcp(self, path: str | Path) -> Command:
        """File > Import XCP: the cameras of a Vicon ``.xcp`` file."""
        return self.stack.push(file_commands.ImportXcp(self.project, path))

    def import_labels(self, path: str | Path, kind: str | None = None) -> Command:
        """File > Import Labels From Cara File / Text File (``kind`` "cara" or "text";
        by default from the file's extension)."""
        return self.stack.push(file_commands.ImportLabels(self.project, path, kind))

    def import_brim(self, path: str | Path) -> Command:
        """File > Import Calibration Brim [svg] (a ``.csv`` of label,x,y,z in mm too):
        the brim model replaces the brim points."""
        from carapost.commands.process import ImportBrimSvg
        from carapost.io.errors import CaraFileError
        from carapost.io.take_import import read_brim_csv

        p = Path(path)
        suffix = p.suffix.lower()
        if suffix == ".svg":
            return self.stack.push(ImportBrimSvg(self.project, p))
        if suffix == ".csv":
            labels, xyz = read_brim_csv(p)
            return self.set_brim_model(labels, xyz, f"Import Calibration Brim {p.name}")
        raise CaraFileError(p, "a brim model must be a .svg or .csv file")

    def set_brim_model(self, labels: Sequence[str], xyz: NDArray,
                       description: str = "Set Calibration Brim") -> Command:
        """Replace the brim points by a brim model: labels and positions (B, 3) in mm."""
        from carapost.commands.process import SetBrimModel

        return self.stack.push(SetBrimModel(labels, xyz, description=description))

    def missing_files(self) -> dict[str, str]:
        """Cameras whose video does not exist: ``{camera name: path}``."""
        return file_commands.missing_files(self.project)

    def relocate_files(self, mapping: Mapping[str | int, str | Path] | str | Path) -> Command:
        """Edit > Relocate Files: other video files for some cameras.

        Parameters
        ----------
        mapping : mapping or path
            Camera name (or index) -> new video file or image-sequence folder; or a
            folder in which every missing video is looked for by its file name.

        Raises
        ------
        CommandError
            Unknown cameras, a video of another image size, or (folder) no missing
            video found there.
        CaraFileError
            A new file that does not exist or cannot be opened as a video.
        """
        command = self.stack.push(file_commands.RelocateFiles.of(self.project, mapping))
        self.close()  # the next image comes from the new files
        return command

    def export_options(self, **overrides: Any) -> ExportOptions:
        """The Export section of the Properties, with some options replaced."""
        return ExportOptions.from_properties(self.project.properties).with_overrides(
            **overrides)

    def export_c3d(self, path: str | Path, **overrides: Any) -> Path:
        """File > Export C3D with the Export properties (Export Range, Include Brim Points,
        Export Stabilized Coordinates); keyword ``frame_range``, ``include_brim`` or
        ``stabilized`` replaces one of them. See `carapost.export.export_c3d`."""
        from carapost.export import export_c3d

        o = self.export_options(**overrides)
        return export_c3d(self.project, path, frame_range=o.frame_range,
                          include_brim=o.include_brim, stabilized=o.stabilized)

    def export_fbx(self, path: str | Path, **overrides: Any) -> Path:
        """File > Export FBX with the Export properties (range, brim, FBX Up Axis, FBX
        Include Cameras, FBX Include Sticks, Export Stabilized Coordinates); keywords
        ``frame_range``, ``include_brim``, ``up_axis``, ``include_cameras``,
        ``include_sticks``, ``stabilized`` replace them.

        Cameras asked for by the property (not by a keyword) are left out, with a
        warning, when the project has no calibration.
        """
        from carapost.export import export_fbx

        o = self.export_options(**overrides)
        cameras = o.include_cameras
        if cameras and "include_cameras" not in overrides \
                and self.project.calibration.intrinsics is None:
            log.warning("Export FBX: FBX Include Cameras is on but the project has no camera "
                        "calibration; writing the points only")
            cameras = False
        return export_fbx(self.project, path, frame_range=o.frame_range,
                          include_brim=o.include_brim, up_axis=o.up_axis,
                          include_cameras=cameras, include_sticks=o.include_sticks,
                          stabilized=o.stabilized)

    def export_xcp(self, path: str | Path, frame: int | None = None) -> Path:
        """File > Export XCP [Current Frame] (or the cameras of ``frame``)."""
        from carapost.export import export_xcp

        return export_xcp(self.project, path, frame=frame)

    # ====================================================================================
    # Edit
    # ====================================================================================
    def create_points_from_detections(
            self, detections: Iterable[Sequence[int]] | None = None) -> Command:
        """Edit > Create Points From Detections (default: the selected detections)."""
        return self.stack.push(edit.CreatePointsFromDetections(self.project, detections))

    def delete_selected(self, point_ids: Iterable[int] | None = None,
                        detections: Iterable[Sequence[int]] | None = None) -> Command:
        """Edit > Delete Selected (Ctrl+D): points and/or detections (default: selected)."""
        return self.stack.push(edit.DeleteSelected(self.project, point_ids, detections))

    def split_selected_point(self, point_id: int | None = None,
                             frame: int | None = None) -> Command:
        """Edit > Split Selected Point (at the current frame by default)."""
        return self.stack.push(edit.SplitSelectedPoint(self.project, point_id, frame))

    def merge(self, point_ids: Iterable[int] | None = None,
              detections: Iterable[Sequence[int]] | None = None) -> Command:
        """Edit > Merge (M): points and/or detections into one point."""
        return self.stack.push(edit.Merge(self.project, point_ids, detections))

    def clear_selected(self, frames: str | Sequence[int] = "current",
                       point_ids: Iterable[int] | None = None) -> Command:
        """Edit > Clear Selected [Current Frame] / [Active Range] (or (first, last))."""
        p = self.project
        if isinstance(frames, str):
            which = one_of(frames, ("current", "active"), "Clear Selected: frames")
            ctor = (edit.ClearSelected.current_frame if which == "current"
                    else edit.ClearSelected.active_range)
            return self.stack.push(ctor(p, point_ids))
        rng = self.frame_range(frames, "Clear Selected")
        return self.stack.push(edit.ClearSelected(p, rng, point_ids))

    def clear_active_range(self) -> Command:
        """Edit > Clear Active Range: every point's data over the active range."""
        return self.stack.push(edit.ClearActiveRange(self.project))

    def detach_detections(self, frames: str = "current", *,
                          active_camera: int | None = None,
                          cameras: Iterable[int] | None = None,
                          point_ids: Iterable[int] | None = None) -> Command:
        """Edit > Detach Detections [Current Frame] (Ctrl+H) / [Active Range].

        The cameras are ``cameras`` when given; else, as in the window, the explicitly
        selected cameras, else ``active_camera`` (the window's active view).
        """
        which = one_of(frames, ("current", "active"), "Detach Detections: frames")
        p = self.project
        kw: dict[str, Any] = {} if point_ids is None else {"point_ids": point_ids}
        if cameras is not None:
            rng = self.frame_range(which, "Detach Detections")
            desc = ("Detach Detections [Current Frame]" if which == "current"
                    else "Detach Detections [Active Range]")
            cams = [int(c) for c in cameras]
            return self.stack.push(edit.DetachDetections(p, rng, cams, description=desc,
                                                         **kw))
        ctor = (edit.DetachDetections.current_frame if which == "current"
                else edit.DetachDetections.active_range)
        return self.stack.push(ctor(p, active_camera=active_camera, **kw))

    def increment_image_sequence_offset(self, cameras: Iterable[int] | None = None,
                                        step: int = 1) -> Command:
        """Edit > Increment Image Sequence Offset (the selected cameras by default)."""
        return self.stack.push(edit.IncrementImageSequenceOffset(self.project, cameras,
                                                                 step))

    def remove_unused_detections(self) -> Command:
        """Edit > Remove Unused Detections."""
        return self.stack.push(edit.RemoveUnusedDetections(self.project))

    def remove_interpolated_3d_points(self, point_ids: Iterable[int] | None = None) -> Command:
        """Edit > Remove Interpolated 3D Points (active range; selected or all points)."""
        return self.stack.push(edit.RemoveInterpolated3DPoints(self.project, point_ids))

    def rename_point(self, point_id: int, label: str) -> Command:
        """Edit > Rename Point (Ctrl+R)."""
        return self.stack.push(edit.RenamePoint(self.project, int(point_id), label))

    def rename_label(self, old: str, new: str) -> Command:
        """Labelling pane: rename a label (and the point that carries it)."""
        return self.stack.push(file_commands.RenameLabel(self.project, old, new))

    def assign_label(self, point_id: int, label: str) -> Command:
        """Labelling pane click: the point takes the label."""
        return self.stack.push(edit.AssignLabel(self.project, int(point_id), label))

    def clear_all_labels(self) -> Command:
        """Edit > Clear All Labels."""
        return self.stack.push(edit.ClearAllLabels(self.project))

    def delete_labels(self, names: Iterable[str]) -> Command:
        """Edit > Delete Selected Labels (the labels named)."""
        return self.stack.push(edit.DeleteSelectedLabels(self.project, list(names)))

    def unlabel_selected_points(self, point_ids: Iterable[int] | None = None) -> Command:
        """Edit > Unlabel Selected Points (Ctrl+U)."""
        return self.stack.push(edit.UnlabelSelectedPoints(self.project, point_ids))

    def create_stick(self, point_ids: Iterable[int] | None = None) -> Command:
        """Edit > Create Stick from Selected Point (S)."""
        return self.stack.push(edit.CreateStick(self.project, point_ids))

    def create_stick_mesh(self) -> Command:
        """Edit > Create Stick Mesh (Delaunay mesh of the face at the current frame)."""
        return self.stack.push(file_commands.CreateStickMesh(self.project))

    def edit_stick_color(self, sticks: Iterable[int], colour: tuple[int, int, int]) -> Command:
        """Edit > Edit Stick Color: sticks (indices) get an RGB colour."""
        return self.stack.push(edit.EditStickColor(self.project, list(sticks), colour))

    def rotate_sensors(self, cameras: Iterable[int] | None = None,
                       clockwise: bool = True) -> Command:
        """View > Rotate Selected Sensors Clockwise / Anticlockwise."""
        return self.stack.push(edit.RotateSelectedSensors(self.project, cameras,
                                                          clockwise=clockwise))

    # ====================================================================================
    # queries
    # ====================================================================================
    @property
    def caddies(self) -> tuple[tuple[int, ...], ...]:
        """The cameras of each caddy of this take (`carapost.model.rig.caddy_groups`)."""
        from carapost.model.rig import caddy_groups

        return caddy_groups(self.project.n_cameras, self.project.take.metadata)

    def __repr__(self) -> str:
        p = self.project
        name = Path(p.path).name if p.path else (p.take.name or "untitled")
        return (f"<Session {name}: {p.n_frames} frames, {p.n_cameras} cameras, "
                f"{p.n_points} points, {self.stack.position}/{len(self.stack)} History>")
