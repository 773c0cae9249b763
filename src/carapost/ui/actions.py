"""The one declarative table of the main window's actions; menus are built from it.

Each :class:`ActionSpec` names its menu, title (the reference guide's wording), shortcut,
the :class:`~carapost.ui.mainwindow.MainWindow` method that handles it, and what it
needs: ``requires`` is ``"module"`` or ``"module:attribute"``; when that cannot be
imported the item is shown disabled with the tooltip :data:`NOT_AVAILABLE` and lights up
once the code lands (no change here needed).

Processing commands of other parts of the project plug in through
``carapost.commands.menu``: an item with ``handler="run_process"`` and ``arg="name"``
calls ``carapost.commands.menu.name(project, progress=progress, **options)`` on a
worker thread; it returns a :class:`~carapost.commands.stack.Command` (or None), which
the window pushes on the GUI thread as one undo entry.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

NOT_AVAILABLE = "Not available yet"
PROCESS_MODULE = "carapost.commands.menu"

#: Menu titles in menu-bar order.
MENUS = ("File", "Edit", "View", "Process", "Help")


@dataclass(frozen=True)
class ActionSpec:
    """One menu item.

    Attributes
    ----------
    id : str
        Unique id (``"edit.merge"``).
    menu : str
        Menu path, ``/``-separated (``"View/Panels"``).
    title : str
        Text of the item.
    shortcut : str
        Qt key sequence text (``"Ctrl+Shift+H"``), "" for none.
    handler : str
        Name of the MainWindow method called (with ``arg`` when given).
    arg : str
        Argument passed to the handler ("" = none).
    requires : str
        ``"module"`` or ``"module:attribute"`` the item needs; "" = always there.
    checkable : bool
        A toggle (the handler receives the new state).
    separator : bool
        Draw a separator above the item.
    tip : str
        Status/tooltip text.
    """

    id: str
    menu: str
    title: str
    shortcut: str = ""
    handler: str = ""
    arg: str = ""
    requires: str = ""
    checkable: bool = False
    separator: bool = False
    tip: str = ""


def _proc(id_: str, title: str, hook: str, shortcut: str = "", separator: bool = False,
          tip: str = "") -> ActionSpec:
    return ActionSpec(id_, "Process", title, shortcut, "run_process", hook,
                      f"{PROCESS_MODULE}:{hook}", separator=separator, tip=tip)


_A = ActionSpec

# fmt: off
ACTIONS: tuple[ActionSpec, ...] = (
    # --- File ------------------------------------------------------------------------------
    _A("file.open", "File", "Open...", "Ctrl+O", "open_project", tip="Open a .cara project"),
    _A("file.clear", "File", "Clear", "", "clear_project", tip="Close the project"),
    _A("file.save", "File", "Save", "Ctrl+S", "save_project"),
    _A("file.save_as", "File", "Save As...", "", "save_project_as"),
    _A("file.import_take", "File", "Import Camera Files...", "", "import_take",
       requires="carapost.io.take_import:import_take", separator=True,
       tip="Import the per-camera video files of a take"),
    _A("file.import_brim", "File", "Import Calibration Brim [svg]...", "", "import_brim",
       requires="carapost.io.brim_svg:read_brim_svg"),
    _A("file.import_xcp", "File", "Import XCP...", "", "import_xcp",
       requires="carapost.io.xcp:read_xcp"),
    _A("file.import_labels_cara", "File", "Import Labels From Cara File...", "",
       "import_labels", "cara", requires="carapost.io.labels:read_labels_from_cara",
       separator=True),
    _A("file.import_labels_text", "File", "Import Labels From Text File...", "",
       "import_labels", "text", requires="carapost.io.labels:read_label_file"),
    _A("file.export_xcp", "File", "Export XCP [Current Frame]...", "", "export", "xcp",
       requires="carapost.api:export_xcp", separator=True),
    _A("file.export_c3d", "File", "Export C3D...", "", "export", "c3d",
       requires="carapost.api:export_c3d"),
    _A("file.export_fbx", "File", "Export FBX...", "", "export", "fbx",
       requires="carapost.api:export_fbx"),
    _A("file.recent", "File/Recent Files", "", separator=True),
    _A("file.clear_recent", "File", "Clear Recent Files", "", "clear_recent"),
    _A("file.exit", "File", "Exit", "", "close", separator=True),
    # --- Edit ------------------------------------------------------------------------------
    _A("edit.undo", "Edit", "Undo", "Ctrl+Z", "undo"),
    _A("edit.redo", "Edit", "Redo", "Ctrl+Y", "redo"),
    _A("edit.clear_history", "Edit", "Clear History", "", "clear_history"),
    _A("edit.create_points", "Edit", "Create Points From Detections", "", "edit_command",
       "CreatePointsFromDetections", separator=True),
    _A("edit.delete", "Edit", "Delete Selected", "Ctrl+D", "edit_command", "DeleteSelected"),
    _A("edit.split", "Edit", "Split Selected Point", "", "edit_command", "SplitSelectedPoint"),
    _A("edit.merge", "Edit", "Merge", "M", "edit_command", "Merge"),
    _A("edit.clear_current", "Edit", "Clear Selected [Current Frame]", "", "edit_command",
       "ClearSelected.current_frame"),
    _A("edit.clear_range", "Edit", "Clear Selected [Active Range]", "", "edit_command",
       "ClearSelected.active_range"),
    _A("edit.detach_current", "Edit", "Detach Detections [Current Frame]", "Ctrl+H",
       "detach", "current"),
    _A("edit.detach_range", "Edit", "Detach Detections [Active Range]", "Ctrl+Shift+H",
       "detach", "range"),
    _A("edit.relocate", "Edit", "Relocate Files...", "", "relocate_files", separator=True),
    _A("edit.increment_offset", "Edit", "Increment Image Sequence Offset", "",
       "edit_command", "IncrementImageSequenceOffset"),
    _A("edit.add_target_track", "Edit", "Add Target Track", "Shift+A", "point_edit_mode",
       "add", requires="carapost.commands.target_track:AddTargetTrack", separator=True),
    _A("edit.edit_target_track", "Edit", "Edit Target Track", "Shift+E", "point_edit_mode",
       "edit", requires="carapost.commands.target_track:EditTargetTrack"),
    _A("edit.stop_point_edit", "Edit", "Stop Point Edit mode", "Shift+S", "point_edit_mode",
       ""),
    _A("edit.gaps_to_keys", "Edit", "Gaps To Keys", "", "edit_command", "GapsToKeys",
       requires="carapost.commands.target_track:GapsToKeys"),
    _A("edit.remove_unused", "Edit", "Remove Unused Detections", "", "edit_command",
       "RemoveUnusedDetections", separator=True),
    _A("edit.remove_interpolated", "Edit", "Remove Interpolated 3D Points", "", "edit_command",
       "RemoveInterpolated3DPoints"),
    _A("edit.rename", "Edit", "Rename Point...", "Ctrl+R", "rename_point", separator=True),
    _A("edit.clear_labels", "Edit", "Clear All Labels", "", "edit_command", "ClearAllLabels"),
    _A("edit.delete_labels", "Edit", "Delete Selected Labels", "", "delete_selected_labels"),
    _A("edit.unlabel", "Edit", "Unlabel Selected Points", "Ctrl+U", "edit_command",
       "UnlabelSelectedPoints"),
    _A("edit.create_stick", "Edit", "Create Stick from Selected Point", "S", "edit_command",
       "CreateStick", separator=True),
    _A("edit.create_stick_mesh", "Edit", "Create Stick Mesh", "", "create_stick_mesh",
       requires="scipy.spatial:Delaunay"),
    _A("edit.edit_stick_color", "Edit", "Edit Stick Color...", "", "edit_stick_color"),
    _A("edit.clear_active_range", "Edit", "Clear Active Range", "", "edit_command",
       "ClearActiveRange"),
    _A("edit.restore_defaults", "Edit", "Restore Properties To Defaults", "", "edit_command",
       "RestorePropertiesToDefaults", separator=True),
    _A("edit.read_blob_params", "Edit", "Read Blob Parameters From Take Files", "",
       "edit_command", "RevertBlobParameters"),
    # --- View ------------------------------------------------------------------------------
    _A("view.panels", "View/Panels", ""),
    _A("view.floating", "View", "New Floating Workspace", "", "new_floating_workspace"),
    _A("view.brim_svg", "View", "Show Calibration Brim SVG", "", "show_brim_svg",
       requires="carapost.io.brim_svg:read_brim_svg"),
    _A("view.full_screen", "View", "Full Screen", "F", "toggle_full_screen", checkable=True,
       separator=True),
    _A("view.toggle_docks", "View", "Toggle Dock Widget Visibility", "Ctrl+F",
       "toggle_docks"),
    _A("view.blob_preview", "View", "Toggle Blob Preview", "Ctrl+B", "toggle_blob_preview",
       requires="carapost.algorithms.blobs:preview_blobs", checkable=True),
    _A("view.show_stabilized", "View", "Toggle Show Stabilized", "Ctrl+Shift+S",
       "toggle_show_stabilized", requires=f"{PROCESS_MODULE}:stabilized_positions",
       checkable=True),
    _A("view.go_to_frame", "View", "Go To Frame...", "Ctrl+G", "go_to_frame", separator=True),
    _A("view.start", "View", "Go to Start Frame", "Home", "go_start"),
    _A("view.end", "View", "Go to End Frame", "End", "go_end"),
    _A("view.play", "View", "Play", "Space", "toggle_play", checkable=True),
    _A("view.next", "View", "Next Frame", "Right", "step", "1"),
    _A("view.prev", "View", "Prev Frame", "Left", "step", "-1"),
    _A("view.lock", "View", "Lock To Point", "", "toggle_lock", checkable=True),
    _A("view.next_key", "View", "Next Key Frame", "Shift+Right", "step_key", "1"),
    _A("view.prev_key", "View", "Prev Key Frame", "Shift+Left", "step_key", "-1"),
    _A("view.select_point", "View", "Select Point...", "Ctrl+P", "select_point_dialog",
       separator=True),
    _A("view.point_info", "View", "Get Point Information", "", "point_information"),
    _A("view.rotate_cw", "View", "Rotate Selected Sensors Clockwise", "Ctrl+Right",
       "rotate_sensors", "cw"),
    _A("view.rotate_ccw", "View", "Rotate Selected Sensors Anticlockwise", "Ctrl+Left",
       "rotate_sensors", "ccw"),
    _A("view.fewest_gaps", "View", "Select Point With Fewest Gaps", "Ctrl+A",
       "select_fewest_gaps"),
    _A("view.next_gap", "View", "Go To Next Gap of Selected Point", "", "go_next_gap"),
    _A("view.distance", "View", "Distance Between Two Points", "", "distance_two_points"),
    _A("view.active_start", "View", "Set Active Range Start", "Ctrl+1", "range_command",
       "active_start", separator=True),
    _A("view.active_end", "View", "Set Active Range End", "Ctrl+2", "range_command",
       "active_end"),
    _A("view.active_reset", "View", "Reset Active Range", "Ctrl+3", "range_command",
       "reset_active"),
    _A("view.view_to_active", "View", "Set View Range to Active Range", "", "range_command",
       "view_to_active"),
    _A("view.view_reset", "View", "Reset View Range", "", "range_command", "reset_view"),
    _A("view.center", "View", "Center Selection All 2D Views", "C", "center_selection",
       "center", separator=True),
    _A("view.frame", "View", "Frame Selection All 2D Views", "Shift+C", "center_selection",
       "frame"),
    # --- Process ---------------------------------------------------------------------------
    _A("process.blobs_range", "Process", "Detect Blobs [Active Range]", "", "detect_blobs",
       "range", requires="carapost.algorithms.blobs:detect_blobs_batch"),
    _A("process.blobs_current", "Process", "Detect Blobs [Current Frame]", "", "detect_blobs",
       "current", requires="carapost.algorithms.blobs:detect_blobs_batch"),
    _A("process.load_rom", "Process", "Load ROM...", "", "load_rom", separator=True),
    _proc("process.init_rom", "Initialize from ROM", "initialize_from_rom"),
    _proc("process.init_rom_brim", "Initialize from ROM [Brim Only]",
          "initialize_from_rom_brim_only"),
    _proc("process.brim_v20", "Initialize Default Calibration Brim [v2.0]",
          "initialize_brim_v20", separator=True),
    _proc("process.brim_v11", "Initialize Default Calibration Brim [v1.1]",
          "initialize_brim_v11"),
    _proc("process.brim_v10", "Initialize Default Calibration Brim [v1.0]",
          "initialize_brim_v10"),
    _proc("process.solve_brim", "Solve Calibration Brim [Manual]", "solve_brim"),
    _proc("process.init3d", "Initialize 3D", "initialize_3d", separator=True),
    _proc("process.bundle_frame", "Bundle Current Frame [Unconstrained]",
          "bundle_current_frame"),
    _proc("process.bundle_seq", "Bundle Sequence [Unconstrained]", "bundle_sequence"),
    _proc("process.track_fwd_seq", "Track Forwards [Sequence]", "track_forwards_sequence",
          separator=True),
    _proc("process.track_bwd_seq", "Track Backwards [Sequence]", "track_backwards_sequence"),
    _proc("process.track_fwd_one", "Track Forwards [Single Frame]", "track_forwards_frame",
          shortcut="Ctrl+W"),
    _proc("process.track_bwd_one", "Track Backwards [Single Frame]", "track_backwards_frame"),
    _proc("process.stab_manual", "Stabilize Data [Manual]", "stabilize_manual",
          separator=True),
    _proc("process.stab_assisted", "Stabilize Data [Assisted]", "stabilize_assisted"),
    _proc("process.align", "Align Data", "align_data"),
    _proc("process.interpolate", "Interpolate Gaps", "interpolate_gaps", separator=True),
    # --- Help ------------------------------------------------------------------------------
    _A("help.online", "Help", "View Latest Help Online", "", "open_help", "online",
       tip="Open the project's documentation"),
    _A("help.installed", "Help", "View Installed Help", "", "open_help", "installed"),
    _A("help.updates", "Help", "Check For Updates", "", "check_updates",
       requires="carapost.ui._updates"),
    _A("help.licensing", "Help", "Licensing", "", "show_licence"),
    _A("help.third_party", "Help", "Show 3rd Party Licenses", "", "show_third_party"),
    _A("help.about", "Help", "About", "", "show_about"),
)
# fmt: on

#: Guide item names that we word differently (the guide's name -> ours). We import
#: per-camera video files, not the proprietary ``.pico`` container, and the help points
#: to this project's documentation rather than a vendor web site.
GUIDE_ALIASES: dict[str, str] = {
    "Import Pico Files": "Import Camera Files...",
    "Read Blob Parameters From Pico Files": "Read Blob Parameters From Take Files",
    "View latest help on vicon.com": "View Latest Help Online",
    "View installed help": "View Installed Help",
    "Panels": "View/Panels",
    "Recent Files": "File/Recent Files",
}

#: Dock panes in View > Panels order (object names are the titles).
PANELS = ("Labelling", "History", "Selected Point", "Log", "Properties", "Selection",
          "Tracker")


def find_spec(id_: str) -> ActionSpec:
    """The action with this id (KeyError if none)."""
    for spec in ACTIONS:
        if spec.id == id_:
            return spec
    raise KeyError(id_)


def requirement_met(requires: str) -> bool:
    """Whether ``"module"`` / ``"module:attribute"`` can be imported right now."""
    if not requires:
        return True
    module, _, attr = requires.partition(":")
    try:
        mod = importlib.import_module(module)
    except Exception:  # missing or broken: either way not usable yet
        return False
    return not attr or hasattr(mod, attr)


def menu_items() -> list[ActionSpec]:
    """Actions that are menu items with a title."""
    return [a for a in ACTIONS if a.title]
