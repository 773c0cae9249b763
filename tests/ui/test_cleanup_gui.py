"""The clean-up items through the real window actions: Import C3D, Interpolate Gaps,
Filter Trajectories, Remove Filtering, Find Problems (the pane, jump-to-frame, one-click
repair)."""

from __future__ import annotations

import numpy as np

from carapost.algorithms.codes import RECON_FILTERED, RECON_INTERPOLATED
from carapost.io.c3d import write_c3d
from tests.algorithms.test_gapfill import face_take


def _c3d(tmp_path, spike=True):
    X = face_take(frames=800, points=20, seed=6)
    Xg = X.copy()
    Xg[200:240, 3] = np.nan
    if spike:
        Xg[500, 8] += [7.0, 0.0, 0.0]
    path = tmp_path / "take.c3d"
    write_c3d(path, Xg, labels=[f"F{i}" for i in range(20)], rate=100.0)
    return path, X


def _run(qtbot, w, action):
    w.action(action).trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    assert w.last_error == "", w.last_error


def test_import_c3d_interpolate_filter_from_the_menus(make_window, qtbot, tmp_path):
    path, X = _c3d(tmp_path, spike=False)
    w = make_window()
    w.dialogs.open_paths.append(str(path))
    _run(qtbot, w, "file.import_c3d")
    p = w.project
    assert (p.n_frames, p.points.count, p.n_cameras) == (800, 20, 0)
    assert p.points.labels[3] == "F3"
    _run(qtbot, w, "process.interpolate")
    assert len(w.stack.history()) == 1
    assert (p.points.recon[200:240, 3] == RECON_INTERPOLATED).all()
    err = np.linalg.norm(p.points.positions[200:240, 3] - X[200:240, 3], axis=-1)
    assert err.max() < 5.0 and np.isfinite(p.points.sigma[200:240, 3]).all()
    # the Selected Point pane says what the sample is and its estimated error
    from carapost.ui.panes import SelectedPointPane

    p.set_selection(points=[int(p.points.ids[3])])
    w.set_frame(220)
    w.flush()
    pane = w.findChild(SelectedPointPane)
    assert "interpolated, estimated error" in pane.sample.text()
    # the Graph view shades +- the estimate around the filled samples of the point
    from carapost.ui.views.graph import GraphView

    graph = GraphView(w.context.view)
    qtbot.addWidget(graph)
    graph.refresh(None)
    xs = graph.bands[0].opts["x"]
    assert len(xs) == 40 and xs.min() == 200 and xs.max() == 239
    assert np.allclose(graph.bands[0].opts["height"], 2 * p.points.sigma[200:240, 3])
    unfiltered = p.points.positions.copy()
    _run(qtbot, w, "process.filter")
    assert len(w.stack.history()) == 2
    assert (p.points.recon[:200, 3] == RECON_FILTERED).all()
    # Remove Filtering (the selected point): one History entry, raw data back
    _run(qtbot, w, "process.remove_filter")
    assert len(w.stack.history()) == 3
    assert np.array_equal(p.points.positions[:, 3], unfiltered[:, 3], equal_nan=True)
    assert (p.points.recon[:200, 3] != RECON_FILTERED).all()
    w.stack.undo()
    w.stack.undo()
    w.stack.undo()
    assert np.isnan(p.points.positions[200:240, 3]).all()


def test_find_problems_pane_jump_and_repair(make_window, qtbot, tmp_path):
    from carapost.ui.problems import ProblemsPane

    path, X = _c3d(tmp_path)
    w = make_window()
    w.dialogs.open_paths.append(str(path))
    _run(qtbot, w, "file.import_c3d")
    p = w.project
    _run(qtbot, w, "process.find_problems")
    pane = w.findChild(ProblemsPane)
    kinds = [(q.kind, q.first) for q in pane.problems()]
    assert ("gap", 200) in kinds and ("spike", 500) in kinds and len(kinds) == 2
    pane.list.setCurrentRow(kinds.index(("spike", 500)))
    assert p.current_frame == 500 and p.selection.points == {int(p.points.ids[8])}
    pane.repair_button.click()
    w.flush()
    assert len(w.stack.history()) == 1
    assert np.linalg.norm(p.points.positions[500, 8] - X[500, 8]) < 1.0
    assert [q.kind for q in pane.problems()] == ["gap"]
    pane.list.setCurrentRow(0)
    assert p.current_frame == 199                   # the frame before the gap
    pane.repair_current()
    assert pane.problems() == [] and len(w.stack.history()) == 2
