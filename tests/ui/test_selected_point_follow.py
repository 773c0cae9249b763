"""The Selected Point pane follows the frame cheaply: the refresh its throttle deferred
during a scrub moves the chart's cursor and the sample text without recomputing the codes
of every point in every frame, and with no point selected (the hint covers the chart)
the chart's cursor is not moved at all."""

from __future__ import annotations

from carapost.ui.panes import SelectedPointPane


def _scrub(w, qtbot, pane, frames) -> None:
    for f in frames:  # a fast scrub: the pane refreshes at once, then once at the end
        w.set_frame(f)
        w.flush()
    qtbot.waitUntil(lambda: not pane._throttle.timer.isActive(), timeout=2000)


def test_a_scrub_moves_the_cursor_without_recomputing_the_codes(make_window, demo, qtbot,
                                                                  monkeypatch):
    from carapost.ui.views import continuity

    p, frames = demo
    w = make_window(p, frames)
    pane = w.findChild(SelectedPointPane)
    chart = pane.chart
    p.set_selection(points=[int(p.points.ids[3])])
    w.flush()
    assert chart._rows  # the point and its cameras
    calls: list[tuple] = []
    original = continuity.point_codes
    monkeypatch.setattr(continuity, "point_codes",
                        lambda *a, **k: calls.append(a) or original(*a, **k))
    _scrub(w, qtbot, pane, range(5, 40))
    assert chart.cursor.value() == 39 + 0.5  # the trailing refresh shows the last frame
    assert calls == []  # and recomputed nothing of the take
    _scrub(w, qtbot, pane, [20])
    assert chart.cursor.value() == 20 + 0.5
    # another point: the chart rebuilds its rows (and codes) at once
    p.set_selection(points=[int(p.points.ids[4])])
    w.flush()
    assert calls and chart._rows[0][0] == 4
    assert chart.cursor.value() == 20 + 0.5


def test_without_a_selection_the_hidden_chart_is_left_alone(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    pane = w.findChild(SelectedPointPane)
    chart = pane.chart
    p.set_selection(points=[])
    w.flush()
    assert "Select one point" in chart.hint.text() and not chart.hint.isHidden()
    before = chart.cursor.value()
    _scrub(w, qtbot, pane, range(5, 30))
    assert chart.cursor.value() == before  # behind the hint: not moved, not repainted
    # selecting a point shows the chart with its cursor on the current frame
    p.set_selection(points=[int(p.points.ids[2])])
    w.flush()
    assert chart.hint.isHidden()
    assert chart.cursor.value() == 29 + 0.5
