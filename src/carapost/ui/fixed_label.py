"""Labels of a fixed size, for text that changes while the window is busy."""

from __future__ import annotations

from PySide6.QtWidgets import QLabel


def fix_to_text(label: QLabel, text: str, *, min_width: int = 0) -> None:
    """Give ``label`` the fixed size of ``text`` with every digit at its widest.

    A label whose size follows its text makes Qt lay its layout, and often the whole
    main window, out again each time a digit changes (a frame counter during playback,
    a rate shown once a second). A label of fixed width and height does not even tell
    its layout. ``text`` is the longest text the label will show; each of its digits is
    replaced by the font's widest digit so that no number of that length is wider.

    Parameters
    ----------
    label : QLabel
        The label; its font and contents margins are used.
    text : str
        The longest text it will show (digits stand for any digit).
    min_width : int
        A lower bound on the width, in pixels.
    """
    fm = label.fontMetrics()
    widest = max("0123456789", key=fm.horizontalAdvance)
    sized = "".join(widest if ch.isdigit() else ch for ch in text)
    margins = label.contentsMargins()
    # 6 px of slack: some styles draw a frame inside the margins
    width = fm.horizontalAdvance(sized) + margins.left() + margins.right() + 6
    height = max(label.sizeHint().height(), fm.height() + margins.top() + margins.bottom())
    label.setFixedSize(max(min_width, width), height)
