"""Persistent user settings (window layout, recent files, GUI preferences): QSettings.

GUI preferences that do not belong to a take (the guide's Display section: point label
visibility and font size; its Show Again Flags; the Tracker pane's "Update ... Every
Frame" switches) are user settings, declared in
:data:`PREFERENCES`; project files written before they moved may still hold them and
are read without them (:data:`carapost.model.properties.MOVED_TO_USER_SETTINGS`).

Settings live under the organisation ``carapost``. Setting the environment variable
``CARAPOST_SETTINGS_DIR`` puts them in ``<dir>/carapost.ini`` instead, which the tests
use so they never touch the user's own settings.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QObject, QSettings, Signal

ORGANISATION = "carapost"
APPLICATION = "carapost"
SETTINGS_DIR_ENV = "CARAPOST_SETTINGS_DIR"
MAX_RECENT = 8
_PREFERENCES_GROUP = "preferences"


@dataclass(frozen=True)
class Preference:
    """A GUI preference kept in the user settings: yes/no, or a whole number in a range.

    Attributes
    ----------
    key : str
        Settings key (the property key it had in project files).
    label : str
        Name as displayed (the reference guide's name).
    default : bool or int
        Its type is the preference's type.
    help : str
    minimum, maximum : int or None
        Inclusive bounds of a whole-number preference (values outside are clamped).
    unit : str
        Unit shown beside a whole-number value.
    step : int
        Step of the spin box of a whole-number value.
    """

    key: str
    label: str
    default: bool | int
    help: str
    minimum: int | None = None
    maximum: int | None = None
    unit: str = ""
    step: int = 1

    @property
    def kind(self) -> str:
        """``"bool"`` or ``"int"``."""
        return "bool" if isinstance(self.default, bool) else "int"


#: Keys of the guide's Display section. Each of its rows is about the person looking at
#: the take, not about the take: which labels to draw and how large is a matter of
#: eyesight, screen and habit, the same for every take, and two artists opening the same
#: .cara should each see labels their way (nor should opening a colleague's take change
#: one's own). None changes what is tracked, filled or exported. So all of them are user
#: settings, shown in the Properties pane as "Display (this computer)".
DISPLAY_PREFERENCES = ("point_labels_all", "point_labels_selected",
                       "point_labels_preselected", "label_font_size")

#: Every GUI preference (the guide's Display and Show Again Flags sections and the
#: Tracker pane's display switches), in display order.
PREFERENCES: tuple[Preference, ...] = (
    Preference("point_labels_all", "Point Labels : All", False,
               "Draw the label of every labelled point in the 2D and 3D views."),
    Preference("point_labels_selected", "Point Labels : Selected", True,
               "Draw labels of the selected points."),
    Preference("point_labels_preselected", "Point Labels : Pre-Selected", True,
               "Draw the label of the point under the mouse cursor (the pre-selection)."),
    Preference("label_font_size", "Font Size", 10,
               "Text size of point labels in the views. Range is our choice.",
               minimum=4, maximum=72, unit="pt"),
    Preference("show_version_check_dialog", "Show Version Check Dialog On Startup", True,
               "At start-up, say when a newer release is available. Kept for Help > Check For "
               "Updates, which carapost does not have yet: nothing reads it today."),
    Preference("tracker_update_timeline_every_frame", "Update Timeline Every Frame", True,
               "Refresh the continuity chart and Selected Point pane while target tracking"
               " (a few times a second); off, they change when the run ends."
               " Default is our choice (the guide gives none)."),
    Preference("tracker_update_2d_view_every_frame", "Update 2D View Every Frame", False,
               "Show each tracked frame in the views while target tracking (slower)."
               " Default is our choice (the guide gives none)."),
)
#: Frame-access preferences (ours: the guide has no such settings), shown in the
#: Properties pane as "Frames (this computer)". The cache size applies to the next take
#: opened; its default is `carapost.io.frameservice.DEFAULT_CACHE_MB` (not imported
#: here, so that reading a setting never loads the decoders).
FRAME_PREFERENCES: tuple[Preference, ...] = (
    Preference("frame_cache_mb", "Image Cache", 1500,
               "Memory for decoded camera images (8-bit grey, shared by the views, playback "
               "and the processing that reads images). 1500 MB holds about 500 frames of "
               "four 1280x720 cameras. Applies to the next take opened.",
               minimum=64, maximum=65536, unit="MB", step=250),
    Preference("build_proxies_after_import", "Build Playback Proxies After Import", True,
               "Write fast-decoding copies of the camera videos in the background when a "
               "take opens, so playback runs at the take's frame rate (View > Build "
               "Playback Proxies writes them on request). Display only; deleting them "
               "loses nothing."),
    Preference("start_detector_after_import", "Start Blob Detector When a Take Opens", True,
               "Load the blob detector when the window opens and start its two worker "
               "processes in the background when a take with images opens, so the first "
               "Detect Blobs does not wait for them (about 250 MB while they run; they "
               "stop after two minutes without work)."),
)
_PREFERENCE_BY_KEY = {p.key: p for p in PREFERENCES + FRAME_PREFERENCES}


def make_settings() -> QSettings:
    """The settings store (a private INI file when ``CARAPOST_SETTINGS_DIR`` is set)."""
    folder = os.environ.get(SETTINGS_DIR_ENV)
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        return QSettings(str(Path(folder) / "carapost.ini"), QSettings.Format.IniFormat)
    return QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION,
                     APPLICATION)


def frame_cache_mb(settings: QSettings) -> float:
    """Size of the decoded-image cache in megabytes (the ``frame_cache_mb``
    preference). It holds 8-bit grey images of the open take, shared by the views,
    playback and the jobs that read images."""
    return float(preference(settings, "frame_cache_mb"))


def build_proxies(settings: QSettings) -> bool:
    """Whether playback proxies (fast-decoding copies of the camera videos, in the user
    cache, for display only) are written in the background when a take opens (the
    ``build_proxies_after_import`` preference)."""
    return bool(preference(settings, "build_proxies_after_import"))


def start_detector(settings: QSettings) -> bool:
    """Whether the blob detector's processes are started when a take opens (the
    ``start_detector_after_import`` preference)."""
    return bool(preference(settings, "start_detector_after_import"))


def set_build_proxies(settings: QSettings, on: bool) -> None:
    """Store whether proxies are written after a take opens."""
    set_preference(settings, "build_proxies_after_import", bool(on))


def recent_files(settings: QSettings) -> list[str]:
    """The recent project files, newest first (at most eight)."""
    value = settings.value("recent_files", [])
    if isinstance(value, str):
        value = [value] if value else []
    return [str(v) for v in (value or [])][:MAX_RECENT]


def add_recent_file(settings: QSettings, path: str) -> list[str]:
    """Put ``path`` at the top of the recent files; returns the new list."""
    path = str(Path(path).absolute())
    files = [p for p in recent_files(settings) if p != path]
    files.insert(0, path)
    files = files[:MAX_RECENT]
    settings.setValue("recent_files", files)
    return files


def clear_recent_files(settings: QSettings) -> None:
    """Forget the recent files."""
    settings.setValue("recent_files", [])


class _PreferenceSignals(QObject):
    """Tells every window of this process that a preference changed (key)."""

    changed = Signal(str)


_SIGNALS: _PreferenceSignals | None = None


def preference_signals() -> _PreferenceSignals:
    """The process-wide notifier: ``changed(key)`` after :func:`set_preference` stored
    a new value, so every view of every window redraws with it."""
    global _SIGNALS
    if _SIGNALS is None:
        _SIGNALS = _PreferenceSignals()
    return _SIGNALS


def _clamp(pref: Preference, value: int) -> int:
    if pref.minimum is not None:
        value = max(value, pref.minimum)
    if pref.maximum is not None:
        value = min(value, pref.maximum)
    return value


def preference(settings: QSettings, key: str) -> bool | int:
    """The user's value of a GUI preference (its default when never set or unreadable;
    a whole number is clamped to its range).

    Raises
    ------
    KeyError
        If ``key`` is not one of :data:`PREFERENCES`.
    """
    pref = _PREFERENCE_BY_KEY[key]
    value = settings.value(f"{_PREFERENCES_GROUP}/{key}", pref.default)
    if pref.kind == "int":
        try:
            return _clamp(pref, int(float(value)))
        except (TypeError, ValueError):  # a hand-edited or foreign settings file
            return int(pref.default)
    if isinstance(value, str):  # INI files give text back
        return value.strip().lower() in ("true", "1", "yes", "on")
    return bool(value)


def set_preference(settings: QSettings, key: str, value: bool | int) -> None:
    """Store a GUI preference for this user (a whole number clamped to its range) and
    emit :func:`preference_signals` ``changed(key)`` if the value changed.

    Raises
    ------
    KeyError
        If ``key`` is not one of :data:`PREFERENCES`.
    """
    pref = _PREFERENCE_BY_KEY.get(key)
    if pref is None:
        raise KeyError(f"unknown preference {key!r}")
    new: bool | int = _clamp(pref, int(value)) if pref.kind == "int" else bool(value)
    if preference(settings, key) == new and settings.contains(f"{_PREFERENCES_GROUP}/{key}"):
        return
    settings.setValue(f"{_PREFERENCES_GROUP}/{key}", new)
    preference_signals().changed.emit(key)
