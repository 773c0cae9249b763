"""Every modal question the window asks, in one place (tests replace it with FakeDialogs)."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QColorDialog,
    QFileDialog,
    QInputDialog,
    QLineEdit,
    QMessageBox,
    QWidget,
)


class Dialogs:
    """Every modal question the window asks, in one place (tests replace it)."""

    def __init__(self, parent: QWidget) -> None:
        self.parent = parent

    def open_file(self, title: str, filters: str, folder: bool = False) -> str | None:
        """A path to read, or None."""
        if folder:
            path = QFileDialog.getExistingDirectory(self.parent, title)
        else:
            path, _ = QFileDialog.getOpenFileName(self.parent, title, "", filters)
        return path or None

    def save_file(self, title: str, filters: str, default: str = "") -> str | None:
        """A path to write, or None."""
        path, _ = QFileDialog.getSaveFileName(self.parent, title, default, filters)
        return path or None

    def ask_save(self, name: str) -> str:
        """``"save"``, ``"discard"`` or ``"cancel"`` for unsaved changes."""
        box = QMessageBox.question(
            self.parent, "Unsaved changes", f"Save the changes to {name}?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard
            | QMessageBox.StandardButton.Cancel)
        return {QMessageBox.StandardButton.Save: "save",
                QMessageBox.StandardButton.Discard: "discard"}.get(box, "cancel")

    def confirm(self, title: str, text: str) -> bool:
        """Yes/no question."""
        return QMessageBox.question(self.parent, title, text) == QMessageBox.StandardButton.Yes

    def get_int(self, title: str, label: str, value: int, lo: int, hi: int) -> int | None:
        """A whole number, or None."""
        v, ok = QInputDialog.getInt(self.parent, title, label, value, lo, hi)
        return int(v) if ok else None

    def get_text(self, title: str, label: str, value: str = "") -> str | None:
        """A line of text, or None."""
        v, ok = QInputDialog.getText(self.parent, title, label, text=value)
        return v if ok else None

    def get_completed_text(self, title: str, label: str, value: str,
                           completions: list[str]) -> str | None:
        """A line of text with completion from ``completions`` (case-insensitive, any
        part of the name), or None."""
        from PySide6.QtWidgets import QCompleter

        dialog = QInputDialog(self.parent)
        dialog.setWindowTitle(title)
        dialog.setLabelText(label)
        dialog.setTextValue(value)
        edit = dialog.findChild(QLineEdit)
        if edit is not None:
            completer = QCompleter(completions, dialog)
            completer.setCaseSensitivity(Qt.CaseSensitivity.CaseInsensitive)
            completer.setFilterMode(Qt.MatchFlag.MatchContains)
            edit.setCompleter(completer)
        return dialog.textValue() if dialog.exec() else None

    def get_colour(self, title: str) -> tuple[int, int, int] | None:
        """An RGB colour, or None."""
        c = QColorDialog.getColor(parent=self.parent, title=title)
        return (c.red(), c.green(), c.blue()) if c.isValid() else None

    def info(self, title: str, text: str) -> None:
        """A message that does not block."""
        self._box(QMessageBox.Icon.Information, title, text)

    def error(self, title: str, text: str) -> None:
        """An error message that does not block."""
        self._box(QMessageBox.Icon.Critical, title, text)

    def _box(self, icon: QMessageBox.Icon, title: str, text: str) -> None:
        box = QMessageBox(icon, title, text, QMessageBox.StandardButton.Ok, self.parent)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        box.setModal(False)
        box.show()

