"""Dragging the white handles of a selected keyframe: per-track pattern and search sizes."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF

from carapost.ui.views.target_overlay import track_sizes
from tests.commands.test_edit_commands import snapshot
from tests.ui.test_target_tracker_ui import (  # noqa: F401 (take is a fixture)
    _click_image,
    _Drag,
    _keyed_point,
    _view,
    _window,
    take,
)


def _drag(view, a, b) -> None:
    to_scene = view.group.mapToScene
    down = to_scene(QPointF(*a))
    for i, (s, f) in enumerate(((True, False), (False, False), (False, True))):
        pos = to_scene(QPointF(*(np.asarray(a) + (np.asarray(b) - a) * i / 2)))
        view.drag(_Drag(down, pos, s, f), lasso=False)


def _extent(item) -> float:
    x, y = item.getData()
    return float(np.nanmax(x) - np.nanmin(x))


def test_dragging_the_handles_sets_this_tracks_sizes(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    pid, col, m = _keyed_point(w, scene)
    centre = p.points.obs[0, col, 0].astype(float)
    view = _view(w, 0)
    w.flush()
    assert _extent(view.targets.cross) == 81.0
    before, n = snapshot(p), len(w.stack.history())
    # the right end of the green cross, dragged out: a larger search region
    _drag(view, centre + [40.5, 0.0], centre + [60.0, 0.0])
    assert p.target_sizes[(pid, 0)] == (21, 121)
    assert len(w.stack.history()) == n + 1
    assert w.stack.history()[-1].description.startswith("Target Track Size")
    # a corner of the blue box, dragged out: a larger pattern; the keyframe did not move
    _drag(view, centre + [-10.5, 10.5], centre + [-12.5, 12.0])
    assert p.target_sizes[(pid, 0)] == (25, 121)
    assert np.array_equal(p.points.obs[0, col, 0], centre.astype(np.float32))
    w.flush()
    assert _extent(view.targets.box) == 25.0 and _extent(view.targets.cross) == 121.0
    assert track_sizes(p, 1)[0][col] == 21.0        # the other camera's track: unchanged
    assert _extent(_view(w, 1).targets.box) == 21.0
    after = snapshot(p)
    # the next run tracks camera 0 with its own sizes, camera 1 with the defaults
    job = w.context.session.prepare_target_track(+1, True, get_image=w.context.frames.require)
    sizes = {tr.camera: (tr.params or job.params) for tr in job.tracks}
    assert (sizes[0].pattern_size, sizes[0].search_size) == (25, 121)
    assert (sizes[1].pattern_size, sizes[1].search_size) == (21, 81)
    w.pane("Tracker").buttons["forward_one"].click()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    err = np.linalg.norm(p.points.obs[1, col, :2] - scene.uv[1, m, :2], axis=-1)
    assert err.max() < 0.3
    w.action("edit.undo").trigger()
    assert snapshot(p) == after
    w.action("edit.undo").trigger()
    w.action("edit.undo").trigger()
    assert snapshot(p) == before and p.target_sizes == {}
    assert p.current_frame == 1          # the run showed the frame it tracked
    w.context.set_frame(0)
    w.flush()
    assert _extent(view.targets.box) == 21.0


def test_a_drag_inside_the_box_still_moves_the_keyframe(make_window, take, qtbot):  # noqa: F811
    w, p, scene = _window(make_window, take, qtbot)
    pid, col, m = _keyed_point(w, scene, cameras=(0,))
    centre = p.points.obs[0, col, 0].astype(float)
    _drag(_view(w, 0), centre + [3.0, 2.0], centre + [4.0, 2.0])
    assert p.target_sizes == {}
    assert np.allclose(p.points.obs[0, col, 0], centre + [1.0, 0.0], atol=1e-3)
