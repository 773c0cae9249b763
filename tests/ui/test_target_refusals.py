"""Bad input to the Target Tracker in the window: a clear message in the status bar (and
the Log), nothing changed, no History entry."""

from __future__ import annotations

import copy

import numpy as np

from carapost.algorithms.codes import SOURCE_TARGET
from tests.commands.test_edit_commands import snapshot
from tests.ui.test_target_sizes_ui import _drag
from tests.ui.test_target_tracker_ui import (  # noqa: F401 (take is a fixture)
    _click_image,
    _keyed_point,
    _run,
    _view,
    _window,
    take,
)

BUTTONS = ("back_to_start", "back_one", "forward_one", "forward_to_end")


def _refused(w, before, n, text, qtbot=None):
    assert text in w.last_error, w.last_error
    if qtbot is not None:   # shown after the runner's own "finished" message
        qtbot.waitUntil(lambda: text in w.statusBar().currentMessage(), timeout=5000)
    assert text in w.statusBar().currentMessage()
    assert snapshot(w.context.project) == before
    assert len(w.stack.history()) == n


def test_no_point_selected(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    p.set_selection(points=[])
    before, n = snapshot(p), len(w.stack.history())
    pane = w.pane("Tracker")
    for name in (*BUTTONS, "add_keyframe", "clear"):
        w.context.last_error = ""
        pane.buttons[name].click()
        _refused(w, before, n, "no point is selected")
        assert not w.runner.busy
    w.action("edit.gaps_to_keys").trigger()
    _refused(w, before, n, "no point is selected")
    w.action("edit.edit_target_track").trigger()
    _click_image(w, 0, (100.0, 100.0))
    _refused(w, before, n, "select one point")


def test_keyframe_outside_the_image(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    before, n = snapshot(p), len(w.stack.history())
    w.action("edit.add_target_track").trigger()
    for xy in ((2.0, 2.0), (639.0, 180.0), (320.0, 355.0)):   # its box leaves the image
        _click_image(w, 0, xy)
        _refused(w, before, n, "does not fit")
    pid, _, m = _keyed_point(w, scene)
    before, n = snapshot(p), len(w.stack.history())
    w.action("edit.edit_target_track").trigger()
    _click_image(w, 2, (637.0, 4.0))
    _refused(w, before, n, "does not fit")


def test_pattern_larger_than_allowed_or_the_image(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    pid, _, m = _keyed_point(w, scene)
    w.flush()
    col = int(p.points.index_of([pid])[0])
    centre = p.points.obs[0, col, 0].astype(float)
    before, n = snapshot(p), len(w.stack.history())
    # a corner of the blue box dragged far out: a box wider than the largest pattern
    _drag(_view(w, 0), centre + [-10.5, 10.5], centre + [-200.0, 200.0])
    assert "pattern box" in w.last_error
    assert snapshot(p) == before and len(w.stack.history()) == n


def test_no_images_for_the_take(make_window, take, qtbot):  # noqa: F811
    project, scene, _get = take
    p = copy.deepcopy(project)
    w = make_window(p)            # the synthetic project has no camera videos
    assert not w.context.frames.has_images
    m = list(scene.labels).index("Cheek_L")
    p.set_selection(points=[int(p.points.ids[m])])
    before, n = snapshot(p), len(w.stack.history())
    for name in BUTTONS:
        w.pane("Tracker").buttons[name].click()
        _refused(w, before, n, "no images to track in")
        assert not w.runner.busy


def test_marker_lost_on_the_first_frame_says_where(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    pid, _, m = _keyed_point(w, scene)
    # no match is perfect: every track is lost on its first frame
    w.context.session.set_property("Target Tracker", "tracker_break_threshold", 1.0)
    before, n = snapshot(p), len(w.stack.history())
    _run(w, qtbot, "forward_one")
    _refused(w, before, n, "lost the marker", qtbot)
    assert "frame 1 (match 0." in w.last_error and "nothing changed" in w.last_error
    assert p.current_frame == 0
    # the Session says so too, and adds no History entry
    assert w.context.session.target_track(+1) is None
    assert snapshot(p) == before and len(w.stack.history()) == n
    col = int(p.points.index_of([pid])[0])
    assert not (p.points.source[:, col] == SOURCE_TARGET).any()
    assert np.isnan(p.points.obs[1:, col]).all()
