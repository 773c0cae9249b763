"""The main window: it lays out the workspace, timebar, docks, menus and status bar.

What the menu items do lives in :mod:`carapost.ui.handlers` (one module per menu),
called with the window's :class:`~carapost.ui.context.ActionContext`; the menus are
built from :data:`carapost.ui.actions.ACTIONS` and the docks from
:data:`carapost.ui.docks.PANES`. Every change of project data is a method of the open
project's :class:`~carapost.session.Session` (``context.session``); panes and views
follow the context's change signals.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QByteArray, QTimer
from PySide6.QtGui import QAction
from PySide6.QtWidgets import QDockWidget, QMainWindow, QVBoxLayout, QWidget

from carapost.commands.stack import CommandStack
from carapost.model.events import Change
from carapost.model.project import Project, new_project
from carapost.ui import actions as action_table
from carapost.ui.bridge import JobRunner, LogBridge
from carapost.ui.context import ActionContext, ViewContext
from carapost.ui.dialogs import Dialogs
from carapost.ui.docks import build_docks, pane_names
from carapost.ui.empty_state import EmptyHint
from carapost.ui.frames import FrameSource
from carapost.ui.handlers import file as file_menu
from carapost.ui.handlers import navigation
from carapost.ui.menus import MenuBar
from carapost.ui.settings import make_settings, recent_files
from carapost.ui.statusbar import JobStatus
from carapost.ui.timebar import Timebar
from carapost.ui.tracker_progress import TrackerProgress
from carapost.ui.workspace import FloatingWorkspace, Workspace

log = logging.getLogger("carapost.ui")

AUTOSAVE_MS = 120_000


class MainWindow(QMainWindow):
    """The carapost main window.

    Attributes
    ----------
    context : ActionContext
        What the handlers and panes work with (project, stack, dialogs, jobs).
    strict : bool
        Re-raise an exception of a menu handler after reporting it (tests set this, so
        a broken handler fails the test instead of only showing an error box).
    """

    def __init__(self, project: Project | None = None, *, restore: bool = True) -> None:
        super().__init__()
        self.setObjectName("carapost-main")
        self.setWindowTitle("carapost")
        self.settings = make_settings()
        self.context = ctx = ActionContext(Dialogs(self), self.settings, self)
        ctx.shell = self
        self.strict = False
        self.floating: list[FloatingWorkspace] = []
        self._docks_hidden: list[QDockWidget] = []

        # central: workspace above the timebar
        self.workspace = Workspace(ctx.view)
        self.timebar = Timebar()
        central = QWidget()
        lay = QVBoxLayout(central)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.setSpacing(0)
        lay.addWidget(self.workspace, 1)
        lay.addWidget(self.timebar)
        self.tracker_progress = TrackerProgress(ctx)   # below the play controls
        lay.addWidget(self.tracker_progress)
        self.setCentralWidget(central)
        self.empty_hint = EmptyHint(self.workspace, ctx)  # how to start, without a take
        # the timebar and the views (continuity chart, graphs) ask for frames and ranges
        self.timebar.frame_requested.connect(ctx.set_frame)
        ctx.view.frame_requested.connect(ctx.set_frame)
        self.timebar.range_dragged.connect(self._set_active_range)
        ctx.view.range_requested.connect(self._set_active_range)
        self.timebar.play_toggled.connect(ctx.playback.toggle)

        # panes, and the log records of the whole application in the Log pane
        self.docks = build_docks(self, ctx)
        self.log_bridge = LogBridge()
        self.log_bridge.signals.record.connect(self.pane("Log").add)
        logging.getLogger().addHandler(self.log_bridge)
        app_log = logging.getLogger("carapost")
        if app_log.level == logging.NOTSET or app_log.level > logging.INFO:
            app_log.setLevel(logging.INFO)

        # status bar: messages, point/selection summary, job progress + Cancel
        self.job_status = JobStatus(self.statusBar(), ctx)
        self.progress = self.job_status.progress
        self.cancel_button = self.job_status.cancel_button

        # menus from the action table; View > Panels from the dock table
        self.menu_bar = MenuBar(self, self._make_trigger)
        self.menus = self.menu_bar.menus
        for name in pane_names():
            self.menus["View/Panels"].addAction(self.docks[name].toggleViewAction())
        self.menus["File/Recent Files"].aboutToShow.connect(self._fill_recent)
        self._fill_recent()

        ctx.view.changed.connect(self._changed)
        ctx.history_changed.connect(self._update_actions)
        ctx.project_replaced.connect(self._project_replaced)
        ctx.playback.playing_changed.connect(self._playing_changed)
        self.autosave_timer = QTimer(self)
        self.autosave_timer.timeout.connect(lambda: file_menu.autosave(ctx))
        self.autosave_timer.start(AUTOSAVE_MS)

        self.resize(1600, 1000)
        if restore:
            self.restore_settings()
        self.set_project(project if project is not None else new_project(0, 0))

    # -- what scripts, the app and tests use ----------------------------------------------------
    @property
    def project(self) -> Project:
        """The open project."""
        return self.context.project

    @property
    def stack(self) -> CommandStack:
        """Undo history of the open project."""
        return self.context.stack

    @property
    def runner(self) -> JobRunner:
        """The worker that runs long jobs."""
        return self.context.runner

    @property
    def view_context(self) -> ViewContext:
        """State the views share."""
        return self.context.view

    @property
    def dialogs(self) -> Any:
        """Modal questions (tests put FakeDialogs here)."""
        return self.context.dialogs

    @dialogs.setter
    def dialogs(self, value: Any) -> None:
        self.context.dialogs = value

    @property
    def last_error(self) -> str:
        """Text of the last reported error."""
        return self.context.last_error

    def pane(self, name: str) -> Any:
        """The widget of a dock pane (``"History"``, ``"Log"``...)."""
        return self.docks[name].widget()

    def set_project(self, project: Project, frames: FrameSource | None = None) -> None:
        """Show another project (a fresh undo history)."""
        self.context.set_project(project, frames)

    def set_frames(self, frames: FrameSource) -> None:
        """Replace the image source (synthetic takes, tests, benchmarks)."""
        self.context.set_frames(frames)

    def set_frame(self, frame: int) -> None:
        """Move to a frame."""
        self.context.set_frame(frame)

    def open_project(self, path: str | None = None) -> bool:
        """File > Open."""
        return file_menu.open_project(self.context, path)

    def report_error(self, title: str, text: str, *, show: bool = True) -> None:
        """Log an error, show it in the status bar and (``show``) in a box."""
        self.context.report_error(title, text, show=show)

    def flush(self) -> None:
        """Deliver pending model changes now (tests and benchmarks)."""
        self.context.flush()

    def action(self, id_: str) -> QAction:
        """The QAction of an action-table id."""
        return self.menu_bar.actions[id_]

    # -- menus ----------------------------------------------------------------------------------
    def _make_trigger(self, spec: action_table.ActionSpec) -> Callable[[bool], None]:
        callback = spec.callback
        assert callback is not None

        def trigger(checked: bool = False) -> None:
            try:
                if spec.checkable:
                    callback(self.context, checked)
                else:
                    callback(self.context)
            except Exception as exc:  # a broken handler must never take the window down
                log.exception("%s failed", spec.title)
                self.report_error(spec.title, f"{spec.title} failed: {exc}")
                if self.strict:
                    raise
        return trigger

    def _fill_recent(self) -> None:
        self.menu_bar.fill_recent(recent_files(self.settings), self.open_project)

    # -- following the context --------------------------------------------------------------
    def _update_actions(self) -> None:
        st = self.stack
        undo, redo = self.action("edit.undo"), self.action("edit.redo")
        undo.setEnabled(st.can_undo)
        redo.setEnabled(st.can_redo)
        undo.setText(f"Undo {st.undo_text()}" if st.can_undo else "Undo")
        redo.setText(f"Redo {st.redo_text()}" if st.can_redo else "Redo")
        title = f"carapost - {self.context.project_name()}[*]"
        if title != self.windowTitle():
            self.setWindowTitle(title)
        # Qt re-sends the title to the window system on every call (an X11 round trip
        # per frame while playing): only when it changes
        if self.isWindowModified() != self.context.is_modified:
            self.setWindowModified(self.context.is_modified)

    def _changed(self, change: Change) -> None:
        self.timebar.refresh()
        self._update_actions()
        if change.parts & {"stabilization", "file"}:  # Stabilize Data switches it on
            self.action("view.show_stabilized").setChecked(self.project.show_stabilized)

    def _project_replaced(self) -> None:
        self.timebar.set_project(self.project)
        self._update_actions()
        opening = self.context.view.opening
        for view in self.all_views():
            # fitted in the view's slice of the opening, just before it is redrawn
            if not opening.defer(view, view.fit, "fit"):
                view.fit()

    def _set_active_range(self, a: int, b: int) -> None:
        navigation.set_active_range(self.context, a, b)

    def _playing_changed(self, playing: bool) -> None:
        self.timebar.set_playing(playing)
        self.action("view.play").setChecked(playing)

    # -- the Shell of the handlers (layout operations) ---------------------------------------
    def set_full_screen(self, on: bool) -> None:
        """Full Screen (F)."""
        if on:
            self.showFullScreen()
        else:
            self.showNormal()

    def toggle_docks(self) -> None:
        """Hide every dock (only the workspace and timebar), or show them again."""
        visible = [d for d in self.docks.values() if d.isVisible()]
        if visible:
            self._docks_hidden = visible
            for d in visible:
                d.hide()
        else:
            for d in self._docks_hidden or list(self.docks.values()):
                d.show()
            self._docks_hidden = []

    def new_floating_workspace(self) -> FloatingWorkspace:
        """A separate window with its own workspace (a 3D view to start with)."""
        fw = FloatingWorkspace(self.context.view, self)
        self.floating.append(fw)
        fw.destroyed.connect(lambda *_: self.floating.remove(fw) if fw in self.floating
                             else None)
        fw.workspace.refresh(None)
        fw.show()
        return fw

    def all_views(self) -> list[Any]:
        """Views of the main and the floating workspaces."""
        views = list(self.workspace.views())
        for fw in self.floating:
            views.extend(fw.workspace.views())
        return views

    # -- settings and closing ----------------------------------------------------------------
    def restore_settings(self) -> None:
        """Window geometry, dock layout, workspace and display options of the last run."""
        s = self.settings
        geo = s.value("window/geometry")
        if isinstance(geo, QByteArray | bytes) and geo:
            self.restoreGeometry(QByteArray(geo))
        state = s.value("window/state")
        if isinstance(state, QByteArray | bytes) and state:
            self.restoreState(QByteArray(state))
        specs = s.value("workspace/views")
        n = s.value("workspace/layout")
        if isinstance(specs, list) and specs:
            self.workspace.specs = [str(x) for x in specs]
        try:
            layout = int(n) if n is not None else self.workspace.n
        except (TypeError, ValueError):
            layout = self.workspace.n
        self.workspace.set_layout(layout, keep_specs=True)
        opts = s.value("display/options")
        if isinstance(opts, dict):
            self.context.view.options.update(opts)

    def save_settings(self) -> None:
        """Remember the layout for the next run."""
        s = self.settings
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState())
        self.workspace.specs_update()
        s.setValue("workspace/views", list(self.workspace.specs))
        s.setValue("workspace/layout", self.workspace.n)
        s.setValue("display/options", self.context.view.options.to_dict())
        s.sync()

    def closeEvent(self, ev) -> None:
        if not file_menu.maybe_save(self.context):
            ev.ignore()
            return
        self.shutdown()
        ev.accept()

    def shutdown(self) -> None:
        """Stop timers and workers, save settings, detach from logging."""
        self.autosave_timer.stop()
        self.save_settings()
        for fw in list(self.floating):
            fw.close()
        logging.getLogger().removeHandler(self.log_bridge)
        self.context.shutdown()  # playback, the worker, the session and its images
