"""Persistent user settings (window layout, recent files) through QSettings.

Settings live under the organisation ``carapost``. Setting the environment variable
``CARAPOST_SETTINGS_DIR`` puts them in ``<dir>/carapost.ini`` instead, which the tests
use so they never touch the user's own settings.
"""

from __future__ import annotations

import os
from pathlib import Path

from PySide6.QtCore import QSettings

ORGANISATION = "carapost"
APPLICATION = "carapost"
SETTINGS_DIR_ENV = "CARAPOST_SETTINGS_DIR"
MAX_RECENT = 8


def make_settings() -> QSettings:
    """The settings store (a private INI file when ``CARAPOST_SETTINGS_DIR`` is set)."""
    folder = os.environ.get(SETTINGS_DIR_ENV)
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        return QSettings(str(Path(folder) / "carapost.ini"), QSettings.Format.IniFormat)
    return QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION,
                     APPLICATION)


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
