"""The main window: menus from the action table, workspace, timebar, panes, processing.

The window owns one project and its :class:`~carapost.commands.stack.CommandStack`.
Every change to project data goes through :meth:`MainWindow.push`; model change
events come back through :class:`~carapost.ui.bridge.ModelBridge` and redraw the views
and panes. Current frame and selection are set directly on the model (they are view
state, not undoable edits).
"""

from __future__ import annotations

import importlib
import inspect
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from PySide6.QtCore import QByteArray, Qt, QTimer, QUrl
from PySide6.QtGui import QAction, QDesktopServices, QKeySequence
from PySide6.QtWidgets import (
    QColorDialog,
    QDockWidget,
    QFileDialog,
    QInputDialog,
    QLabel,
    QMainWindow,
    QMenu,
    QMessageBox,
    QProgressBar,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from carapost.commands import edit
from carapost.commands.stack import Command, CommandError, CommandStack
from carapost.model import queries
from carapost.model.events import Change
from carapost.model.project import Project, new_project
from carapost.ui import actions as action_table
from carapost.ui.bridge import JobRunner, LogBridge, ModelBridge
from carapost.ui.context import ViewContext
from carapost.ui.frames import FrameSource, frame_source_for
from carapost.ui.panes import (
    HistoryPane,
    LabellingPane,
    LogPane,
    PropertiesPane,
    SelectedPointPane,
    SelectionPane,
    TrackerPane,
)
from carapost.ui.settings import add_recent_file, clear_recent_files, make_settings, recent_files
from carapost.ui.timebar import Timebar
from carapost.ui.workspace import FloatingWorkspace, Workspace

log = logging.getLogger("carapost.ui")

CARA_FILTER = "carapost projects (*.cara);;All files (*)"
AUTOSAVE_MS = 120_000
THIRD_PARTY = (
    ("PySide6 (Qt for Python)", "LGPL-3.0"), ("numpy", "BSD-3-Clause"),
    ("scipy", "BSD-3-Clause"), ("opencv-python-headless", "Apache-2.0 (OpenCV), MIT"),
    ("pyqtgraph", "MIT"), ("ezc3d", "MIT"), ("lxml", "BSD-3-Clause"),
)


class Dialogs:
    """Every modal question the window asks, in one place (tests replace it)."""

    def __init__(self, parent: QWidget) -> None:
        self.parent = parent

    def open_file(self, title: str, filters: str, folder: bool = False) -> str | None:
        """A path to read, or None."""
        if folder:
            path = QFileDialog.getExistingDirectory(self.parent, title)
        else:
            path, _ = QFileDialog.getOpenFileName(self.parent, title, "", filters)
        return path or None

    def save_file(self, title: str, filters: str, default: str = "") -> str | None:
        """A path to write, or None."""
        path, _ = QFileDialog.getSaveFileName(self.parent, title, default, filters)
        return path or None

    def ask_save(self, name: str) -> str:
        """``"save"``, ``"discard"`` or ``"cancel"`` for unsaved changes."""
        box = QMessageBox.question(
            self.parent, "Unsaved changes", f"Save the changes to {name}?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard
            | QMessageBox.StandardButton.Cancel)
        return {QMessageBox.StandardButton.Save: "save",
                QMessageBox.StandardButton.Discard: "discard"}.get(box, "cancel")

    def confirm(self, title: str, text: str) -> bool:
        """Yes/no question."""
        return QMessageBox.question(self.parent, title, text) == QMessageBox.StandardButton.Yes

    def get_int(self, title: str, label: str, value: int, lo: int, hi: int) -> int | None:
        """A whole number, or None."""
        v, ok = QInputDialog.getInt(self.parent, title, label, value, lo, hi)
        return int(v) if ok else None

    def get_text(self, title: str, label: str, value: str = "") -> str | None:
        """A line of text, or None."""
        v, ok = QInputDialog.getText(self.parent, title, label, text=value)
        return v if ok else None

    def get_colour(self, title: str) -> tuple[int, int, int] | None:
        """An RGB colour, or None."""
        c = QColorDialog.getColor(parent=self.parent, title=title)
        return (c.red(), c.green(), c.blue()) if c.isValid() else None

    def info(self, title: str, text: str) -> None:
        """A message that does not block."""
        self._box(QMessageBox.Icon.Information, title, text)

    def error(self, title: str, text: str) -> None:
        """An error message that does not block."""
        self._box(QMessageBox.Icon.Critical, title, text)

    def _box(self, icon: QMessageBox.Icon, title: str, text: str) -> None:
        box = QMessageBox(icon, title, text, QMessageBox.StandardButton.Ok, self.parent)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        box.setModal(False)
        box.show()


class MainWindow(QMainWindow):
    """The carapost main window."""

    def __init__(self, project: Project | None = None, *, restore: bool = True) -> None:
        super().__init__()
        self.setObjectName("carapost-main")
        self.setWindowTitle("carapost")
        self.settings = make_settings()
        self.dialogs = Dialogs(self)
        self.ctx = ViewContext(self)
        self.bridge = ModelBridge(self)
        self.bridge.changed.connect(self._on_change)
        self.runner = JobRunner(self)
        self.project: Project = new_project(0, 0)
        self.stack = CommandStack(self.project)
        self.floating: list[FloatingWorkspace] = []
        self.point_mode = ""
        self.last_error = ""
        self._docks_hidden: list[QDockWidget] = []

        # central: workspace above the timebar
        self.workspace = Workspace(self.ctx)
        self.timebar = Timebar()
        central = QWidget()
        lay = QVBoxLayout(central)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.setSpacing(0)
        lay.addWidget(self.workspace, 1)
        lay.addWidget(self.timebar)
        self.setCentralWidget(central)
        self.timebar.frame_requested.connect(self.set_frame)
        self.timebar.range_dragged.connect(self.set_active_range)
        self.timebar.play_toggled.connect(self.toggle_play)
        self.workspace.active_changed.connect(self._view_activated)

        # panes
        self.log_pane = LogPane()
        self.log_bridge = LogBridge()
        self.log_bridge.signals.record.connect(self.log_pane.add)
        root = logging.getLogger()
        root.addHandler(self.log_bridge)
        app_log = logging.getLogger("carapost")
        if app_log.level == logging.NOTSET or app_log.level > logging.INFO:
            app_log.setLevel(logging.INFO)
        self.labelling = LabellingPane(self)
        self.history = HistoryPane(self)
        self.selected_point = SelectedPointPane(self)
        self.properties = PropertiesPane(self)
        self.selection_pane = SelectionPane(self)
        self.tracker = TrackerPane(self)
        self.docks: dict[str, QDockWidget] = {}
        areas = {"Labelling": Qt.DockWidgetArea.RightDockWidgetArea,
                 "History": Qt.DockWidgetArea.RightDockWidgetArea,
                 "Selected Point": Qt.DockWidgetArea.BottomDockWidgetArea,
                 "Log": Qt.DockWidgetArea.BottomDockWidgetArea,
                 "Properties": Qt.DockWidgetArea.LeftDockWidgetArea,
                 "Selection": Qt.DockWidgetArea.LeftDockWidgetArea,
                 "Tracker": Qt.DockWidgetArea.LeftDockWidgetArea}
        widgets = {"Labelling": self.labelling, "History": self.history,
                   "Selected Point": self.selected_point, "Log": self.log_pane,
                   "Properties": self.properties, "Selection": self.selection_pane,
                   "Tracker": self.tracker}
        for name in action_table.PANELS:
            dock = QDockWidget(name, self)
            dock.setObjectName(f"dock-{name}")
            dock.setWidget(widgets[name])
            self.addDockWidget(areas[name], dock)
            self.docks[name] = dock
        self.tabifyDockWidget(self.docks["Properties"], self.docks["Selection"])
        self.tabifyDockWidget(self.docks["Properties"], self.docks["Tracker"])
        self.docks["Properties"].raise_()
        self.splitDockWidget(self.docks["Log"], self.docks["Selected Point"],
                             Qt.Orientation.Horizontal)
        self.resizeDocks([self.docks["Properties"], self.docks["Labelling"]], [330, 260],
                         Qt.Orientation.Horizontal)
        self.resizeDocks([self.docks["Log"]], [170], Qt.Orientation.Vertical)

        # status bar: message, frame/selection summary, progress + Cancel
        self.status_label = QLabel()
        self.progress = QProgressBar()
        self.progress.setMaximumWidth(260)
        self.progress.hide()
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.hide()
        self.cancel_button.clicked.connect(self.runner.cancel)
        self.statusBar().addPermanentWidget(self.status_label)
        self.statusBar().addPermanentWidget(self.progress)
        self.statusBar().addPermanentWidget(self.cancel_button)
        self.runner.started.connect(self._job_started)
        self.runner.progressed.connect(self._job_progress)
        self.runner.finished.connect(self._job_finished)
        self.runner.failed.connect(self._job_failed)
        self.ctx.frame_ready.connect(self._frame_ready, Qt.ConnectionType.QueuedConnection)

        # menus
        self.actions_by_id: dict[str, QAction] = {}
        self.menus: dict[str, QMenu] = {}
        self._build_menus()

        # playback and autosave
        self.play_timer = QTimer(self)
        self.play_timer.timeout.connect(self._play_tick)
        self.autosave_timer = QTimer(self)
        self.autosave_timer.timeout.connect(self.autosave)
        self.autosave_timer.start(AUTOSAVE_MS)

        self.resize(1600, 1000)
        if restore:
            self.restore_settings()
        self.set_project(project if project is not None else new_project(0, 0))

    # ======================================================================================
    # menus
    # ======================================================================================
    def _menu(self, path: str) -> QMenu:
        if path in self.menus:
            return self.menus[path]
        parent, _, name = path.rpartition("/")
        if parent:
            menu = self._menu(parent).addMenu(name)
        else:
            menu = self.menuBar().addMenu(name)
        menu.setToolTipsVisible(True)
        self.menus[path] = menu
        return menu

    def _build_menus(self) -> None:
        for top in action_table.MENUS:
            self._menu(top)
        for spec in action_table.ACTIONS:
            if not spec.title:  # a submenu placeholder
                parent = self._menu(spec.menu.rpartition("/")[0])
                if spec.separator:
                    parent.addSeparator()
                self._menu(spec.menu)
                continue
            menu = self._menu(spec.menu)
            if spec.separator:
                menu.addSeparator()
            act = QAction(spec.title, self)
            act.setObjectName(spec.id)
            if spec.shortcut:
                act.setShortcut(QKeySequence(spec.shortcut))
                act.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
            act.setCheckable(spec.checkable)
            available = action_table.requirement_met(spec.requires)
            if available:
                act.setToolTip(spec.tip or spec.title)
            else:
                act.setEnabled(False)
                act.setToolTip(action_table.NOT_AVAILABLE)
                act.setStatusTip(f"{spec.title}: {action_table.NOT_AVAILABLE}")
            act.setProperty("available", available)
            act.triggered.connect(self._make_trigger(spec))
            menu.addAction(act)
            self.addAction(act)  # shortcuts work with the menu bar hidden (full screen)
            self.actions_by_id[spec.id] = act
        panels = self.menus["View/Panels"]
        for name in action_table.PANELS:
            panels.addAction(self.docks[name].toggleViewAction())
        self.menus["File/Recent Files"].aboutToShow.connect(self._fill_recent)
        self._fill_recent()

    def _make_trigger(self, spec: action_table.ActionSpec) -> Callable[[bool], None]:
        def trigger(checked: bool = False) -> None:
            handler = getattr(self, spec.handler)
            try:
                if spec.checkable:
                    handler(checked)
                elif spec.arg or spec.handler in ("point_edit_mode",):
                    handler(spec.arg)
                else:
                    handler()
            except Exception as exc:  # a broken handler must never take the window down
                log.exception("%s failed", spec.title)
                self.report_error(spec.title, f"{spec.title} failed: {exc}")
        return trigger

    def _fill_recent(self) -> None:
        menu = self.menus["File/Recent Files"]
        menu.clear()
        files = recent_files(self.settings)
        for path in files:
            menu.addAction(path, lambda p=path: [self.open_project(p)] and None)
        if not files:
            act = menu.addAction("(none)")
            act.setEnabled(False)

    def action(self, id_: str) -> QAction:
        """The QAction of an action-table id."""
        return self.actions_by_id[id_]

    def _update_actions(self) -> None:
        st = self.stack
        undo, redo = self.action("edit.undo"), self.action("edit.redo")
        undo.setEnabled(st.can_undo)
        redo.setEnabled(st.can_redo)
        undo.setText(f"Undo {st.undo_text()}" if st.can_undo else "Undo")
        redo.setText(f"Redo {st.redo_text()}" if st.can_redo else "Redo")
        self.setWindowModified(not st.is_clean or self.project.modified)

    # ======================================================================================
    # project and model events
    # ======================================================================================
    def set_project(self, project: Project, frames: FrameSource | None = None) -> None:
        """Show another project (a fresh undo history)."""
        self.stop_play()
        self.bridge.detach()
        self.project = project
        self.stack = CommandStack(project, on_change=self._stack_changed)
        if frames is None:
            frames = frame_source_for(project, on_ready=self._on_frame_ready)
        self.ctx.set_project(project, frames)
        self.bridge.attach(project)
        self.timebar.set_project(project)
        name = Path(project.path).name if project.path else project.take.name
        self.setWindowTitle(f"carapost - {name}[*]")
        self._on_change(None)
        self._stack_changed()
        for view in self.workspace.views():
            view.fit()

    def set_frames(self, frames: FrameSource) -> None:
        """Replace the image source (synthetic takes, tests, benchmarks)."""
        self.ctx.frames.close()
        self.ctx.frames = frames
        self.workspace.refresh(None)

    def _on_frame_ready(self, frame: int, camera: int) -> None:
        # called on a decoder thread: hop to the GUI thread through a queued signal
        try:
            self.ctx.frame_ready.emit(frame, camera)
        except RuntimeError:
            pass

    def _frame_ready(self, frame: int, camera: int) -> None:
        if frame == self.project.current_frame:
            for view in self.workspace.views():
                if view.kind == "sensor" and view.camera == camera:
                    view.refresh(None)

    def _on_change(self, change: Change | None) -> None:
        if change is not None:
            self.ctx.changed.emit(change)
        else:
            self.workspace.refresh(None)
            self.ctx.changed.emit(Change(frozenset({"file"})))
        for fw in self.floating:
            fw.workspace.refresh(change)
        parts = change.parts if change is not None else None
        if parts is None or parts & {"labels", "current_frame", "points", "point_list", "file"}:
            self.labelling.refresh(change)
        if parts is None or parts & {"properties", "file"}:
            self.properties.refresh(None)
            self.tracker.settings.refresh(None)
        if parts is None or parts & {"selection", "cameras", "file"}:
            self.selection_pane.refresh(change)
        self.selected_point.refresh(change)
        self.timebar.refresh()
        sel = self.project.selection
        self.status_label.setText(f"{self.project.n_points} points | "
                                  f"{len(sel.points)} selected")
        self._update_actions()

    def flush(self) -> None:
        """Deliver pending model changes now (tests and benchmarks)."""
        self.bridge.flush()

    def _stack_changed(self) -> None:
        self.history.refresh()
        self._update_actions()

    # ======================================================================================
    # commands
    # ======================================================================================
    def push(self, command: Command | None) -> bool:
        """Run a command as one undo entry; refusals are logged (red) and shown in the bar."""
        if command is None:
            return False
        if self.runner.busy:
            self.report_error("Busy", f"{command.description}: wait for "
                              f"{self.runner.title} to finish (or cancel it)", show=False)
            return False
        try:
            self.stack.push(command)
        except CommandError as exc:
            self.report_error(command.description, str(exc), show=False)
            return False
        return True

    def make_and_push(self, factory: Callable[[], Command], what: str) -> bool:
        """Build a command (its constructor validates) and push it."""
        try:
            command = factory()
        except CommandError as exc:
            self.report_error(what, str(exc), show=False)
            return False
        return self.push(command)

    def report_error(self, title: str, text: str, *, show: bool = True) -> None:
        """Log an error (red in the Log pane), show it in the status bar and, once, a box."""
        logging.getLogger("carapost.ui").error("%s", text)
        self.statusBar().showMessage(text, 8000)
        self.last_error = text
        if show:
            self.dialogs.error(title, text)

    def edit_command(self, name: str) -> None:
        """Run an Edit-menu command by name (``"Merge"``, ``"ClearSelected.current_frame"``)."""
        cls_name, _, ctor = name.partition(".")
        target: Any = getattr(edit, cls_name, None)
        if target is None:
            self.report_error(name, f"{name}: {action_table.NOT_AVAILABLE}", show=False)
            return
        factory = getattr(target, ctor) if ctor else target
        self.make_and_push(lambda: factory(self.project), name)

    def set_properties(self, values: dict[str, Any]) -> None:
        """Change properties through an undoable command."""
        self.make_and_push(lambda: edit.SetProperties(self.project, values), "Set property")

    def undo(self) -> None:
        """Edit > Undo."""
        if not self.runner.busy:
            self.stack.undo()

    def redo(self) -> None:
        """Edit > Redo."""
        if not self.runner.busy:
            self.stack.redo()

    def goto_history(self, position: int) -> None:
        """History pane click: undo/redo until ``position`` commands are applied."""
        if not self.runner.busy:
            self.stack.goto(position)

    def clear_history(self) -> None:
        """Edit > Clear History (logs the memory freed)."""
        freed = self.stack.clear()
        self.statusBar().showMessage(f"History cleared: {freed / 1e6:.1f} MB freed", 5000)

    def detach(self, which: str) -> None:
        """Detach Detections [Current Frame] / [Active Range]."""
        ctor = (edit.DetachDetections.current_frame if which == "current"
                else edit.DetachDetections.active_range)
        self.make_and_push(lambda: ctor(self.project, active_camera=self.ctx.active_camera),
                           "Detach Detections")

    def delete_selected_labels(self) -> None:
        """Delete Selected Labels (those selected in the Labelling pane)."""
        names = self.labelling.selected_labels()
        self.make_and_push(lambda: edit.DeleteSelectedLabels(self.project, names),
                           "Delete Selected Labels")

    def rename_point(self) -> None:
        """Rename Point (Ctrl+R)."""
        sel = self.project.selection.points
        if len(sel) != 1:
            self.report_error("Rename Point", "Rename Point: select exactly one point",
                              show=False)
            return
        pid = next(iter(sel))
        col = int(self.project.points.index_of([pid])[0])
        text = self.dialogs.get_text("Rename Point", f"Label of point {pid}:",
                                     self.project.points.labels[col])
        if text is not None:
            self.make_and_push(lambda: edit.RenamePoint(self.project, pid, text), "Rename Point")

    def create_stick_mesh(self) -> None:
        """Create Stick Mesh."""
        from carapost.ui.uicommands import CreateStickMesh

        self.make_and_push(lambda: CreateStickMesh(self.project), "Create Stick Mesh")

    def edit_stick_color(self) -> None:
        """Edit Stick Color: sticks between selected points get a new colour."""
        p = self.project
        sel = p.selection.points
        idx = [i for i, s in enumerate(p.sticks) if s.a in sel and s.b in sel]
        if not idx:
            self.report_error("Edit Stick Color", "Edit Stick Color: select the points at "
                              "both ends of a stick", show=False)
            return
        colour = self.dialogs.get_colour("Stick colour")
        if colour is not None:
            self.make_and_push(lambda: edit.EditStickColor(p, idx, colour), "Edit Stick Color")

    def relocate_files(self) -> None:
        """Relocate Files: choose the video of each camera."""
        from carapost.ui.uicommands import RelocateVideos

        paths: dict[int, str] = {}
        for c, cam in enumerate(self.project.take.cameras):
            path = self.dialogs.open_file(f"Video of camera {cam.name} (was {cam.video_path})",
                                          "Videos (*.mkv *.avi *.mp4 *.mov);;All files (*)")
            if path:
                paths[c] = path
        if paths and self.make_and_push(lambda: RelocateVideos(self.project, paths),
                                        "Relocate Files"):
            self.set_frames(frame_source_for(self.project, on_ready=self._on_frame_ready))

    def point_edit_mode(self, mode: str) -> None:
        """Add / Edit Target Track modes ("" stops them)."""
        self.point_mode = mode
        text = {"add": "Add Target Track", "edit": "Edit Target Track"}.get(mode, "")
        self.statusBar().showMessage(text or "Point edit mode stopped", 3000)

    def target_track(self, name: str) -> None:
        """Tracker pane buttons (wired by the target-tracker module)."""
        self.run_process(f"target_track_{name}")

    # ======================================================================================
    # files
    # ======================================================================================
    def maybe_save(self) -> bool:
        """Ask about unsaved changes; False if the user cancelled."""
        if not (self.project.modified or not self.stack.is_clean) or self.project.n_frames == 0:
            return True
        name = Path(self.project.path).name if self.project.path else self.project.take.name
        answer = self.dialogs.ask_save(name)
        if answer == "cancel":
            return False
        if answer == "save":
            return self.save_project()
        return True

    def open_project(self, path: str | None = None) -> bool:
        """File > Open (Ctrl+O); offers the autosave copy when it is newer."""
        from carapost.io.cara import load_project, recoverable_autosave
        from carapost.io.errors import CaraFileError

        if not self.maybe_save():
            return False
        if path is None:
            path = self.dialogs.open_file("Open project", CARA_FILTER)
            if not path:
                return False
        source = path
        auto = recoverable_autosave(path)
        if auto is not None and self.dialogs.confirm(
                "Recover", f"An autosaved copy of {Path(path).name} is newer than the file "
                "(the program may have stopped unexpectedly). Open the autosaved copy?"):
            source = str(auto)

        def relocate(camera: str, missing: str) -> str | None:
            return self.dialogs.open_file(f"Find the video of camera {camera} ({missing})",
                                          "Videos (*.mkv *.avi *.mp4 *.mov);;All files (*)")
        try:
            project = load_project(source, relocate=relocate)
        except CaraFileError as exc:
            self.report_error("Open", str(exc))
            return False
        project.path = str(Path(path).absolute())
        project.modified = source != path
        self.set_project(project)
        if project.modified:
            self.stack._clean_position = None  # recovered: unsaved until saved
            self._update_actions()
        add_recent_file(self.settings, project.path)
        log.info("Opened %s", path)
        return True

    def clear_project(self) -> None:
        """File > Clear: close the project."""
        if self.maybe_save():
            self.set_project(new_project(0, 0))

    def save_project(self) -> bool:
        """File > Save (Ctrl+S)."""
        if self.project.path is None:
            return self.save_project_as()
        return self._save_to(self.project.path)

    def save_project_as(self) -> bool:
        """File > Save As."""
        path = self.dialogs.save_file("Save project", CARA_FILTER,
                                      self.project.path or f"{self.project.take.name}.cara")
        return bool(path) and self._save_to(path)

    def _save_to(self, path: str) -> bool:
        from carapost.io.cara import save_project
        from carapost.io.errors import CaraFileError

        try:
            written = save_project(self.project, path)
        except (CaraFileError, OSError) as exc:
            self.report_error("Save", str(exc))
            return False
        self.stack.mark_clean()
        self._update_actions()
        add_recent_file(self.settings, str(written))
        name = Path(written).name
        self.setWindowTitle(f"carapost - {name}[*]")
        self.statusBar().showMessage(f"Saved {written}", 4000)
        return True

    def autosave(self) -> None:
        """Write the autosave copy beside the project when there are unsaved changes."""
        from carapost.io.cara import autosave_project

        if self.project.path and (self.project.modified or not self.stack.is_clean) \
                and not self.runner.busy:
            try:
                autosave_project(self.project)
            except Exception as exc:  # autosave must never interrupt work
                log.warning("autosave failed: %s", exc)

    def clear_recent(self) -> None:
        """File > Clear Recent Files."""
        clear_recent_files(self.settings)
        self._fill_recent()

    def import_take(self) -> None:
        """File > Import Camera Files: read a take on a worker thread."""
        from carapost.api import import_take

        if not self.maybe_save():
            return
        path = self.dialogs.open_file("Import camera files (choose one camera's file or the "
                                      "take's .json)",
                                      "Takes (*.json *.mkv *.avi *.mp4);;All files (*)")
        if not path:
            return
        self.runner.start("Import Camera Files", lambda progress: import_take(path),
                          lambda project, cancelled: project is not None
                          and self.set_project(project))

    def import_brim(self) -> None:
        """File > Import Calibration Brim [svg]: a planar custom brim replaces the brim."""
        from carapost.commands.process import ImportBrimSvg

        path = self.dialogs.open_file("Import Calibration Brim [svg]",
                                      "SVG files (*.svg);;All files (*)")
        if not path:
            return
        self.make_and_push(lambda: ImportBrimSvg(self.project, path),
                           "Import Calibration Brim [svg]")

    def show_brim_svg(self) -> None:
        """View > Show Calibration Brim SVG."""
        self.report_error("Show Calibration Brim SVG", action_table.NOT_AVAILABLE, show=False)

    def import_xcp(self) -> None:
        """File > Import XCP."""
        from carapost.io.errors import CaraFileError
        from carapost.io.xcp import read_xcp
        from carapost.ui.uicommands import ApplyCalibration

        path = self.dialogs.open_file("Import XCP", "Calibration (*.xcp);;All files (*)")
        if not path:
            return
        try:
            calib = read_xcp(path)
        except (CaraFileError, OSError, ValueError) as exc:
            self.report_error("Import XCP", str(exc))
            return
        for note in calib.notes:
            log.warning("%s: %s", Path(path).name, note)
        self.make_and_push(lambda: ApplyCalibration(self.project, calib, path), "Import XCP")

    def import_labels(self, kind: str) -> None:
        """Import Labels From Cara File / Text File."""
        from carapost.io.errors import CaraFileError
        from carapost.io.labels import read_label_file, read_labels_from_cara

        filters = CARA_FILTER if kind == "cara" else "Label files (*.txt);;All files (*)"
        path = self.dialogs.open_file("Import labels", filters)
        if not path:
            return
        try:
            names = read_labels_from_cara(path) if kind == "cara" else read_label_file(path)
        except (CaraFileError, OSError, ValueError) as exc:
            self.report_error("Import Labels", str(exc))
            return
        self.make_and_push(lambda: edit.AddLabels(
            self.project, names, description=f"Import Labels From {Path(path).name}"),
            "Import Labels")

    def export(self, kind: str) -> None:
        """Export C3D / FBX / XCP [Current Frame] on a worker thread."""
        api = importlib.import_module("carapost.api")
        fn = getattr(api, f"export_{kind}")
        ext = {"c3d": "C3D (*.c3d)", "fbx": "FBX (*.fbx)", "xcp": "XCP (*.xcp)"}[kind]
        path = self.dialogs.save_file(f"Export {kind.upper()}", ext,
                                      f"{self.project.take.name}.{kind}")
        if not path:
            return
        params = inspect.signature(fn).parameters
        kwargs: dict[str, Any] = {}
        if kind == "xcp" and "frame" in params:
            kwargs["frame"] = self.project.current_frame
        project = self.project
        self.runner.start(f"Export {kind.upper()}", lambda progress: fn(project, path, **kwargs),
                          lambda result, cancelled: log.info("Exported %s", path))

    # ======================================================================================
    # processing
    # ======================================================================================
    def detect_blobs(self, which: str) -> None:
        """Detect Blobs [Current Frame] / [Active Range] on a worker thread."""
        from carapost.algorithms.blobs import detect_blobs_batch

        p = self.project
        title = "Detect Blobs [Current Frame]" if which == "current" else \
            "Detect Blobs [Active Range]"
        if p.n_frames == 0 or not self.ctx.frames.has_images:
            self.report_error(title, f"{title}: the take has no images to search")
            return
        try:
            params = self.ctx.blob_parameters()
        except ValueError as exc:
            self.report_error(title, f"{title}: {exc}")
            return
        frames = [p.current_frame] if which == "current" else \
            list(range(p.active_range[0], p.active_range[1] + 1))
        cams = [int(c) for c in p.processing_cameras()]
        keys = [(f, c) for f in frames for c in cams]
        source = self.ctx.frames.worker_copy()

        def job(progress: Callable[[int, int], bool]) -> Any:
            return detect_blobs_batch(lambda key: source.require(*key), keys, params,
                                      workers=2, progress=progress)

        def done(result: Any, cancelled: bool) -> None:
            if source is not self.ctx.frames:
                source.close()
            if not result:
                return
            images = sorted(result)
            tables = [{"centre": result[k].centre, "axes": result[k].axes,
                       "angle": result[k].angle, "colour": result[k].colour,
                       "score": result[k].score} for k in images]
            label = title + (" (cancelled: partial)" if cancelled else "")
            self.push(edit.ReplaceDetections(images, tables, label))
            n = sum(len(t["centre"]) for t in tables)
            log.info("%s: %d detections in %d images%s", title, n, len(images),
                     " (cancelled)" if cancelled else "")

        self.runner.start(title, job, done)

    def run_process(self, hook: str) -> None:
        """A Process-menu item provided by ``carapost.commands.menu.<hook>``."""
        try:
            module = importlib.import_module(action_table.PROCESS_MODULE)
            fn = getattr(module, hook)
        except (ImportError, AttributeError):
            self.report_error(hook, f"{hook.replace('_', ' ')}: {action_table.NOT_AVAILABLE}",
                              show=False)
            return
        project = self.project
        title = hook.replace("_", " ").capitalize()
        for spec in action_table.ACTIONS:
            if spec.arg == hook and spec.title:
                title = spec.title

        wants_images = "get_image" in inspect.signature(fn).parameters
        source = self.ctx.frames.worker_copy() if wants_images and \
            self.ctx.frames.has_images else None

        def job(progress: Callable[[int, int], bool]) -> Any:
            if source is None:
                return fn(project, progress=progress)
            try:  # tracking: patch tracking, and detection of frames that have none
                return fn(project, progress=progress, get_image=source.require)
            finally:
                if source is not self.ctx.frames:
                    source.close()

        def done(result: Any, cancelled: bool) -> None:
            if isinstance(result, Command):
                self.push(result)

        self.runner.start(title, job, done)

    def load_rom(self) -> None:
        """Process > Load ROM (the ROM project is read and checked by the command)."""
        from carapost.commands.tracking import LoadRom

        path = self.dialogs.open_file("Load ROM", CARA_FILTER)
        if not path:
            return
        self.make_and_push(lambda: LoadRom(self.project, path), "Load ROM")

    def _job_started(self, title: str) -> None:
        self.progress.setRange(0, 0)
        self.progress.setFormat(f"{title} %p%")
        self.progress.show()
        self.cancel_button.show()
        self.statusBar().showMessage(title)

    def _job_progress(self, done: int, total: int) -> None:
        self.progress.setRange(0, max(total, 1))
        self.progress.setValue(done)

    def _job_finished(self, title: str, cancelled: bool) -> None:
        self.progress.hide()
        self.cancel_button.hide()
        self.statusBar().showMessage(f"{title} {'cancelled' if cancelled else 'finished'}",
                                     4000)

    def _job_failed(self, title: str, message: str) -> None:
        self.last_error = message
        self.dialogs.error(title, message)

    # ======================================================================================
    # navigation
    # ======================================================================================
    def set_frame(self, frame: int) -> None:
        """Move to a frame (clamped to the view range... and to the take)."""
        p = self.project
        if p.n_frames == 0:
            return
        p.set_current_frame(int(frame))
        if self.play_timer.isActive():
            self.ctx.frames.prefetch(range(p.current_frame + 1, p.current_frame + 16),
                                     list(range(p.n_cameras)))

    def set_active_range(self, a: int, b: int) -> None:
        """Ctrl+drag on the timebar, continuity chart or graph: set the active range."""
        self.make_and_push(lambda: edit.SetRange(self.project, "active_range", (a, b),
                                                 f"Set Active Range {a}-{b}"), "Active range")

    def range_command(self, name: str) -> None:
        """Ctrl+1/2/3, Set View Range to Active Range, Reset View Range."""
        factory = getattr(edit.SetRange, name)
        self.make_and_push(lambda: factory(self.project), name)

    def go_to_frame(self) -> None:
        """Go To Frame (Ctrl+G)."""
        p = self.project
        f = self.dialogs.get_int("Go To Frame", "Frame:", p.current_frame, 0,
                                 max(p.n_frames - 1, 0))
        if f is not None:
            self.set_frame(f)

    def go_start(self) -> None:
        """Go to Start Frame (Home)."""
        self.set_frame(0)

    def go_end(self) -> None:
        """Go to End Frame (End)."""
        self.set_frame(self.project.n_frames - 1)

    def step(self, delta: str | int) -> None:
        """Next / Prev Frame (arrows; auto-repeat while held acts like play)."""
        self.set_frame(self.project.current_frame + int(delta))

    def step_key(self, delta: str | int) -> None:
        """Next / Prev Key Frame of the selected point (wrapping), else one frame."""
        p = self.project
        d = int(delta)
        cols = p.selected_columns()
        if len(cols) == 0:
            self.step(d)
            return
        keys = np.flatnonzero(p.points.keyframe[:, cols, :].any(axis=(1, 2)))
        if len(keys) == 0:
            self.step(d)
            return
        f = p.current_frame
        later, earlier = keys[keys > f], keys[keys < f]
        if d > 0:
            self.set_frame(int(later[0]) if len(later) else int(keys[0]))
        else:
            self.set_frame(int(earlier[-1]) if len(earlier) else int(keys[-1]))

    def toggle_play(self, on: bool) -> None:
        """Play / Stop (Space): plays every frame of the view range."""
        p = self.project
        if on and p.n_frames:
            if p.current_frame >= p.view_range[1]:
                self.set_frame(p.view_range[0])
            self.play_timer.start(max(int(1000 / max(p.take.fps, 1)), 1))
        else:
            self.play_timer.stop()
        self.timebar.set_playing(self.play_timer.isActive())
        self.action("view.play").setChecked(self.play_timer.isActive())

    def stop_play(self) -> None:
        """Stop playback."""
        if self.play_timer.isActive():
            self.toggle_play(False)

    @property
    def playing(self) -> bool:
        """Whether playback runs."""
        return self.play_timer.isActive()

    def _play_tick(self) -> None:
        p = self.project
        if p.current_frame >= p.view_range[1]:
            self.stop_play()
            return
        self.set_frame(p.current_frame + 1)

    def toggle_lock(self, on: bool) -> None:
        """Lock To Point."""
        self.ctx.lock_to_point = on
        self.ctx.notify_options()

    def toggle_blob_preview(self, on: bool) -> None:
        """Toggle Blob Preview (Ctrl+B)."""
        self.ctx.options.blob_preview = on
        self.ctx.notify_options()

    def toggle_show_stabilized(self, on: bool) -> None:
        """Toggle Show Stabilized (Ctrl+Shift+S)."""
        self.ctx.show_stabilized = on
        self.ctx.notify_options()

    def toggle_full_screen(self, on: bool) -> None:
        """Full Screen (F)."""
        if on:
            self.showFullScreen()
        else:
            self.showNormal()

    def toggle_docks(self) -> None:
        """Toggle Dock Widget Visibility (Ctrl+F): only the workspace and timebar."""
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
        """View > New Floating Workspace (a 3D view to start with)."""
        fw = FloatingWorkspace(self.ctx, self)
        self.floating.append(fw)
        fw.destroyed.connect(lambda *_: self.floating.remove(fw) if fw in self.floating
                             else None)
        fw.workspace.refresh(None)
        fw.show()
        return fw

    def center_selection(self, mode: str) -> None:
        """Center (C) / Frame (Shift+C) Selection in all 2D views."""
        for view in self._all_views():
            if view.kind == "sensor":
                view.center_selection(frame=(mode == "frame"))

    def _all_views(self) -> list:
        views = list(self.workspace.views())
        for fw in self.floating:
            views.extend(fw.workspace.views())
        return views

    def _view_activated(self, view: Any) -> None:
        if view.kind == "sensor":
            self.ctx.active_camera = view.camera

    # ======================================================================================
    # selection tools
    # ======================================================================================
    def select_point_dialog(self) -> None:
        """Select Point (Ctrl+P): by id."""
        p = self.project
        if p.n_points == 0:
            return
        pid = self.dialogs.get_int("Select Point", "Point id:", int(p.points.ids[0]),
                                   int(p.points.ids.min()), int(p.points.ids.max()))
        if pid is None:
            return
        if pid not in set(p.points.ids.tolist()):
            self.report_error("Select Point", f"Select Point: there is no point {pid}",
                              show=False)
            return
        p.set_selection(points=[pid])

    def select_fewest_gaps(self) -> None:
        """Select Point With Fewest Gaps (Ctrl+A) within the active range."""
        p = self.project
        col = queries.point_with_fewest_gaps(p, frames=p.active_range) if p.n_points else None
        if col is None:
            self.statusBar().showMessage("No point has a gap", 4000)
            log.info("Select Point With Fewest Gaps: no point has a gap")
            return
        pid = int(p.points.ids[col])
        p.set_selection(points=[pid])
        log.info("Selected %s (fewest gaps)", p.point_label(col))

    def go_next_gap(self) -> None:
        """Go To Next Gap of Selected Point: the frame before the gap."""
        p = self.project
        cols = p.selected_columns()
        if len(cols) != 1:
            self.report_error("Go To Next Gap", "Go To Next Gap: select one point", show=False)
            return
        gap = queries.next_gap(p, int(cols[0]), p.current_frame)
        if gap is None:
            gs = queries.gaps(p, int(cols[0]))
            if len(gs) == 0:
                self.statusBar().showMessage("The selected point has no gap", 4000)
                return
            gap = (int(gs[0, 0]), int(gs[0, 1]))  # wrap to the first gap
        self.set_frame(max(gap[0] - 1, 0))

    def point_information(self) -> str:
        """Get Point Information: 3D position, 2D in each sensor, distances to cameras."""
        p = self.project
        cols = p.selected_columns()
        if len(cols) != 1:
            self.report_error("Get Point Information", "Get Point Information: select one "
                              "point", show=False)
            return ""
        col, f = int(cols[0]), p.current_frame
        X = p.points.positions[f, col].astype(np.float64)
        lines = [f"{p.point_label(col)} (id {int(p.points.ids[col])}) at frame {f}"]
        lines.append("3D: " + ("none" if np.isnan(X[0]) else
                               f"({X[0]:.2f}, {X[1]:.2f}, {X[2]:.2f}) mm"))
        for c in range(p.n_cameras):
            o = p.points.obs[f, col, c]
            det = int(p.points.detection[f, col, c])
            size = ""
            if det >= 0:
                ax = p.detections.get(f, c)["axes"]
                if det < len(ax):
                    size = f", blob {2 * float(ax[det, 0]):.1f} x {2 * float(ax[det, 1]):.1f} px"
            lines.append(f"Sensor {c}: " + ("-" if np.isnan(o[0]) else
                                            f"({o[0]:.1f}, {o[1]:.1f}) px{size}"))
        cal = p.calibration
        if not np.isnan(X[0]) and p.n_cameras and cal.solved.any():
            centres = -np.einsum("cji,cj->ci", cal.R[f], cal.t[f])
            half = (p.n_cameras + 1) // 2
            groups = [("caddy 1", centres[:half]), ("caddy 2", centres[half:]),
                      ("all cameras", centres)]
            for name, cs in groups:
                if len(cs):
                    lines.append(f"Distance to centroid of {name}: "
                                 f"{np.linalg.norm(cs.mean(0) - X):.1f} mm")
        text = "\n".join(lines)
        log.info("Point information:\n%s", text)
        self.dialogs.info("Get Point Information", text)
        return text

    def distance_two_points(self) -> float | None:
        """Distance Between Two Points, written to the log."""
        p = self.project
        cols = p.selected_columns()
        if len(cols) != 2:
            self.report_error("Distance Between Two Points", "Distance Between Two Points: "
                              "select exactly two points", show=False)
            return None
        a, b = p.points.positions[p.current_frame, cols].astype(np.float64)
        d = float(np.linalg.norm(a - b))
        if math.isnan(d):
            log.warning("Distance Between Two Points: a point has no 3D position at frame %d",
                        p.current_frame)
            return None
        log.info("Distance between %s and %s: %.2f mm", p.point_label(int(cols[0])),
                 p.point_label(int(cols[1])), d)
        return d

    def rotate_sensors(self, direction: str) -> None:
        """Rotate Selected Sensors (Ctrl+Right / Ctrl+Left)."""
        p = self.project
        cams = p.selection.cameras or ({self.ctx.active_camera}
                                       if self.ctx.active_camera is not None else set())
        self.make_and_push(lambda: edit.RotateSelectedSensors(p, cams or None,
                                                              clockwise=direction == "cw"),
                           "Rotate Selected Sensors")

    # ======================================================================================
    # help
    # ======================================================================================
    def open_help(self, which: str) -> None:
        """Open the documentation folder / README."""
        root = Path(__file__).resolve().parents[3]
        target = root / "docs" if (root / "docs").is_dir() else root
        QDesktopServices.openUrl(QUrl.fromLocalFile(str(target)))

    def check_updates(self) -> None:
        """Help > Check For Updates (there is no update server)."""
        self.dialogs.info("Check For Updates", action_table.NOT_AVAILABLE)

    def show_licence(self) -> None:
        """Help > Licensing."""
        self.dialogs.info("Licensing", "carapost is free software under the MIT licence; "
                          "it needs no licence key.")

    def show_third_party(self) -> None:
        """Help > Show 3rd Party Licenses."""
        self.dialogs.info("Third-party licences",
                          "\n".join(f"{name}: {lic}" for name, lic in THIRD_PARTY))

    def show_about(self) -> None:
        """Help > About."""
        from carapost import __version__ as version

        self.dialogs.info("About carapost", f"carapost {version}\nPost-processing of "
                          "head-mounted facial motion capture.\nMIT licence.")

    # ======================================================================================
    # settings and closing
    # ======================================================================================
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
            self.ctx.options.update(opts)

    def save_settings(self) -> None:
        """Remember the layout for the next run."""
        s = self.settings
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState())
        self.workspace.specs_update()
        s.setValue("workspace/views", list(self.workspace.specs))
        s.setValue("workspace/layout", self.workspace.n)
        s.setValue("display/options", self.ctx.options.to_dict())
        s.sync()

    def closeEvent(self, ev) -> None:  # noqa: N802 - Qt API
        if not self.maybe_save():
            ev.ignore()
            return
        self.shutdown()
        ev.accept()

    def shutdown(self) -> None:
        """Stop timers and workers, save settings, detach from logging."""
        self.stop_play()
        self.autosave_timer.stop()
        if self.runner.busy:
            self.runner.cancel()
            self.runner.wait(30)
        self.save_settings()
        for fw in list(self.floating):
            fw.close()
        logging.getLogger().removeHandler(self.log_bridge)
        self.bridge.detach()
        self.ctx.frames.close()
