"""View > Show Calibration Brim SVG: a floating window with the imported brim drawing."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt
from PySide6.QtSvgWidgets import QSvgWidget
from PySide6.QtWidgets import QWidget

from carapost.ui.context import ActionContext

TITLE = "Show Calibration Brim SVG"


def show_brim_svg(ctx: ActionContext) -> QWidget | None:
    """Open the custom brim's SVG (File > Import Calibration Brim [svg]) in a floating
    window; says so when the take's brim did not come from an SVG."""
    path = ctx.project.take.metadata.get("brim_svg")
    if not path:
        ctx.dialogs.info(TITLE, "This take's brim did not come from an SVG: import a custom "
                                "brim with File > Import Calibration Brim [svg].")
        return None
    p = Path(path)
    if not p.is_file():
        ctx.report_error(TITLE, f"{TITLE}: the brim SVG {p} is missing", show=True)
        return None
    window = QSvgWidget(str(p))
    window.setWindowTitle(f"Calibration brim: {p.name}")
    window.setWindowFlag(Qt.WindowType.Tool, True)
    window.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
    size = window.renderer().defaultSize()
    if size.width() > 0 and size.height() > 0:
        scale = min(900 / size.width(), 700 / size.height(), 4.0)
        window.resize(int(size.width() * scale), int(size.height() * scale))
    window.setStyleSheet("background: white;")
    window.show()
    ctx.brim_window = window  # keep it alive while it is open
    return window
