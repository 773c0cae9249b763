"""Update Timeline Every Frame and Update 2D View Every Frame during a Target Tracker run.

The window's real Tracker pane buttons on a rendered synthetic take; the frame source
is slowed down a little so that a run lasts long enough for the worker's progress to
reach the GUI thread several times.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from carapost.algorithms.codes import SOURCE_TARGET
from carapost.ui.frames import ArrayFrameSource
from carapost.ui.handlers import target_live
from carapost.ui.settings import set_preference
from carapost.ui.views.continuity import KEYFRAME, N_QUALITY, TARGET0, camera_codes
from tests.commands.test_edit_commands import snapshot
from tests.ui.test_target_tracker_ui import _keyed_point, take  # noqa: F401 (fixture)


def _slow_window(make_window, take, qtbot, delay: float = 0.01,  # noqa: F811
                 holds: dict | None = None):
    """A window whose frame source takes ``delay`` s per image; ``holds`` maps a frame to
    a condition the tracking worker waits for before it gets that frame's images (at
    most 30 s), so that what the GUI shows part-way through a run is seen however
    loaded the machine is. The GUI thread itself is never held."""
    import copy
    import threading

    project, scene, get = take
    p = copy.deepcopy(project)
    holds = dict(holds or {})

    def slow(f: int, c: int):
        hold = holds.get(f)
        if hold is not None and threading.current_thread() is not threading.main_thread():
            deadline = time.monotonic() + 30.0
            while not hold() and time.monotonic() < deadline:
                time.sleep(0.005)
        time.sleep(delay)
        return get(f, c)

    w = make_window(p, ArrayFrameSource(slow))
    w.show()
    qtbot.wait(30)
    return w, p, scene


@pytest.mark.parametrize("live", [True, False])
def test_timeline_draws_the_tracked_span_while_tracking(make_window, take, qtbot,  # noqa: F811
                                                        monkeypatch, live):
    monkeypatch.setattr(target_live, "INTERVAL", 0.0)
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    # with the timeline live, the run waits at frames 6 and 12 until the chart has drawn
    holds = {6: lambda: len(seen) >= 1, 12: lambda: len(seen) >= 2} if live else {}
    w, p, scene = _slow_window(make_window, take, qtbot, holds=holds)
    set_preference(w.context.settings, target_live.LIVE_TIMELINE, live)
    pid, col, m = _keyed_point(w, scene)
    chart = w.pane("Selected Point").chart
    real = chart.show_live

    def spy(column, camera, frames, scores):
        real(column, camera, frames, scores)
        if column == col and camera == 0:
            # what the chart draws now, and what the model holds now (nothing tracked)
            seen.append((chart.row_codes((col, 0)).copy(), p.points.source[:, col, 0].copy()))

    monkeypatch.setattr(chart, "show_live", spy)
    before = snapshot(p)
    w.pane("Tracker").buttons["forward_to_end"].click()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    codes = chart.row_codes((col, 0))
    if live:
        assert len(seen) >= 2
        drawn, model = seen[-1]
        tracked = np.flatnonzero((drawn >= TARGET0) & (drawn < TARGET0 + N_QUALITY))
        assert len(tracked) >= 3 and (model[tracked] != SOURCE_TARGET).all()
        assert drawn[0] == KEYFRAME
        # the span grew from the start frame, in order
        assert tracked[0] == 1 and np.all(np.diff(tracked) == 1)
        assert len(np.flatnonzero(seen[0][0] >= TARGET0)) <= len(tracked)
    else:
        assert seen == [] and chart.live_draws == 0
    # at the end the chart shows the model (the result), drawn or not while running
    assert (p.points.source[1:, col, 0] == SOURCE_TARGET).all()
    np.testing.assert_array_equal(codes, camera_codes(p, col)[0])
    w.action("edit.undo").trigger()
    w.flush()
    assert snapshot(p) == before
    np.testing.assert_array_equal(chart.row_codes((col, 0)), camera_codes(p, col)[0])


def test_a_paused_run_leaves_the_charts_showing_the_model(make_window, take, qtbot,  # noqa: F811
                                                          monkeypatch):
    monkeypatch.setattr(target_live, "INTERVAL", 0.0)
    paused: list[bool] = []
    # the run waits at frame 8 until Pause has been clicked
    w, p, scene = _slow_window(make_window, take, qtbot, delay=0.03,
                               holds={8: lambda: bool(paused)})
    set_preference(w.context.settings, target_live.LIVE_TIMELINE, True)
    pid, col, m = _keyed_point(w, scene, cameras=(0,))
    chart = w.pane("Selected Point").chart
    pane = w.pane("Tracker")
    pane.buttons["forward_to_end"].click()
    qtbot.waitUntil(lambda: chart.live_draws >= 2, timeout=60_000)
    pane.buttons["forward_to_end"].click()      # Pause
    paused.append(True)
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    kept = np.flatnonzero(p.points.source[:, col, 0] == SOURCE_TARGET)
    assert 0 < len(kept) < p.n_frames - 1        # paused part-way, what was tracked is kept
    np.testing.assert_array_equal(chart.row_codes((col, 0)), camera_codes(p, col)[0])
    np.testing.assert_array_equal(chart.row_codes((col, -1)), chart._codes[col])


def test_views_follow_every_camera_being_tracked_in_lockstep(make_window, take, qtbot,  # noqa: F811
                                                             monkeypatch):
    shown: list[int] = []
    # the run waits at frame 8 until the views have followed it at least once
    w, p, scene = _slow_window(make_window, take, qtbot, delay=0.015,
                               holds={8: lambda: len(shown) >= 1})
    set_preference(w.context.settings, "tracker_update_2d_view_every_frame", True)
    set_preference(w.context.settings, target_live.LIVE_TIMELINE, False)
    pid, col, m = _keyed_point(w, scene, cameras=(0, 1, 2))
    real = w.context.set_frame

    def spy(frame, *a, **k):
        shown.append(int(frame))
        return real(frame, *a, **k)

    monkeypatch.setattr(w.context, "set_frame", spy)
    w.pane("Tracker").buttons["forward_to_end"].click()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    last = p.n_frames - 1
    assert (p.points.source[1:, col, :3] == SOURCE_TARGET).all()
    # the cameras are tracked in lockstep: the views go once through the range, never
    # back to the start for another camera, and reach the end
    assert len(shown) >= 2, shown
    assert all(b >= a for a, b in zip(shown, shown[1:], strict=False)), shown
    assert shown[-1] == last


def test_live_redraws_are_throttled():
    """However often the worker reports progress, the charts redraw at most every
    INTERVAL seconds (the GUI thread is not kept busy redrawing)."""
    from types import SimpleNamespace

    from carapost.synth.demo_project import demo_project

    p = demo_project(50, 4, 2, size=(160, 90))
    pid = int(p.points.ids[1])
    job = SimpleNamespace(live=[])
    live = target_live._Live(SimpleNamespace(project=p, shell=None), job)
    for f in range(1, 40):
        job.live.append((pid, 0, f, 0.95))
        live.tick(f, 40)
    assert live.redraws == 1                  # all 39 ticks came within INTERVAL
    assert live.read == 1
    live.last -= target_live.INTERVAL         # INTERVAL later: one more, with the rest
    live.tick(40, 40)
    assert live.redraws == 2 and live.read == 39
    assert live.tracks[(pid, 0)][0] == list(range(1, 40))


def test_views_draw_the_tracked_position_while_following(make_window, take, qtbot):  # noqa: F811
    """With Update 2D View Every Frame on, each camera view draws where the run has just
    tracked the point on the frame shown (the model is written only at the end)."""
    from carapost.algorithms.target_track import TargetTrackerParameters

    checked: list[tuple[int, float]] = []
    # the run waits at frame 8 until a view has been checked part-way
    w, p, scene = _slow_window(make_window, take, qtbot, delay=0.03,
                               holds={8: lambda: bool(checked)})
    set_preference(w.context.settings, "tracker_update_2d_view_every_frame", True)
    pid, col, m = _keyed_point(w, scene, cameras=(0, 1))
    views = {v.camera: v for v in w.workspace.views() if v.kind == "sensor"}

    def check(_done, _total):
        f = p.current_frame
        live = views[0].targets.live
        if f == 0 or not live.isVisible() or p.points.source[f, col, 0] == SOURCE_TARGET:
            return
        x, y = live.getData()
        centre = np.array([np.nanmean(x), np.nanmean(y)])
        checked.append((f, float(np.hypot(*(centre - scene.uv[f, m, 0])))))

    w.runner.progressed.connect(check)
    w.pane("Tracker").buttons["forward_to_end"].click()

    def done() -> bool:
        # held at frame 8 no progress comes: look at the view from here too (on a
        # loaded machine the last progress before the hold can come before the view
        # has drawn the live position)
        if not checked:
            check(0, 0)
        return not w.runner.busy

    qtbot.waitUntil(done, timeout=60_000)
    w.flush()
    assert checked, checked                           # seen part-way
    # the circle is the tracked marker of that frame (its centre within the ring's
    # sampling of the truth), not yet in the model
    assert max(e for _, e in checked) < 0.5, checked
    r = TargetTrackerParameters().pattern_size / 4.0
    x, y = views[0].targets.live.getData()
    assert abs(np.nanmax(x) - np.nanmin(x) - 2 * r) < 0.2
    # the run ended: the result is drawn from the model, the live circle is gone
    assert not views[0].targets.live.isVisible() and not views[1].targets.live.isVisible()
    assert (p.points.source[1:, col, :2] == SOURCE_TARGET).all()
