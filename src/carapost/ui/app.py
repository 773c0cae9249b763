"""Application entry point: ``carapost gui [PROJECT]``."""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

from PySide6.QtGui import QColor, QPalette
from PySide6.QtWidgets import QApplication

log = logging.getLogger("carapost.ui")


def dark_palette() -> QPalette:
    """The dark Fusion palette the views' colours are designed for."""
    pal = QPalette()
    base, window, text = QColor(32, 32, 34), QColor(48, 48, 50), QColor(225, 225, 225)
    roles = {
        QPalette.ColorRole.Window: window, QPalette.ColorRole.WindowText: text,
        QPalette.ColorRole.Base: base, QPalette.ColorRole.AlternateBase: window,
        QPalette.ColorRole.ToolTipBase: QColor(60, 60, 60),
        QPalette.ColorRole.ToolTipText: text, QPalette.ColorRole.Text: text,
        QPalette.ColorRole.Button: window, QPalette.ColorRole.ButtonText: text,
        QPalette.ColorRole.Highlight: QColor(60, 110, 170),
        QPalette.ColorRole.HighlightedText: QColor(255, 255, 255),
        QPalette.ColorRole.PlaceholderText: QColor(140, 140, 140),
    }
    for role, colour in roles.items():
        pal.setColor(role, colour)
    for role in (QPalette.ColorRole.Text, QPalette.ColorRole.ButtonText,
                 QPalette.ColorRole.WindowText):
        pal.setColor(QPalette.ColorGroup.Disabled, role, QColor(120, 120, 120))
    return pal


def application(argv: list[str] | None = None) -> QApplication:
    """The QApplication (created once, styled)."""
    app = QApplication.instance()
    if app is None:
        app = QApplication(argv if argv is not None else sys.argv[:1])
        app.setOrganizationName("carapost")
        app.setApplicationName("carapost")
        app.setStyle("Fusion")
        app.setPalette(dark_palette())
    return app  # type: ignore[return-value]


def open_path(window, path: str) -> bool:
    """Open a ``.cara`` project, or import a take from any other file.

    A take is imported by File > Import Camera Files itself
    (`carapost.ui.handlers.file.import_take`, which reads it with
    `carapost.session.read_take`, the function behind `carapost.Session.import_take`), so
    ``carapost gui take.json`` builds the same project as the menu and the scripts.
    """
    from carapost.ui.handlers import file as file_menu

    if Path(path).suffix.lower() == ".cara":
        return file_menu.open_project(window.context, path)
    return file_menu.import_take(window.context, path)


def _warm_up_detector() -> None:
    """Load the blob detector's compiled kernels (compiled once after installation,
    ~3 s; then loaded from numba's cache in a fraction of a second) off the GUI thread,
    so the first Blob Preview or Detect Blobs does not wait for them."""
    def work() -> None:
        try:
            from carapost.algorithms.blobs import warm_up

            warm_up()
        except Exception:  # the detector reports real problems when it is used
            log.debug("blob detector warm-up failed", exc_info=True)

    threading.Thread(target=work, name="carapost-warm-up", daemon=True).start()


def run_gui(path: str | None = None) -> int:
    """Open the main window (on ``path`` if given) and run until it closes.

    Returns
    -------
    int
        Exit status (0 on a normal close).
    """
    from carapost.ui.mainwindow import MainWindow

    app = application()
    window = MainWindow()
    window.show()
    _warm_up_detector()
    if path:
        if not Path(path).exists():
            window.report_error("Open", f"{path}: no such file")
        else:
            open_path(window, path)
    else:
        from carapost.ui.handlers.file import offer_untitled_recovery

        offer_untitled_recovery(window.context)
    return int(app.exec())
