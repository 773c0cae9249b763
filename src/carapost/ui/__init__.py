"""carapost.ui: the PySide6 main window, views and panes."""

from carapost.ui._qt_compat import protect_true

protect_true()
