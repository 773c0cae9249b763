"""The two contexts of a window.

* :class:`ViewContext` is what the views share: the project, images, display options and
  per-frame caches.
* :class:`ActionContext` is what the menu handlers (:mod:`carapost.ui.handlers`) and the
  panes work with: the view context plus the :class:`~carapost.session.Session` of the
  open project (its command stack and images), the dialogs, the job runner and the
  window's few layout operations (:class:`Shell`). Every change of project data is a
  Session method called through :meth:`ActionContext.act` (one undo entry, refusals
  reported), or, for long Process work, ``session.prepare`` on the GUI thread, the job
  on the worker and :meth:`ActionContext.apply` of its result; a new project arrives
  through :meth:`ActionContext.set_session` / :meth:`ActionContext.set_project`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, fields
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from PySide6.QtCore import QObject, QSettings, Qt, QTimer, Signal

from carapost.commands.recipe import Result
from carapost.commands.stack import CommandError, CommandStack
from carapost.io.errors import CaraFileError
from carapost.io.launcher import start_launcher
from carapost.model.events import Change
from carapost.model.project import Project, Selection, new_project
from carapost.session import Session
from carapost.ui.autosaver import Autosaver
from carapost.ui.bridge import JobRunner, ModelBridge
from carapost.ui.frames import FrameSource, frame_source_for
from carapost.ui.opening import OpenSlices
from carapost.ui.playback import Playback
from carapost.ui.proxies import ProxyBuilder
from carapost.ui.settings import (
    DISPLAY_PREFERENCES,
    build_proxies,
    frame_cache_mb,
    make_settings,
    preference,
    preference_signals,
    start_detector,
)
from carapost.ui.warm_start import start_detector_processes, start_detector_server

log = logging.getLogger("carapost.ui")
#: Milliseconds after a take opens before the blob detector's processes are started.
DETECTOR_START_DELAY_MS = 1000


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
    uncertainty: bool = False

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
    ("rays", "Rays"), ("rom", "ROM"), ("sticks", "Sticks"), ("uncertainty", "Uncertainty"),
)


class ViewContext(QObject):
    """Shared by every view of one window (and its floating workspaces).

    Signals
    -------
    changed(Change)
        The model changed (coalesced, GUI thread).
    options_changed()
        Display options, pre-selection, active camera or lock changed, or a Display
        preference of the user settings (point labels, font size).

    properties_requested(dict)
        A view asks for project properties to change (the owner pushes the undoable
        ``SetProperties``; see :meth:`edit_properties`).
    frame_ready(int, int)
        A decoded image of (frame, camera) arrived (queued onto the GUI thread).
    frame_requested(int)
        A view asks to go to a frame.
    range_requested(int, int)
        A view asks for this active range (Ctrl+drag on the continuity chart or graph).
    point_clicked(int, float, float)
        A click at image (x, y) of a camera in Add / Edit Target Track mode.
    keyframe_moved(int, int, float, float)
        A selected keyframe (camera, point id) was dragged to image (x, y).
    target_resized(int, int, str, float)
        A handle of a selected keyframe (camera, point id) was dragged: its pattern box
        or search cross ("pattern" / "search") is now this size (image px).
    live_changed()
        A Target Tracker run in progress has tracked another frame (:attr:`live_xy`).
    """

    changed = Signal(object)
    options_changed = Signal()
    properties_requested = Signal(object)
    frame_ready = Signal(int, int)
    frame_requested = Signal(int)
    range_requested = Signal(int, int)
    point_clicked = Signal(int, float, float)
    keyframe_moved = Signal(int, int, float, float)
    target_resized = Signal(int, int, str, float)
    live_changed = Signal()

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.project: Project = new_project(0, 0)
        #: Target Track point edit mode shown in the camera views ("add", "edit", "")
        self.point_mode = ""
        self.frames: FrameSource = FrameSource()
        #: threads closing earlier takes' frame services (joined at shutdown)
        self.closing: list[threading.Thread] = []
        self.options = DisplayOptions()
        self.preselected: int | None = None  # point id under the mouse
        self.active_camera: int | None = None
        self.lock_to_point = False
        self.show_stabilized = False
        #: playback runs (panes that follow the frame refresh less often meanwhile)
        self.playing = False
        #: during a Target Tracker run: the latest (frame, x, y) tracked of each (point id,
        #: camera), not yet in the model (the run's result writes it); None otherwise
        self.live_xy: dict[tuple[int, int], tuple[int, float, float]] | None = None
        self.live_direction = 1   # the run's: +1 forwards, -1 backwards
        self._proj_cache: dict[int, NDArray[np.float64] | None] = {}
        self._preview_cache: dict[tuple[int, int], Any] = {}
        #: the user settings the Display preferences are read from (the owner's, when
        #: it has one; a store of its own otherwise)
        self.settings: QSettings | None = None
        self._label_mode: tuple[QSettings, tuple[bool, bool, bool, int]] | None = None
        #: redraws deferred while a take opens, run one per event-loop turn; connected
        #: first, so a later change runs them before any listener sees it
        self.opening = OpenSlices(self)
        self.changed.connect(self.opening.change_arrived)
        self.changed.connect(self._invalidate)
        # a Display preference changed here or in another window: redraw the labels
        preference_signals().changed.connect(self._preference_changed)

    def _preference_changed(self, key: str) -> None:
        self._label_mode = None
        if key in DISPLAY_PREFERENCES:
            self.options_changed.emit()

    # -- caches ------------------------------------------------------------------------------
    def set_project(self, project: Project, frames: FrameSource) -> None:
        """Switch to another project."""
        old = self.frames
        if getattr(old, "asynchronous", False):
            # the old take's decoder threads finish the frame in hand before they stop:
            # the GUI thread does not wait for them
            closing = threading.Thread(target=old.close, name="carapost-close-frames",
                                       daemon=True)
            closing.start()
            # joined at shutdown: PyAV must not be closing a file while Python exits
            self.closing = [t for t in self.closing if t.is_alive()] + [closing]
        else:
            old.close()
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
        p = self.project
        cached = self._proj_cache.get(frame)
        # an entry made before a point was added (the change event is still queued) has
        # the old point count: recompute it
        if frame in self._proj_cache and (cached is None or len(cached) == p.n_points):
            return cached
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

    def user_settings(self) -> QSettings:
        """The user settings the Display preferences are read from and written to."""
        if self.settings is None:
            self.settings = make_settings()
        return self.settings

    def label_mode(self) -> tuple[bool, bool, bool, int]:
        """(all, selected, pre-selected, font size) from the Display preferences of the
        user settings (they are about the user, not the take).

        Read from the settings once per change of a preference (every camera view asks
        twice per frame drawn; four settings reads each time were ~0.1 ms)."""
        s = self.user_settings()
        cached = self._label_mode
        if cached is None or cached[0] is not s:
            cached = (s, (bool(preference(s, "point_labels_all")),
                          bool(preference(s, "point_labels_selected")),
                          bool(preference(s, "point_labels_preselected")),
                          int(preference(s, "label_font_size"))))
            self._label_mode = cached
        return cached[1]

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

    def edit_properties(self, values: dict[str, Any]) -> None:
        """Ask for project properties to change through the undoable command path."""
        self.properties_requested.emit(dict(values))


class Dialogs(Protocol):
    """The modal questions a handler may ask (:class:`carapost.ui.dialogs.Dialogs`)."""

    def open_file(self, title: str, filters: str, folder: bool = False) -> str | None: ...
    def save_file(self, title: str, filters: str, default: str = "") -> str | None: ...
    def ask_save(self, name: str) -> str: ...
    def confirm(self, title: str, text: str) -> bool: ...
    def get_int(self, title: str, label: str, value: int, lo: int, hi: int) -> int | None: ...
    def get_text(self, title: str, label: str, value: str = "") -> str | None: ...
    def get_colour(self, title: str) -> tuple[int, int, int] | None: ...
    def info(self, title: str, text: str) -> None: ...
    def error(self, title: str, text: str) -> None: ...


class Shell(Protocol):
    """The window's own layout operations that View-menu handlers need."""

    def set_full_screen(self, on: bool) -> None: ...
    def toggle_docks(self) -> None: ...
    def new_floating_workspace(self) -> Any: ...
    def all_views(self) -> list[Any]: ...
    def close(self) -> bool: ...


#: ``fn(progress)`` of a job; ``progress(done, total)`` returns False once cancelled.
JobFn = Callable[[Callable[[int, int], bool]], Any]


class ActionContext(QObject):
    """What menu handlers and panes get instead of the main window.

    Attributes
    ----------
    view : ViewContext
        The views' shared state (project, frame source, display options).
    session : Session
        The open project with its History; its images are the window's frame source.
    stack : CommandStack
        Undo history of the current project (``session.stack``).
    dialogs : Dialogs
        Modal questions (tests put :class:`FakeDialogs` here).
    runner : JobRunner
        The one worker thread for long jobs.
    settings : QSettings
        The user's settings (recent files).
    shell : Shell or None
        Layout operations of the window (full screen, docks, floating workspaces).
    label_selection : list of str
        Labels selected in the Labelling pane (Delete Selected Labels).
    point_mode : str
        Target Track point edit mode (``"add"``, ``"edit"`` or "").
    last_error : str
        Text of the last reported error (tests, status).

    Signals
    -------
    history_changed()
        The command stack changed (push, undo, redo, clear, new project).
    project_replaced()
        :meth:`set_project` switched to another project.
    status_message(str, int)
        Text for the status bar and its timeout in ms (0 = until replaced).
    """

    history_changed = Signal()
    project_replaced = Signal()
    status_message = Signal(str, int)

    def __init__(self, dialogs: Dialogs, settings: QSettings,
                 parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.view = ViewContext(self)
        self.view.settings = settings
        self.dialogs = dialogs
        self.settings = settings
        self.shell: Shell | None = None
        self.runner = JobRunner(self)
        self.bridge = ModelBridge(self)
        self.bridge.changed.connect(self.view.changed.emit)
        self.session = Session(self.view.project)
        self.label_selection: list[str] = []
        self.point_mode = ""
        self.last_error = ""
        self.view.properties_requested.connect(self.set_properties)
        self.view.point_clicked.connect(self._point_clicked)
        self.view.keyframe_moved.connect(self._keyframe_moved)
        self.view.target_resized.connect(self._target_resized)
        self.runner.failed.connect(self._job_failed)
        self.view.frame_ready.connect(self._frame_ready, Qt.ConnectionType.QueuedConnection)
        self.playback = Playback(self)
        self.proxies = ProxyBuilder(self)
        self.autosaver = Autosaver(self)
        start_launcher()  # every take's decoder threads start from it, not from here
        if start_detector(settings):
            # the detector processes' forkserver loads the detector once per program
            # (~1.3 s of a core): now, while no take is open, not beside a take's
            # first images and jumps (`carapost.ui.warm_start`)
            start_detector_server()

    def _point_clicked(self, camera: int, x: float, y: float) -> None:
        from carapost.ui.handlers.target import clicked

        clicked(self, camera, x, y)

    def _keyframe_moved(self, camera: int, point: int, x: float, y: float) -> None:
        self.act("Drag Keyframe", self.session.edit_target_track, point, camera,
                 self.project.current_frame, (x, y))

    def _target_resized(self, camera: int, point: int, kind: str, size: float) -> None:
        self.act("Target Track Size", self.session.set_target_track_size, point, camera,
                 **{kind: size})

    # -- state -------------------------------------------------------------------------------
    @property
    def project(self) -> Project:
        """The open project."""
        return self.view.project

    @property
    def frames(self) -> FrameSource:
        """Images of the open project."""
        return self.view.frames

    @property
    def selection(self) -> Selection:
        """The project's selection (view state: set directly, not undoable)."""
        return self.view.project.selection

    def project_name(self) -> str:
        """File name of the project, or the take's name before it is saved."""
        p = self.project
        return Path(p.path).name if p.path else p.take.name

    @property
    def is_modified(self) -> bool:
        """Whether the project has changes that are not saved."""
        return self.project.modified or not self.stack.is_clean

    @property
    def stack(self) -> CommandStack:
        """Undo history of the open project (the session's)."""
        return self.session.stack

    # -- the one path of model changes --------------------------------------------------------
    def set_project(self, project: Project, frames: FrameSource | None = None) -> None:
        """Show another project with a fresh undo history (Import, Clear, tests)."""
        self.set_session(Session(project), frames)

    def set_session(self, session: Session, frames: FrameSource | None = None) -> None:
        """Show the project of ``session`` (Open, Import): the window acts through it.

        ``frames`` (default: the project's videos) becomes the session's image source.

        In a window on screen the views and panes are then redrawn in slices, one per
        event-loop turn (`carapost.ui.opening`), while the decoders already work on
        the first images.
        """
        self.playback.stop()
        shell = self.shell
        opening = self.view.opening
        opening.begin(visible=shell is not None and shell.isVisible())
        try:
            self._switch_session(session, frames)
        finally:  # the deferred redraws run even when the switch failed half-way
            sensors = [v for v in shell.all_views() if v.kind == "sensor"] if shell else []
            opening.start(images=sensors if self.view.frames.asynchronous else ())

    def _switch_session(self, session: Session, frames: FrameSource | None) -> None:
        self.bridge.detach()
        self.session.close()
        self.session = session
        session.stack.on_change = self.history_changed.emit
        project = session.project
        if frames is None:
            frames = self.video_frames(project)
        self.proxies.stop()
        self.view.set_project(project, frames)
        if project.n_frames and frames.asynchronous:
            # the first images are the longest wait: the decoders start before anything
            # is redrawn
            frames.request(project.current_frame, None)
        self._bind_images()
        self._start_proxies()
        if self.view.frames.has_images and start_detector(self.settings):
            # the first Detect Blobs finds them ready; started once the take is on
            # screen, so their start-up does not compete with the first images
            QTimer.singleShot(DETECTOR_START_DELAY_MS, self, start_detector_processes)
        self.bridge.attach(project)
        self.project_replaced.emit()
        self.view.changed.emit(Change(frozenset({"file"})))
        self.history_changed.emit()

    def _bind_images(self) -> None:
        # the session reads what the views show (GUI thread); jobs get a worker copy
        frames = self.view.frames
        self.session.set_image_source(frames.require if frames.has_images else None)

    def _start_proxies(self) -> None:
        # Proxies already written are used at once; missing ones are written in the
        # background when the user wants that (View > Build Playback Proxies otherwise).
        frames = self.view.frames
        if not hasattr(frames, "attach_proxies"):
            return
        if build_proxies(self.settings):
            self.proxies.start(frames)
        else:
            # in a slice of its own: opening the proxies reads their keyframe indexes
            QTimer.singleShot(0, self, lambda: frames is self.view.frames
                              and frames.attach_proxies())

    def set_frames(self, frames: FrameSource) -> None:
        """Replace the image source (Relocate Files, synthetic takes, tests)."""
        self.proxies.stop()
        self.view.frames.close()
        self.view.frames = frames
        self._bind_images()
        self._start_proxies()
        for view in self.shell.all_views() if self.shell is not None else ():
            view.refresh(None)

    def reload_frames(self) -> None:
        """Open the project's videos again (after their paths changed)."""
        self.set_frames(self.video_frames(self.project))

    def video_frames(self, project: Project) -> FrameSource:
        """The frame service of ``project``'s videos, its cache sized by the user's
        setting (none when the take has no videos)."""
        return frame_source_for(project, on_ready=self.on_frame_ready,
                                cache_mb=frame_cache_mb(self.settings))

    def refuse_busy(self, what: str) -> bool:
        """True (and the refusal shown in the status bar) while a job is running."""
        if self.runner.busy:
            self.report_error("Busy", f"{what}: wait for {self.runner.title} to finish (or "
                              "cancel it)", show=False)
            return True
        return False

    def act(self, title: str, action: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Call a Session method (``ctx.act("Merge", ctx.session.merge)``): one History
        entry, or a refusal logged (red) and shown in the status bar.

        Returns what the method returned, or None when it refused (a file that cannot
        be read is shown in a box too) or a job is running.
        """
        if self.refuse_busy(title):
            return None
        try:
            return action(*args, **kwargs)
        except CommandError as exc:
            self.report_error(title, str(exc), show=False)
        except CaraFileError as exc:
            self.report_error(title, str(exc))
        return None

    def apply(self, result: Result) -> bool:
        """Push the result of a Process job (``session.apply``) on the GUI thread."""
        return self.act(result.description, self.session.apply, result) is not None

    def run_job(self, title: str, fn: JobFn, done: Callable[[Any, bool], None]) -> bool:
        """Run ``fn(progress)`` on the worker; ``done(result, cancelled)`` on the GUI thread.

        For work that is not a Process job (reading a take, writing an export). False
        when another job is still running.
        """
        return self.runner.start(title, fn, done)

    def set_properties(self, values: dict[str, Any]) -> bool:
        """Change project properties (``session.set_properties``, one undo entry)."""
        return self.act("Set property", self.session.set_properties, values) is not None

    # -- feedback ----------------------------------------------------------------------------
    def report_error(self, title: str, text: str, *, show: bool = True) -> None:
        """Log an error (red in the Log pane), show it in the status bar and, once, a box."""
        log.error("%s", text)
        self.status(text, 8000)
        self.last_error = text
        if show:
            self.dialogs.error(title, text)

    def _job_failed(self, title: str, message: str) -> None:
        self.last_error = message  # the runner has logged it with its traceback
        self.dialogs.error(title, message)

    def status(self, text: str, ms: int = 4000) -> None:
        """A message in the status bar."""
        self.status_message.emit(text, ms)

    # -- frames ------------------------------------------------------------------------------
    def set_frame(self, frame: int) -> None:
        """Move to a frame (clamped to the take); prefetches ahead while playing."""
        p = self.project
        if p.n_frames == 0:
            return
        frame = min(max(int(frame), 0), p.n_frames - 1)
        step = frame - p.current_frame
        # The decoders start before the views redraw; a step sets the read-ahead's
        # direction, a jump keeps it.
        self.frames.request(frame, None, direction=step if abs(step) == 1 else 0)
        p.set_current_frame(frame)

    def on_frame_ready(self, frame: int, camera: int) -> None:
        """Decoder-thread callback: hop to the GUI thread through a queued signal.

        Only for the current frame: the read-ahead decodes dozens of frames that no
        view waits for, and each signal would wake the GUI thread for nothing (a view
        that moves to such a frame finds its image in the cache; the image cached
        before the frame changes is found there, the one after is signalled).
        """
        try:
            if frame != self.project.current_frame:
                return
            self.view.frame_ready.emit(frame, camera)
        except RuntimeError:  # the context is already gone at shutdown
            pass

    def _frame_ready(self, frame: int, camera: int) -> None:
        if frame != self.project.current_frame or self.shell is None:
            return
        for view in self.shell.all_views():
            if view.kind == "sensor" and view.camera == camera:
                landed = getattr(view, "image_landed", None)
                show = (partial(landed, frame) if landed is not None
                        else partial(view.refresh, None))
                opening = self.view.opening
                # while a take opens, each first image is shown in a turn of its own
                # (the four decoders deliver them together); a view whose slice is
                # still pending is drawn whole, with its image
                if not (opening.deliver(view, show) or opening.run(view)):
                    show()

    def flush(self) -> None:
        """Deliver pending model changes now (tests and benchmarks)."""
        self.bridge.flush()

    def shutdown(self) -> None:
        """Stop playback and the worker, stop listening, close the images."""
        self.playback.stop()
        self.proxies.stop()
        self.autosaver.wait()
        if self.runner.busy:
            self.runner.cancel()
            self.runner.wait(30)
        self.bridge.detach()
        self.session.close()
        self.view.frames.close()
        for closing in self.view.closing:
            closing.join(10)
