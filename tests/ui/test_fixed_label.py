"""``fix_to_text``: a label sized for the widest digits holds any number of that length."""

from __future__ import annotations

from PySide6.QtWidgets import QLabel

from carapost.ui.fixed_label import fix_to_text


def test_every_number_of_the_length_fits_and_the_size_stays(qtbot) -> None:
    label = QLabel()
    qtbot.addWidget(label)
    fix_to_text(label, "frame 000 / 000")
    size = label.size()
    fm = label.fontMetrics()
    for d in "0123456789":
        text = f"frame {d * 3} / {d * 3}"
        label.setText(text)
        assert label.size() == size
        assert fm.horizontalAdvance(text) <= size.width()
    assert label.minimumSize() == label.maximumSize() == size


def test_min_width_is_a_lower_bound(qtbot) -> None:
    label = QLabel()
    qtbot.addWidget(label)
    fix_to_text(label, "1", min_width=300)
    assert label.width() == 300
    fix_to_text(label, "1" * 200, min_width=300)
    assert label.width() > 300
