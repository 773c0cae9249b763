"""The one declarative table of the main window's actions; menus are built from it.

Each :class:`ActionSpec` names its menu, title (the reference guide's wording), shortcut
and the callable that handles it. The callable takes the window's
:class:`~carapost.ui.context.ActionContext` (checkable items also get the new state);
arguments are bound here with :func:`functools.partial`, so what an item does is
written in this table and the handler modules (:mod:`carapost.ui.handlers`), never
looked up by name. Items of the reference guide that carapost does not implement have
no callable: they are listed, disabled, with the tooltip :data:`NOT_AVAILABLE`.

Every item that changes the project calls the open project's
:class:`~carapost.session.Session`: Edit and View items bind the unbound Session method
(``_do(Session.merge)``), Process items name the Session Process action and its options
(``_proc(..., "track", direction="backwards")``), which
:func:`carapost.ui.handlers.process.run` prepares on the GUI thread, computes on the
worker and applies as one undo entry. A script calling the same Session method does
exactly what the menu item does.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from carapost.session import Session
from carapost.ui.handlers import brim_view as brim_menu
from carapost.ui.handlers import cleanup, navigation
from carapost.ui.handlers import edit as edit_menu
from carapost.ui.handlers import file as file_menu
from carapost.ui.handlers import help as help_menu
from carapost.ui.handlers import inspect as inspect_menu
from carapost.ui.handlers import labelling as labelling_menu
from carapost.ui.handlers import process as process_menu
from carapost.ui.handlers import target as target_menu
from carapost.ui.handlers import view as view_menu

NOT_AVAILABLE = "Not available yet"

#: Menu titles in menu-bar order.
MENUS = ("File", "Edit", "View", "Process", "Help")

#: ``callback(ctx)``, or ``callback(ctx, checked)`` for a checkable item.
Callback = Callable[..., Any]


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
        Text of the item ("" for a submenu placeholder).
    shortcut : str
        Qt key sequence text (``"Ctrl+Shift+H"``), "" for none.
    callback : callable or None
        ``callback(ctx)`` (checkable: ``callback(ctx, checked)``) with ``ctx`` the
        :class:`~carapost.ui.context.ActionContext`; None = not implemented (shown
        disabled, tooltip :data:`NOT_AVAILABLE`).
    checkable : bool
        A toggle (the callback receives the new state).
    separator : bool
        Draw a separator above the item.
    tip : str
        Status/tooltip text.
    """

    id: str
    menu: str
    title: str
    shortcut: str = ""
    callback: Callback | None = None
    checkable: bool = False
    separator: bool = False
    tip: str = ""

    @property
    def available(self) -> bool:
        """Whether the item does something (it has a callback)."""
        return self.callback is not None


def _do(action: edit_menu.SessionAction, **options: Any) -> Callback:
    """Call the Session method ``action`` (unbound: ``Session.merge``) with ``options``."""
    return partial(edit_menu.session_action, action, **options)


def _proc(id_: str, title: str, action: str | None, shortcut: str = "",
          separator: bool = False, images: bool = False, **options: Any) -> ActionSpec:
    """A Process item: the Session Process ``action`` with ``options``, on the worker."""
    cb = None if action is None else partial(process_menu.run, action=action, title=title,
                                             images=images, **options)
    return ActionSpec(id_, "Process", title, shortcut, cb, separator=separator)


def _brim(id_: str, version: str, separator: bool = False) -> ActionSpec:
    title = f"Initialize Default Calibration Brim [v{version}]"
    return ActionSpec(id_, "Process", title, "", partial(process_menu.default_brim,
                                                         version=version),
                      separator=separator)


_A = ActionSpec
S = Session

# fmt: off
ACTIONS: tuple[ActionSpec, ...] = (
    # --- File ------------------------------------------------------------------------------
    _A("file.open", "File", "Open...", "Ctrl+O", file_menu.open_project,
       tip="Open a .cara project"),
    _A("file.clear", "File", "Clear", "", file_menu.clear_project, tip="Close the project"),
    _A("file.save", "File", "Save", "Ctrl+S", file_menu.save_project),
    _A("file.save_as", "File", "Save As...", "", file_menu.save_project_as),
    _A("file.import_take", "File", "Import Camera Files...", "", file_menu.import_take,
       separator=True, tip="Import the per-camera video files of a take"),
    _A("file.import_brim", "File", "Import Calibration Brim [svg]...", "",
       file_menu.import_brim),
    _A("file.import_xcp", "File", "Import XCP...", "", file_menu.import_xcp),
    _A("file.import_c3d", "File", "Import C3D...", "", cleanup.import_c3d,
       tip="A new project from the 3D points and labels of any C3D file"),
    _A("file.import_labels_cara", "File", "Import Labels From Cara File...", "",
       partial(file_menu.import_labels, kind="cara"), separator=True),
    _A("file.import_labels_text", "File", "Import Labels From Text File...", "",
       partial(file_menu.import_labels, kind="text")),
    _A("file.export_xcp", "File", "Export XCP [Current Frame]...", "",
       partial(file_menu.export, kind="xcp"), separator=True),
    _A("file.export_c3d", "File", "Export C3D...", "", partial(file_menu.export, kind="c3d")),
    _A("file.export_fbx", "File", "Export FBX...", "", partial(file_menu.export, kind="fbx")),
    _A("file.recent", "File/Recent Files", "", separator=True),
    _A("file.clear_recent", "File", "Clear Recent Files", "", file_menu.clear_recent),
    _A("file.exit", "File", "Exit", "", file_menu.exit_window, separator=True),
    # --- Edit ------------------------------------------------------------------------------
    _A("edit.undo", "Edit", "Undo", "Ctrl+Z", edit_menu.undo),
    _A("edit.redo", "Edit", "Redo", "Ctrl+Y", edit_menu.redo),
    _A("edit.clear_history", "Edit", "Clear History", "", edit_menu.clear_history),
    _A("edit.create_points", "Edit", "Create Points From Detections", "",
       _do(S.create_points_from_detections), separator=True),
    _A("edit.delete", "Edit", "Delete Selected", "Ctrl+D", _do(S.delete_selected)),
    _A("edit.split", "Edit", "Split Selected Point", "", _do(S.split_selected_point)),
    _A("edit.merge", "Edit", "Merge", "M", _do(S.merge)),
    _A("edit.clear_current", "Edit", "Clear Selected [Current Frame]", "",
       _do(S.clear_selected, frames="current")),
    _A("edit.clear_range", "Edit", "Clear Selected [Active Range]", "",
       _do(S.clear_selected, frames="active")),
    _A("edit.detach_current", "Edit", "Detach Detections [Current Frame]", "Ctrl+H",
       partial(edit_menu.detach, which="current")),
    _A("edit.detach_range", "Edit", "Detach Detections [Active Range]", "Ctrl+Shift+H",
       partial(edit_menu.detach, which="range")),
    _A("edit.relocate", "Edit", "Relocate Files...", "", edit_menu.relocate_files,
       separator=True),
    _A("edit.increment_offset", "Edit", "Increment Image Sequence Offset", "",
       _do(S.increment_image_sequence_offset)),
    _A("edit.add_target_track", "Edit", "Add Target Track", "Shift+A",
       partial(target_menu.set_mode, mode="add"), separator=True),
    _A("edit.edit_target_track", "Edit", "Edit Target Track", "Shift+E",
       partial(target_menu.set_mode, mode="edit")),
    _A("edit.stop_point_edit", "Edit", "Stop Point Edit mode", "Shift+S",
       partial(target_menu.set_mode, mode="")),
    _A("edit.gaps_to_keys", "Edit", "Gaps To Keys", "", target_menu.gaps_to_keys),
    _A("edit.remove_unused", "Edit", "Remove Unused Detections", "",
       _do(S.remove_unused_detections), separator=True),
    _A("edit.remove_interpolated", "Edit", "Remove Interpolated 3D Points", "",
       _do(S.remove_interpolated_3d_points)),
    _A("edit.rename", "Edit", "Rename Point...", "Ctrl+R", edit_menu.rename_point,
       separator=True),
    _A("edit.clear_labels", "Edit", "Clear All Labels", "", _do(S.clear_all_labels)),
    _A("edit.delete_labels", "Edit", "Delete Selected Labels", "",
       edit_menu.delete_selected_labels),
    _A("edit.unlabel", "Edit", "Unlabel Selected Points", "Ctrl+U",
       _do(S.unlabel_selected_points)),
    _A("edit.create_stick", "Edit", "Create Stick from Selected Point", "S",
       _do(S.create_stick), separator=True),
    _A("edit.create_stick_mesh", "Edit", "Create Stick Mesh", "", _do(S.create_stick_mesh)),
    _A("edit.edit_stick_color", "Edit", "Edit Stick Color...", "", edit_menu.edit_stick_color),
    _A("edit.clear_active_range", "Edit", "Clear Active Range", "", _do(S.clear_active_range)),
    _A("edit.restore_defaults", "Edit", "Restore Properties To Defaults", "",
       _do(S.restore_properties_to_defaults), separator=True),
    _A("edit.read_blob_params", "Edit", "Read Blob Parameters From Take Files", "",
       _do(S.read_blob_parameters_from_take)),
    # --- View ------------------------------------------------------------------------------
    _A("view.panels", "View/Panels", ""),
    _A("view.floating", "View", "New Floating Workspace", "",
       view_menu.new_floating_workspace),
    _A("view.brim_svg", "View", "Show Calibration Brim SVG", "", brim_menu.show_brim_svg),
    _A("view.full_screen", "View", "Full Screen", "F", view_menu.toggle_full_screen,
       checkable=True, separator=True),
    _A("view.toggle_docks", "View", "Toggle Dock Widget Visibility", "Ctrl+F",
       view_menu.toggle_docks),
    _A("view.blob_preview", "View", "Toggle Blob Preview", "Ctrl+B",
       view_menu.toggle_blob_preview, checkable=True),
    _A("view.show_stabilized", "View", "Toggle Show Stabilized", "Ctrl+Shift+S",
       view_menu.toggle_show_stabilized, checkable=True),
    _A("view.go_to_frame", "View", "Go To Frame...", "Ctrl+G", navigation.go_to_frame,
       separator=True),
    _A("view.start", "View", "Go to Start Frame", "Home", navigation.go_start),
    _A("view.end", "View", "Go to End Frame", "End", navigation.go_end),
    _A("view.play", "View", "Play", "Space", navigation.toggle_play, checkable=True),
    _A("view.next", "View", "Next Frame", "Right", partial(navigation.step, delta=1)),
    _A("view.prev", "View", "Prev Frame", "Left", partial(navigation.step, delta=-1)),
    _A("view.build_proxies", "View", "Build Playback Proxies", "", navigation.build_proxies),
    _A("view.lock", "View", "Lock To Point", "", navigation.toggle_lock, checkable=True),
    _A("view.next_key", "View", "Next Key Frame", "Shift+Right",
       partial(navigation.step_key, delta=1)),
    _A("view.prev_key", "View", "Prev Key Frame", "Shift+Left",
       partial(navigation.step_key, delta=-1)),
    _A("view.select_point", "View", "Select Point...", "Ctrl+P", navigation.select_point,
       separator=True),
    _A("view.point_info", "View", "Get Point Information", "",
       inspect_menu.point_information),
    _A("view.rotate_cw", "View", "Rotate Selected Sensors Clockwise", "Ctrl+Right",
       partial(edit_menu.rotate_sensors, clockwise=True)),
    _A("view.rotate_ccw", "View", "Rotate Selected Sensors Anticlockwise", "Ctrl+Left",
       partial(edit_menu.rotate_sensors, clockwise=False)),
    _A("view.fewest_gaps", "View", "Select Point With Fewest Gaps", "Ctrl+A",
       navigation.select_fewest_gaps),
    _A("view.next_gap", "View", "Go To Next Gap of Selected Point", "",
       navigation.go_next_gap),
    _A("view.distance", "View", "Distance Between Two Points", "",
       inspect_menu.distance_two_points),
    _A("view.active_start", "View", "Set Active Range Start", "Ctrl+1",
       _do(S.set_range_bound, which="active_start"), separator=True),
    _A("view.active_end", "View", "Set Active Range End", "Ctrl+2",
       _do(S.set_range_bound, which="active_end")),
    _A("view.active_reset", "View", "Reset Active Range", "Ctrl+3",
       _do(S.reset_active_range)),
    _A("view.view_to_active", "View", "Set View Range to Active Range", "",
       _do(S.set_range_bound, which="view_to_active")),
    _A("view.view_reset", "View", "Reset View Range", "",
       _do(S.set_range_bound, which="reset_view")),
    _A("view.center", "View", "Center Selection All 2D Views", "C",
       partial(view_menu.center_selection, frame=False), separator=True),
    _A("view.frame", "View", "Frame Selection All 2D Views", "Shift+C",
       partial(view_menu.center_selection, frame=True)),
    # --- Process ---------------------------------------------------------------------------
    _proc("process.blobs_range", "Detect Blobs [Active Range]", "detect_blobs", images=True,
          frames="active", processes=True),
    _proc("process.blobs_current", "Detect Blobs [Current Frame]", "detect_blobs",
          images=True, frames="current", processes=True),
    _A("process.load_rom", "Process", "Load ROM...", "", process_menu.load_rom,
       separator=True),
    _proc("process.init_rom", "Initialize from ROM", "initialize_from_rom"),
    _proc("process.init_rom_brim", "Initialize from ROM [Brim Only]", "initialize_from_rom",
          brim_only=True),
    _brim("process.brim_v20", "2.0", separator=True),
    _brim("process.brim_v11", "1.1"),
    _brim("process.brim_v10", "1.0"),
    _proc("process.solve_brim", "Solve Calibration Brim [Manual]", "solve_brim"),
    _proc("process.init3d", "Initialize 3D", "initialize_3d", separator=True),
    _proc("process.bundle_frame", "Bundle Current Frame [Unconstrained]",
          "bundle_current_frame"),
    _proc("process.bundle_seq", "Bundle Sequence [Unconstrained]", "bundle_sequence"),
    _proc("process.track_fwd_seq", "Track Forwards [Sequence]", "track", separator=True,
          images=True, direction="forwards"),
    _proc("process.track_bwd_seq", "Track Backwards [Sequence]", "track", images=True,
          direction="backwards"),
    _proc("process.track_fwd_one", "Track Forwards [Single Frame]", "track",
          shortcut="Ctrl+W", images=True, direction="forwards", single_frame=True),
    _proc("process.track_bwd_one", "Track Backwards [Single Frame]", "track", images=True,
          direction="backwards", single_frame=True),
    _proc("process.stab_manual", "Stabilize Data [Manual]", "stabilize", separator=True,
          mode="manual"),
    _proc("process.stab_assisted", "Stabilize Data [Assisted]", "stabilize", mode="assisted"),
    _proc("process.stab_auto", "Stabilize Data [Automatic]", "stabilize", mode="auto"),
    _A("process.align", "Process", "Align Data", "", process_menu.align_data),
    _A("process.remove_stab", "Process", "Remove Stabilization", "",
       process_menu.remove_stabilization),
    _proc("process.interpolate", "Interpolate Gaps", "interpolate_gaps", separator=True),
    _proc("process.filter", "Filter Trajectories", "filter_trajectories"),
    _A("process.remove_filter", "Process", "Remove Filtering", "", cleanup.remove_filtering,
       tip="Restore the raw data of the filtered samples (selected points, active range)"),
    _A("process.find_problems", "Process", "Find Problems", "", cleanup.find_problems,
       tip="List gaps, spikes and suspected identity swaps (Find Problems pane)"),
    _A("process.label_template", "Process", "Label From Template...", "",
       labelling_menu.label_from_template, separator=True,
       tip="Label the unlabelled points from a labelled take of the same marker set"),
    # --- Help ------------------------------------------------------------------------------
    _A("help.online", "Help", "View Latest Help Online", "", help_menu.open_help,
       tip="Open the project's documentation"),
    _A("help.installed", "Help", "View Installed Help", "", help_menu.open_help),
    _A("help.updates", "Help", "Check For Updates", ""),  # there is no update server
    _A("help.licensing", "Help", "Licensing", "", help_menu.show_licence),
    _A("help.third_party", "Help", "Show 3rd Party Licenses", "", help_menu.show_third_party),
    _A("help.about", "Help", "About", "", help_menu.show_about),
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


def find_spec(id_: str) -> ActionSpec:
    """The action with this id (KeyError if none)."""
    for spec in ACTIONS:
        if spec.id == id_:
            return spec
    raise KeyError(id_)


def requirement_met(requires: str) -> bool:
    """Whether ``"module"`` / ``"module:attribute"`` exists right now.

    Only a missing ``module`` itself counts as "not there": a module that exists but
    fails to import raises, so a broken module fails loudly instead of showing as
    :data:`NOT_AVAILABLE`.
    """
    if not requires:
        return True
    module, _, attr = requires.partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = exc.name or ""
        if module == missing or module.startswith(missing + "."):
            return False  # the module (or a parent package) is not there
        raise  # it exists but imports something that is missing
    return not attr or hasattr(mod, attr)


def menu_items() -> list[ActionSpec]:
    """Actions that are menu items with a title."""
    return [a for a in ACTIONS if a.title]
