"""A technician's first day in the window: labelling, charts, re-solving, empty states."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt

from tests.ui.test_window import activate, settle


def test_labelling_pane_filter_keyboard_and_assign_and_next(make_window, demo, qtbot):
    p, frames = demo
    p.labels += ["Upper_Lid_Inner_R", "Upper_Lid_Inner_L", "Chin_Lo_R"]
    w = make_window(p, frames)
    pane = w.pane("Labelling")
    settle(qtbot, w)
    names = list(p.labels)
    # the filter narrows the list; Escape clears it
    qtbot.keyClicks(pane.filter, "m1")
    shown = [pane.list.item(r).text() for r in pane.visible_rows()]
    assert shown == [n for n in names if "m1" in n.lower()] and len(shown) < len(names)
    qtbot.keyClick(pane.filter, Qt.Key.Key_Escape)
    assert len(pane.visible_rows()) == len(names)
    # Assign and Next: each point selected takes the current label, the next unassigned
    # label becomes current: one click per point
    unlabelled = [int(p.points.ids[c]) for c in range(p.n_points) if not p.points.labels[c]]
    todo = [n for n in names if n not in p.points.labels]
    assert len(todo) >= 3
    pane.next_box.setChecked(True)
    pane.move_to(names.index(todo[0]))
    entries = len(w.context.session.history())
    for pid in unlabelled[:3]:
        p.set_selection(points=[pid])
        settle(qtbot, w)
    cols = p.points.index_of(np.array(unlabelled[:3]))
    assert [p.points.labels[c] for c in cols] == todo[:3]
    assert pane.current_label() == todo[3]
    assert len(w.context.session.history()) == entries + 3       # one History entry per label
    # keyboard: Down from the filter into the list, Enter assigns and moves on
    pane.next_box.setChecked(False)
    p.set_selection(points=[unlabelled[3]])
    settle(qtbot, w)
    qtbot.keyClicks(pane.filter, todo[4])
    qtbot.keyClick(pane.filter, Qt.Key.Key_Down)
    assert pane.current_label() == todo[4]
    qtbot.keyClick(pane.list, Qt.Key.Key_Return)
    assert p.points.labels[int(p.points.index_of(np.array([unlabelled[3]]))[0])] == todo[4]
    assert "assigned" in pane.status.text()


def test_ctrl_p_selects_a_point_by_label_and_ctrl_r_completes(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    activate(qtbot, w)
    col = next(c for c in range(p.n_points) if p.points.labels[c])
    label = p.points.labels[col]
    w.dialogs.texts.append(label.lower())            # case does not matter when unique
    qtbot.keyClick(w, Qt.Key.Key_P, Qt.KeyboardModifier.ControlModifier)
    assert p.selection.points == {int(p.points.ids[col])}
    assert label in w.dialogs.completions
    w.dialogs.texts.append("No_Such_Marker")
    w.action("view.select_point").trigger()
    assert p.selection.points == {int(p.points.ids[col])}   # unchanged, refused
    # Rename offers the label list, unassigned labels first
    other = next(c for c in range(p.n_points) if not p.points.labels[c])
    p.set_selection(points=[int(p.points.ids[other])])
    free = [n for n in p.labels if n not in p.points.labels]
    w.dialogs.texts.append(free[0])
    qtbot.keyClick(w, Qt.Key.Key_R, Qt.KeyboardModifier.ControlModifier)
    assert w.dialogs.completions[: len(free)] == free
    assert p.points.labels[other] == free[0]
