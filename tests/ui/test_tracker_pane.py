"""The Tracker and Properties panes are readable at their default width: no
setting's name is elided."""

from __future__ import annotations

import numpy as np
from PySide6.QtWidgets import QCheckBox

from carapost.algorithms.params import TARGET_TRACKER
from carapost.model.properties import SPECS, specs_in_section
from carapost.synth.demo_project import demo_project


def _names_shown_whole(tree, check_boxes_only: bool = False) -> set[str]:
    """Every row's name in ``tree``, asserting none is elided and nothing scrolls.

    With ``check_boxes_only`` a name in the Property column may be elided (a narrow pane
    gives the names what the values leave) but then its tooltip holds it whole."""
    seen = set()
    for i in range(tree.topLevelItemCount()):
        top = tree.topLevelItem(i)
        # a group's title spans the row and fits
        assert top.isFirstColumnSpanned()
        assert tree.fontMetrics().horizontalAdvance(top.text(0)) < tree.viewport().width()
        for j in range(top.childCount()):
            item = top.child(j)
            box = tree.itemWidget(item, 0)
            if isinstance(box, QCheckBox):   # the check box carries the whole name
                seen.add(box.text())
                assert box.width() >= box.sizeHint().width(), box.text()
                assert box.geometry().right() <= tree.viewport().width()
                continue
            seen.add(item.text(0))
            editor = tree.itemWidget(item, 1)
            assert editor.width() >= editor.sizeHint().width() - 2, item.text(0)
            rect = tree.visualItemRect(item)
            need = tree.fontMetrics().horizontalAdvance(item.text(0))
            fits = need < tree.columnWidth(0) - (rect.left() + tree.indentation())
            if check_boxes_only:
                assert fits or item.toolTip(0).startswith(f"{item.text(0)}: "), item.text(0)
            else:
                assert fits, item.text(0)
    # no horizontal scrolling: the three columns fit the pane
    assert sum(tree.columnWidth(c) for c in range(3)) <= tree.viewport().width() + 1
    return seen


def _shown(w, qtbot, pane: str) -> None:
    w.resize(1920, 1050)
    w.show()
    w.docks[pane].show()
    w.docks[pane].raise_()
    qtbot.wait(50)


def test_every_setting_name_shows_whole_at_the_default_width(make_window, qtbot):
    w = make_window(demo_project(12, 8, 4, size=(320, 240), brim=4))
    _shown(w, qtbot, "Tracker")
    labels = {s.label for s in specs_in_section(TARGET_TRACKER)}
    labels |= {"Update Timeline Every Frame", "Update 2D View Every Frame"}
    assert labels <= _names_shown_whole(w.pane("Tracker").settings.tree)


def test_every_property_name_shows_whole_in_the_main_properties_pane(make_window, qtbot):
    """The main pane at its default width, every group open: a check box carries its
    whole name across the row ("Show Version Check Dialog On Startup" was elided)."""
    w = make_window(demo_project(12, 8, 4, size=(320, 240), brim=4))
    _shown(w, qtbot, "Properties")
    tree = w.pane("Properties").tree
    for i in range(tree.topLevelItemCount()):
        tree.topLevelItem(i).setExpanded(True)
    qtbot.wait(20)
    labels = {s.label for s in SPECS if s.section != TARGET_TRACKER}
    assert labels <= _names_shown_whole(tree, check_boxes_only=True)


def test_a_check_box_row_edits_the_property_as_one_history_entry(make_window, qtbot):
    w = make_window(demo_project(12, 8, 4, size=(320, 240), brim=4))
    pane = w.pane("Tracker").settings
    box = pane.editors["tracker_overwrite_existing_tracks"]
    assert box.text() == "Overwrite Existing Tracks" and not box.isChecked()
    n = len(w.stack.history())
    box.click()
    assert w.context.project.properties["tracker_overwrite_existing_tracks"] is True
    assert len(w.stack.history()) == n + 1
    w.action("edit.undo").trigger()
    w.flush()
    assert w.context.project.properties["tracker_overwrite_existing_tracks"] is False
    assert not box.isChecked()


def test_a_progress_bar_below_the_play_controls_during_a_run(make_window, qtbot):
    import copy
    import functools
    import time

    from carapost.synth.demo_project import scene_project
    from carapost.ui.frames import ArrayFrameSource

    project, scene, get = scene_project(frames=16, size=(320, 240), preset="speech", seed=3)
    p = copy.deepcopy(project)
    get = functools.lru_cache(maxsize=None)(get)

    def slow(f, c):   # a run long enough for its progress to reach the window
        time.sleep(0.01)
        return get(f, c)

    w = make_window(p, ArrayFrameSource(slow))
    w.show()
    bar = w.tracker_progress
    assert not bar.isVisible()
    m = list(scene.labels).index("Cheek_L")
    p.set_selection(points=[int(p.points.ids[m])])
    w.context.session.set_property("Target Tracker", "tracker_overwrite_existing_tracks",
                                   True)
    seen = []
    w.runner.progressed.connect(lambda d, t: seen.append((bar.isVisible(), bar.value(),
                                                          bar.maximum(), bar.format())))
    w.pane("Tracker").buttons["forward_to_end"].click()
    assert bar.isVisible()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert not bar.isVisible()
    assert seen and all(v for v, *_ in seen)
    visible, value, maximum, text = seen[-1]
    assert maximum == 15 and 0 < value <= 15
    assert text.startswith("Track forward to end: frame ")
    # the bar sits under the timebar (the play controls)
    assert bar.parent() is w.timebar.parent()
    lay = bar.parent().layout()
    assert lay.indexOf(bar) == lay.indexOf(w.timebar) + 1


def test_the_selected_point_pane_reads_the_frame_a_run_is_tracking(make_window, qtbot):
    """During a run the model is written only by the result: the pane says the frame
    the run has just tracked is being target-tracked, in how many cameras (it read
    "none, 0 cameras"), and reads the model again once the run has ended."""
    import copy
    import functools
    import time

    from carapost.synth.demo_project import scene_project
    from carapost.ui.frames import ArrayFrameSource

    project, scene, get = scene_project(frames=12, size=(320, 240), preset="speech", seed=3)
    p = copy.deepcopy(project)
    get = functools.lru_cache(maxsize=None)(get)

    def slow(f, c):
        time.sleep(0.01)
        return get(f, c)

    w = make_window(p, ArrayFrameSource(slow))
    w.show()
    m = list(scene.labels).index("Cheek_L")
    p.set_selection(points=[int(p.points.ids[m])])
    w.context.session.set_property("Target Tracker", "tracker_overwrite_existing_tracks",
                                   True)
    from carapost.ui.handlers.process import FOLLOW_TRACKING
    from carapost.ui.settings import set_preference

    set_preference(w.context.settings, FOLLOW_TRACKING, True)   # the views follow the run
    pane = w.pane("Selected Point")
    seen = []
    w.context.view.live_changed.connect(lambda: seen.append(
        (p.current_frame, pane.sample.text())))
    w.pane("Tracker").buttons["forward_to_end"].click()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    w.flush()
    live = [(f, t) for f, t in seen if "being target-tracked" in t]
    assert live, seen
    n_cams = int(np.isfinite(p.points.obs[0, m, :, 0]).sum())
    for f, text in live:
        assert text.startswith(f"Cheek_L at frame {f}: ")
        assert text.endswith(f"{n_cams} cameras")
    assert max(f for f, _ in live) > 0          # it followed the run past its start
    assert w.context.view.live_xy is None
    assert "being target-tracked" not in pane.sample.text()
    assert pane.sample.text().startswith(f"Cheek_L at frame {p.current_frame}: ")
