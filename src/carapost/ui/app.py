"""Application entry point: ``carapost gui [PROJECT]``."""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path

from PySide6.QtGui import QColor, QPalette
from PySide6.QtWidgets import QApplication

log = logging.getLogger("carapost.ui")

#: The interpreter's thread switch interval in the window process, in seconds (Python's
#: default is 0.005). Every return of the GUI thread from Qt into a Python slot takes
#: the GIL back; while a decoder, the import's video checks or a job runs Python, each
#: such return can wait up to one interval, and a turn of the event loop makes many.
#: At 1 ms the longest tick gaps fell from 45-54 to 38-43 ms on the demo take with no
#: loss of decoding or playback rate (docs/benchmarks.md, thirteenth session).
GUI_SWITCH_INTERVAL_S = 0.001


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
        sys.setswitchinterval(GUI_SWITCH_INTERVAL_S)
        app = QApplication(argv if argv is not None else sys.argv[:1])
        app.setOrganizationName("carapost")
        app.setApplicationName("carapost")
        app.setStyle("Fusion")
        app.setPalette(dark_palette())
        app.setStyleSheet(check_box_style())
    return app  # type: ignore[return-value]


def check_box_style() -> str:
    """Check boxes with a visible frame: Fusion draws an unchecked box in the dark
    palette's own colours, nearly invisible."""
    from pathlib import Path

    tick = (Path(__file__).resolve().parents[1] / "resources" / "icons" / "check.svg")
    tick_url = tick.as_posix()
    return (
        "QCheckBox::indicator, QAbstractItemView::indicator { width: 13px; height: 13px; "
        "border: 1px solid #9a9a9a; border-radius: 2px; background: #26262a; }"
        "QCheckBox::indicator:hover, QAbstractItemView::indicator:hover "
        "{ border-color: #d0d0d0; }"
        "QCheckBox::indicator:checked, QAbstractItemView::indicator:checked "
        f"{{ background: #3c6eaa; border-color: #6a9ad0; image: url({tick_url}); }}"
        "QCheckBox::indicator:disabled { border-color: #5a5a5a; background: #303032; }")


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
