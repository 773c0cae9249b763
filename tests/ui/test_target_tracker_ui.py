"""The guide's three Target Tracker workflows through the window's real actions and panes.

A rendered synthetic take (truth known) in a hidden window: Edit > Add/Edit Target
Track clicks in the camera views, the Tracker pane's buttons (which read Pause while the
run is on the worker), Gaps To Keys, Add Keyframe To Current Frame; every run is one
History entry and its undo is bit-identical.
"""

from __future__ import annotations

import copy
import functools

import numpy as np
import pytest
from PySide6.QtCore import QPointF, Qt

from carapost.algorithms.codes import SOURCE_KEYFRAME, SOURCE_TARGET
from carapost.synth.demo_project import scene_project
from carapost.ui.frames import ArrayFrameSource
from tests.commands.test_edit_commands import snapshot

FRAMES = 24


@pytest.fixture(scope="module")
def take():
    project, scene, get = scene_project(frames=FRAMES, size=(640, 360), preset="speech",
                                        seed=3)
    return project, scene, functools.lru_cache(maxsize=None)(get)


def _window(make_window, take, qtbot):
    project, scene, get = take
    p = copy.deepcopy(project)
    w = make_window(p, ArrayFrameSource(get))
    w.show()
    qtbot.wait(30)
    return w, p, scene


def _view(w, camera: int):
    return next(v for v in w.workspace.views() if v.kind == "sensor" and v.camera == camera)


def _click_image(w, camera: int, xy) -> None:
    view = _view(w, camera)
    view.click(view.group.mapToScene(QPointF(float(xy[0]), float(xy[1]))),
               Qt.KeyboardModifier.NoModifier, False)


def _keyed_point(w, scene, cameras=(0, 1), label="Cheek_L") -> tuple[int, int, int]:
    """A new target-tracked point keyed at the marker's truth on frame 0, through the
    window's actions: Add Target Track in the first camera, Edit Target Track in the
    others. Returns (point id, its column, the marker's truth index)."""
    m = list(scene.labels).index(label)
    w.action("edit.add_target_track").trigger()
    _click_image(w, cameras[0], scene.uv[0, m, cameras[0]])
    (pid,) = w.context.project.selection.points
    if len(cameras) > 1:
        w.action("edit.edit_target_track").trigger()
        for c in cameras[1:]:
            _click_image(w, c, scene.uv[0, m, c])
    w.action("edit.stop_point_edit").trigger()
    col = int(w.context.project.points.index_of([pid])[0])
    return pid, col, m


def _run(w, qtbot, button: str) -> None:
    pane = w.pane("Tracker")
    pane.buttons[button].click()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()


def _truth_column(p, scene, label: str) -> int:
    m = list(scene.labels).index(label)
    vis = scene.visible[:, m]
    p.points.obs[:, m] = np.where(vis[..., None], scene.uv[:, m], np.nan)
    p.points.source[:, m] = np.where(vis, 1, 0)
    p.points.positions[:, m] = scene.points3d[:, m]
    return m


def test_create_and_track_a_new_target_tracked_point(make_window, take, qtbot):
    w, p, scene = _window(make_window, take, qtbot)
    m = list(scene.labels).index("Cheek_L")
    w.action("edit.add_target_track").trigger()
    assert w.context.point_mode == "add"
    assert "Add Target Track" in _view(w, 0).header.text()
    _click_image(w, 0, scene.uv[0, m, 0])
    (pid,) = p.selection.points
    w.action("edit.edit_target_track").trigger()
    _click_image(w, 1, scene.uv[0, m, 1])
    w.action("edit.stop_point_edit").trigger()
    assert w.context.point_mode == ""
    col = int(p.points.index_of([pid])[0])
    assert p.points.keyframe[0, col, :2].all()
    # the selected keyframe is drawn: blue pattern box, green search cross, handles
    w.flush()
    overlay = _view(w, 0).targets
    assert overlay.box.isVisible() and overlay.cross.isVisible()
    assert overlay.handles.isVisible()
    before = snapshot(p)
    n = len(w.stack.history())
    pane = w.pane("Tracker")
    pane.buttons["forward_to_end"].click()
    assert pane.buttons["forward_to_end"].text() in ("Pause", ">>")
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    assert pane.buttons["forward_to_end"].text() == ">>"
    assert len(w.stack.history()) == n + 1
    err = np.linalg.norm(p.points.obs[1:, col, :2] - scene.uv[1:, m, :2], axis=-1)
    assert err.max() < 0.2
    assert (p.points.source[1:, col, :2] == SOURCE_TARGET).all()
    after = snapshot(p)
    w.action("edit.undo").trigger()
    assert snapshot(p) == before
    w.action("edit.redo").trigger()
    assert snapshot(p) == after
    # off a keyframe: a broken blue circle
    w.context.set_frame(5)
    w.flush()
    assert _view(w, 0).targets.tracked.isVisible()


def test_fill_a_gap_between_two_keyframes_tracking_backwards(make_window, take, qtbot):
    w, p, scene = _window(make_window, take, qtbot)
    col = _truth_column(p, scene, "Nasolabial_L")
    pts = p.points
    for name in ("obs", "positions"):
        pts.arrays[name][8:16, col] = np.nan
    pts.source[8:16, col] = 0
    pts.detection[8:16, col] = -1
    pts.recon[8:16, col] = 0
    p.set_selection(points=[int(pts.ids[col])])
    w.action("edit.gaps_to_keys").trigger()
    cams = np.flatnonzero(pts.keyframe[16, col])
    assert len(cams) >= 2 and pts.keyframe[7, col][cams].all()
    w.context.set_frame(16)
    before = snapshot(p)
    _run(w, qtbot, "back_to_start")
    # the run stopped short of the start at the keyframe before the gap, and says so
    qtbot.waitUntil(lambda: "stopped: keyframe 7" in w.statusBar().currentMessage(),
                    timeout=5000)
    assert p.current_frame == 8
    err = np.linalg.norm(pts.obs[8:16, col][:, cams] - scene.uv[8:16, col][:, cams], axis=-1)
    assert np.isfinite(err).all() and err.max() < 0.3
    assert np.isfinite(pts.positions[8:16, col]).all()
    w.action("edit.undo").trigger()
    assert snapshot(p) == before


def test_frame_by_frame_with_a_keyframe_added_at_the_failure(make_window, take, qtbot):
    w, p, scene = _window(make_window, take, qtbot)
    col = _truth_column(p, scene, "Cheek_R")
    pts = p.points
    p.set_selection(points=[int(pts.ids[col])])
    w.context.session.set_property("Target Tracker", "tracker_overwrite_existing_tracks",
                                   True)
    w.context.set_frame(12)
    for k in range(3):
        n = len(w.stack.history())
        _run(w, qtbot, "back_one")
        # each click is one History entry and shows the frame it tracked, so the next
        # click goes on from there (the guide's "keep tracking backwards frame by frame")
        assert len(w.stack.history()) == n + 1
        assert p.current_frame == 11 - k
        qtbot.waitUntil(lambda: "tracked" in w.statusBar().currentMessage(), timeout=5000)
    tracked = pts.source[9:12, col]
    assert (tracked[np.isfinite(pts.obs[9:12, col, :, 0])] == SOURCE_TARGET).all()
    # the marker "fails" here: the artist keys the last good frame and goes on
    w.pane("Tracker").buttons["add_keyframe"].click()
    assert (pts.source[9, col][np.isfinite(pts.obs[9, col, :, 0])] == SOURCE_KEYFRAME).all()
    before = snapshot(p)
    _run(w, qtbot, "back_one")
    ok = np.isfinite(pts.obs[8, col, :, 0])
    assert ok.any()
    err = np.linalg.norm(pts.obs[8, col][ok] - scene.uv[8, col][ok], axis=-1)
    # the keyframe at 9 is the artist's key of a tracked position (up to 0.1 px off the
    # truth here): one frame tracked from it adds little to its own error
    key_err = np.linalg.norm(pts.obs[9, col][ok] - scene.uv[9, col][ok], axis=-1)
    assert (err < key_err + 0.15).all() and err.max() < 0.25
    w.action("edit.undo").trigger()
    assert snapshot(p) == before


def test_refusals_go_to_the_status_bar(make_window, take, qtbot):
    w, p, scene = _window(make_window, take, qtbot)
    p.set_selection(points=[])
    before = snapshot(p)
    w.pane("Tracker").buttons["forward_one"].click()
    assert "no point is selected" in w.last_error
    w.action("edit.add_target_track").trigger()
    _click_image(w, 0, (2.0, 2.0))
    assert "does not fit" in w.last_error
    assert snapshot(p) == before


class _Drag:
    """A mouse drag event as the view box passes it on (start, move, finish)."""

    def __init__(self, down: QPointF, pos: QPointF, start: bool, finish: bool) -> None:
        self._down, self._pos, self._start, self._finish = down, pos, start, finish

    def isStart(self) -> bool:
        return self._start

    def isFinish(self) -> bool:
        return self._finish

    def buttonDownScenePos(self) -> QPointF:
        return self._down

    def scenePos(self) -> QPointF:
        return self._pos


def test_dragging_a_keyframe_is_one_undo_step(make_window, take, qtbot):
    w, p, scene = _window(make_window, take, qtbot)
    pid, col, m = _keyed_point(w, scene, cameras=(0,))
    before = snapshot(p)
    view = _view(w, 0)
    start = scene.uv[0, m, 0] + 1.0
    to_scene = view.group.mapToScene
    down = to_scene(QPointF(*start))
    for i, (s, f) in enumerate(((True, False), (False, False), (False, True))):
        pos = to_scene(QPointF(*(start + [0.5 * i, -0.25 * i])))
        view.drag(_Drag(down, pos, s, f), lasso=False)
    # moved by the drag (1, -0.5) px, wherever in the box it was grabbed
    assert np.allclose(p.points.obs[0, col, 0], scene.uv[0, m, 0] + [1.0, -0.5], atol=1e-3)
    assert w.stack.history()[-1].description.startswith("Edit Target Track")
    assert p.points.keyframe[0, col, 0]
    w.action("edit.undo").trigger()
    assert snapshot(p) == before
