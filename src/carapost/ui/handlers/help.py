"""Help menu: documentation, licences, About."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import QUrl
from PySide6.QtGui import QDesktopServices

from carapost.ui.context import ActionContext

#: Runtime dependencies (pyproject's ``dependencies``) and their licences (Help > Show
#: 3rd Party Licenses); test-only packages (ezc3d, c3d, ufbx) are not shipped.
THIRD_PARTY = (
    ("PySide6 (Qt for Python)", "LGPL-3.0"), ("numpy", "BSD-3-Clause"),
    ("scipy", "BSD-3-Clause"), ("numba", "BSD-2-Clause"),
    ("opencv-python-headless", "Apache-2.0 (OpenCV), MIT"), ("pyqtgraph", "MIT"),
    ("lxml", "BSD-3-Clause"), ("av (PyAV)", "BSD-3-Clause; its bundled FFmpeg LGPL-2.1+"),
    ("threadpoolctl", "BSD-3-Clause"), ("rich", "MIT"),
    ("dask (and distributed)", "BSD-3-Clause"),
    ("greenlet", "MIT AND PSF-2.0"),
)


def open_help(ctx: ActionContext) -> None:
    """View Latest Help Online / View Installed Help: the documentation folder."""
    root = Path(__file__).resolve().parents[4]
    target = root / "docs" if (root / "docs").is_dir() else root
    QDesktopServices.openUrl(QUrl.fromLocalFile(str(target)))


def show_licence(ctx: ActionContext) -> None:
    """Help > Licensing."""
    ctx.dialogs.info("Licensing", "carapost is free software under the MIT licence; "
                     "it needs no licence key.")


def show_third_party(ctx: ActionContext) -> None:
    """Help > Show 3rd Party Licenses."""
    ctx.dialogs.info("Third-party licences",
                     "\n".join(f"{name}: {lic}" for name, lic in THIRD_PARTY))


def show_about(ctx: ActionContext) -> None:
    """Help > About."""
    from carapost import __version__ as version

    ctx.dialogs.info("About carapost", f"carapost {version}\nPost-processing of "
                     "head-mounted facial motion capture.\nMIT licence.")
