"""Persistent user settings (window layout, recent files, GUI preferences): QSettings.

GUI preferences that do not belong to a take (the guide's Show Again Flags and the
Tracker pane's "Update ... Every Frame" switches) are user settings, declared in
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

from PySide6.QtCore import QSettings

ORGANISATION = "carapost"
APPLICATION = "carapost"
SETTINGS_DIR_ENV = "CARAPOST_SETTINGS_DIR"
MAX_RECENT = 8
_PREFERENCES_GROUP = "preferences"


@dataclass(frozen=True)
class Preference:
    """A yes/no GUI preference kept in the user settings.

    Attributes
    ----------
    key : str
        Settings key (the property key it had in project files).
    label : str
        Name as displayed (the reference guide's name).
    default : bool
    help : str
    """

    key: str
    label: str
    default: bool
    help: str


#: Every GUI preference (the guide's Show Again Flags section and the Tracker pane's
#: display switches), in display order.
PREFERENCES: tuple[Preference, ...] = (
    Preference("show_version_check_dialog", "Show Version Check Dialog On Startup", True,
               "At start-up, say when a newer release is available. Kept for Help > Check For "
               "Updates, which carapost does not have yet: nothing reads it today."),
    Preference("tracker_update_timeline_every_frame", "Update Timeline Every Frame", True,
               "Refresh the continuity chart and Selected Point pane while target tracking."
               " For the Target Tracker, which is not available yet: nothing reads it today."
               " Default is our choice (the guide gives none)."),
    Preference("tracker_update_2d_view_every_frame", "Update 2D View Every Frame", False,
               "Show each tracked frame in the views while target tracking (slower)."
               " Default is our choice (the guide gives none)."),
)
#: Settings key: write playback proxies in the background when a take opens.
BUILD_PROXIES_KEY = "frames/build_proxies"
_PREFERENCE_BY_KEY = {p.key: p for p in PREFERENCES}


def make_settings() -> QSettings:
    """The settings store (a private INI file when ``CARAPOST_SETTINGS_DIR`` is set)."""
    folder = os.environ.get(SETTINGS_DIR_ENV)
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        return QSettings(str(Path(folder) / "carapost.ini"), QSettings.Format.IniFormat)
    return QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION,
                     APPLICATION)


#: Settings key of the decoded-image cache size (megabytes).
FRAME_CACHE_KEY = "frames/cache_mb"
#: Bounds of the cache size a user may set (megabytes).
FRAME_CACHE_RANGE = (64.0, 65536.0)


def frame_cache_mb(settings: QSettings) -> float:
    """Size of the decoded-image cache in megabytes (default 1500: ~500 frames of four
    1280x720 cameras). It holds 8-bit gray images of the open take, shared by the
    views, playback and the jobs that read images."""
    from carapost.io.frameservice import DEFAULT_CACHE_MB

    try:
        value = float(settings.value(FRAME_CACHE_KEY, DEFAULT_CACHE_MB))
    except (TypeError, ValueError):
        value = DEFAULT_CACHE_MB
    lo, hi = FRAME_CACHE_RANGE
    return min(max(value, lo), hi)


def set_frame_cache_mb(settings: QSettings, value: float) -> None:
    """Store the decoded-image cache size (clamped to `FRAME_CACHE_RANGE`); it applies
    to the next take opened."""
    lo, hi = FRAME_CACHE_RANGE
    settings.setValue(FRAME_CACHE_KEY, min(max(float(value), lo), hi))


def build_proxies(settings: QSettings) -> bool:
    """Whether playback proxies (fast-decoding copies of the camera videos, in the user
    cache, for display only) are written in the background when a take opens (default
    yes; View > Build Playback Proxies writes them on request)."""
    value = settings.value(BUILD_PROXIES_KEY, True)
    if isinstance(value, str):
        return value.strip().lower() in ("true", "1", "yes", "on")
    return bool(value)


def set_build_proxies(settings: QSettings, on: bool) -> None:
    """Store whether proxies are written after a take opens."""
    settings.setValue(BUILD_PROXIES_KEY, bool(on))


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


def preference(settings: QSettings, key: str) -> bool:
    """The user's value of a GUI preference (its default when never set).

    Raises
    ------
    KeyError
        If ``key`` is not one of :data:`PREFERENCES`.
    """
    pref = _PREFERENCE_BY_KEY[key]
    value = settings.value(f"{_PREFERENCES_GROUP}/{key}", pref.default)
    if isinstance(value, str):  # INI files give text back
        return value.strip().lower() in ("true", "1", "yes", "on")
    return bool(value)


def set_preference(settings: QSettings, key: str, value: bool) -> None:
    """Store a GUI preference for this user.

    Raises
    ------
    KeyError
        If ``key`` is not one of :data:`PREFERENCES`.
    """
    if key not in _PREFERENCE_BY_KEY:
        raise KeyError(f"unknown preference {key!r}")
    settings.setValue(f"{_PREFERENCES_GROUP}/{key}", bool(value))
