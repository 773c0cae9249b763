"""The stabilisation items of the window: Stabilize Data on the worker, Ctrl+Shift+S,
Align Data with its axes question, Remove Stabilization, the views' positions."""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QKeySequence

from carapost.io.cara import load_project, save_project
from carapost.model.stabilization import display_positions
from carapost.synth.demo_project import scene_project


def test_stabilise_toggle_align_remove(make_window, qtbot, tmp_path):
    p, _, _ = scene_project(frames=40, preset="speech", seed=1)
    w = make_window(p)
    labels = list(p.points.labels)
    three = [labels.index(n) for n in ("Nose_Tip", "Forehead_Hi_L", "Forehead_Hi_R")]
    w.action("process.stab_auto").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    qtbot.waitUntil(lambda: p.stabilization is not None, timeout=10_000)
    assert p.show_stabilized
    assert w.stack.history()[-1].description.startswith("Stabilize Data [Automatic]")
    toggle = w.action("view.show_stabilized")
    assert toggle.shortcut() == QKeySequence("Ctrl+Shift+S")
    qtbot.waitUntil(toggle.isChecked, timeout=5_000)
    f = p.current_frame = 30
    shown = display_positions(p, f)
    toggle.trigger()  # off: the views show raw data
    assert not p.show_stabilized
    assert np.array_equal(display_positions(p, f), p.points.positions[f], equal_nan=True)
    toggle.trigger()
    assert np.array_equal(display_positions(p, f), shown, equal_nan=True)
    # Align Data: three selected points, the axes from the dialog
    p.set_selection(points=[int(p.points.ids[c]) for c in sorted(three)])
    w.dialogs.texts.append("xy")
    n = len(w.stack.history())
    w.action("process.align").trigger()
    assert p.alignment is not None and len(w.stack.history()) == n + 1
    assert p.alignment.point_ids == tuple(sorted(int(p.points.ids[c]) for c in three))
    # clicked one by one, highest id first: the first click is the origin
    clicks = sorted((int(p.points.ids[c]) for c in three), reverse=True)
    p.set_selection(points=[])
    for k in range(3):
        p.set_selection(points=p.selection.points | {clicks[k]})
    w.dialogs.texts.append("xy")
    w.action("process.align").trigger()
    assert p.alignment.point_ids == tuple(clicks) and len(w.stack.history()) == n + 2
    saved = save_project(p, tmp_path / "aligned.cara", autosave=True)
    assert load_project(saved).selection.ordered_points() == clicks  # kept in the file
    # a refusal is reported, not raised
    p.set_selection(points=[int(p.points.ids[three[0]])])
    w.action("process.align").trigger()
    assert len(w.stack.history()) == n + 2
    w.action("process.remove_stab").trigger()
    assert p.stabilization is None and p.alignment is None and not p.show_stabilized
    w.action("edit.undo").trigger()
    assert p.stabilization is not None and p.alignment is not None
