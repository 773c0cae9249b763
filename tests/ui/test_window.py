"""The real main window driven offscreen: open, scrub, select, edit, undo, process, save."""

from __future__ import annotations

import itertools
import logging
import threading
import time
from functools import partial

import numpy as np
import pytest
from PySide6.QtCore import QPointF, Qt
from PySide6.QtWidgets import QApplication

from carapost.io.autosave import autosave_path
from carapost.io.cara import load_project, save_project
from carapost.synth.demo_project import render_dots
from carapost.ui.frames import ArrayFrameSource
from carapost.ui.handlers import edit as edit_menu
from carapost.ui.handlers import file as file_menu
from carapost.ui.handlers import inspect as inspect_menu
from carapost.ui.handlers import navigation
from tests.ui.helpers import drag, history_rows, image_to_widget, log_rows, send_mouse

pytestmark = pytest.mark.gui


def settle(qtbot, w, ms: int = 30) -> None:
    w.flush()
    qtbot.wait(ms)


def activate(qtbot, w) -> None:
    """Show and activate the window so its shortcuts fire."""
    w.show()
    w.activateWindow()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is w, timeout=2000)


def sensor_views(w):
    return [v for v in w.workspace.views() if v.kind == "sensor"]


def test_open_scrub_and_overlays(make_window, demo, tmp_path, qtbot):
    p, _ = demo
    path = save_project(p, tmp_path / "take.cara")
    w = make_window()
    w.show()
    w.dialogs.open_paths.append(str(path))
    assert w.open_project()
    settle(qtbot, w)
    assert w.project.n_points == p.n_points and w.project.path == str(path)
    assert "take.cara" in w.windowTitle()
    w.set_frames(ArrayFrameSource(partial(render_dots, w.project)))
    # keyboard scrubbing: arrows, End, Home
    w.activateWindow()
    qtbot.keyClick(w, Qt.Key.Key_Right)
    qtbot.keyClick(w, Qt.Key.Key_Right)
    assert w.project.current_frame == 2
    qtbot.keyClick(w, Qt.Key.Key_Left)
    assert w.project.current_frame == 1
    qtbot.keyClick(w, Qt.Key.Key_End)
    assert w.project.current_frame == p.n_frames - 1
    qtbot.keyClick(w, Qt.Key.Key_Home)
    assert w.project.current_frame == 0
    # timebar click scrubs, Ctrl+drag sets the active range (one undo entry)
    ruler = w.timebar.ruler
    send_mouse(ruler, "press", QPointF(ruler.x_of(20), 10))
    send_mouse(ruler, "release", QPointF(ruler.x_of(20), 10))
    assert w.project.current_frame == 20
    drag(ruler, QPointF(ruler.x_of(10), 10), QPointF(ruler.x_of(30), 10),
         mods=Qt.KeyboardModifier.ControlModifier)
    assert w.project.active_range == (10, 30)
    assert w.stack.history()[-1].description.startswith("Set Active Range")
    settle(qtbot, w)
    # the camera view draws this frame's observations as rings and its image
    view = sensor_views(w)[1]
    f, c = w.project.current_frame, view.camera
    obs = w.project.points.obs[f, :, c]
    drawn = np.column_stack(view.points.getData())
    expect = obs[~np.isnan(obs[:, 0])]
    assert drawn.shape == expect.shape and np.allclose(drawn, expect)
    assert view.image.image is not None and view.image.image.shape == (360, 640)
    n_det = len(w.project.detections.get(f, c)["centre"])
    xd, _ = view.det_ellipses.getData()
    assert len(xd) == n_det * 17
    # errors: one segment per connected projection
    xe, _ = view.errors.getData()
    uv = w.view_context.projections(f)[:, c]
    assert len(xe) == 2 * int((~np.isnan(uv[:, 0]) & ~np.isnan(obs[:, 0])).sum())


def test_play_stops_at_view_range_end(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    p.set_view_range((0, 8))
    w.action("view.play").trigger()
    assert w.context.playback.playing and w.action("view.play").isChecked()
    qtbot.waitUntil(lambda: not w.context.playback.playing, timeout=5000)
    assert p.current_frame == 8
    assert not w.action("view.play").isChecked()


def test_select_merge_undo_redo_through_history(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    settle(qtbot, w)
    view = sensor_views(w)[0]
    view.fit()
    settle(qtbot, w)
    f = p.current_frame
    obs = p.points.obs[f, :, 0]
    cols = np.flatnonzero(~np.isnan(obs[:, 0]))
    a, b = int(cols[0]), int(cols[1])
    # click selects the nearest point; Ctrl+click adds another
    qtbot.mouseClick(view.gv.viewport(), Qt.MouseButton.LeftButton,
                     pos=image_to_widget(view, obs[a]).toPoint())
    assert p.selection.points == {int(p.points.ids[a])}
    qtbot.mouseClick(view.gv.viewport(), Qt.MouseButton.LeftButton,
                     Qt.KeyboardModifier.ControlModifier,
                     pos=image_to_widget(view, obs[b]).toPoint())
    assert p.selection.points == {int(p.points.ids[a]), int(p.points.ids[b])}
    n = p.n_points
    qtbot.keyClick(w, Qt.Key.Key_M)  # Merge
    settle(qtbot, w)
    assert p.n_points == n - 1
    pane = w.pane("History")
    rows = history_rows(w)
    assert len(rows) == 2 and rows[1][0].startswith("Merge")
    assert pane.list.currentIndex().row() == 1
    # History click on the first row undoes the merge; the entry turns red
    pane.list.clicked.emit(pane.model.index(0))
    settle(qtbot, w)
    assert p.n_points == n
    colour = history_rows(w)[1][1]
    assert colour.red() > 200 and colour.green() < 100
    assert pane.list.currentIndex().row() == 0
    pane.list.clicked.emit(pane.model.index(1))
    settle(qtbot, w)
    assert p.n_points == n - 1
    assert history_rows(w)[1][1].green() > 200  # applied again: white
    qtbot.keyClick(w, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
    assert p.n_points == n
    qtbot.keyClick(w, Qt.Key.Key_Y, Qt.KeyboardModifier.ControlModifier)
    assert p.n_points == n - 1
    # Clear History frees the memory and empties the list
    pane.clear_button.click()
    settle(qtbot, w)
    assert w.stack.memory() == 0 and history_rows(w) == [("(opened)", history_rows(w)[0][1])]


def test_rubber_band_lasso_and_sensor_selection(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    settle(qtbot, w)
    view = sensor_views(w)[0]
    view.fit()
    settle(qtbot, w)
    obs = p.points.obs[0, :, 0].astype(float)
    # a point not seen in this camera is picked at its projection
    uv = w.view_context.projections(0)[:, 0]
    obs[np.isnan(obs[:, 0])] = uv[np.isnan(obs[:, 0])]
    ok = ~np.isnan(obs[:, 0])
    x0, x1 = np.nanpercentile(obs[:, 0], [10, 60])
    y0, y1 = np.nanmin(obs[:, 1]) - 5, np.nanmax(obs[:, 1]) + 5
    # a widget pixel is ~2 image px: only points clear of the edges are certain
    surely_in = ok & (obs[:, 0] >= x0 + 3) & (obs[:, 0] <= x1 - 3)
    maybe_in = ok & (obs[:, 0] >= x0 - 3) & (obs[:, 0] <= x1 + 3)
    vp = view.gv.viewport()
    drag(vp, image_to_widget(view, (x0, y0)), image_to_widget(view, (x1, y1)))
    sel = p.selection.points
    assert {int(i) for i in p.points.ids[surely_in]} <= sel
    assert sel <= {int(i) for i in p.points.ids[maybe_in]}
    assert surely_in.sum() >= 5
    # detections inside the band are selected too (frame, camera, index)
    cen = p.detections.centres(0, 0)
    in_det = (cen[:, 0] >= x0 + 3) & (cen[:, 0] <= x1 - 3) & (cen[:, 1] >= y0) \
        & (cen[:, 1] <= y1)
    assert set(np.flatnonzero(in_det).tolist()) <= {d[2] for d in p.selection.detections}
    # lasso (Shift+Alt+drag) around one point
    k = int(np.flatnonzero(ok)[0])
    cx, cy = obs[k]
    mods = Qt.KeyboardModifier.ShiftModifier | Qt.KeyboardModifier.AltModifier
    ring = [image_to_widget(view, (cx + 3 * np.cos(t), cy + 3 * np.sin(t)))
            for t in np.linspace(0, 2 * np.pi, 12)]
    send_mouse(vp, "press", ring[0], mods=mods)
    for q in ring[1:]:
        send_mouse(vp, "move", q, buttons=Qt.MouseButton.LeftButton, mods=mods)
    send_mouse(vp, "release", ring[-1], mods=mods)
    near = np.hypot(*(obs - obs[k]).T) < 3
    assert p.selection.points == {int(i) for i in p.points.ids[near & ok]}
    # Shift+click selects the sensor; Detach then uses it
    qtbot.mouseClick(vp, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.ShiftModifier,
                     pos=image_to_widget(view, (10, 10)).toPoint())
    assert p.selection.cameras == {0}
    qtbot.keyClick(w, Qt.Key.Key_H, Qt.KeyboardModifier.ControlModifier)
    assert np.isnan(p.points.obs[0, k, 0, 0])
    assert w.stack.undo_text() == "Detach Detections [Current Frame]"


def test_process_progress_cancel_and_one_undo_entry(make_window, demo, qtbot):
    p, _ = demo
    served = itertools.count()

    def slow_image(f: int, c: int):
        # a few quick images, then slow ones: the run cannot end before Cancel is
        # pressed, however loaded the machine is
        time.sleep(0.005 if next(served) < 80 else 0.25)
        return render_dots(p, f, c)

    slow = ArrayFrameSource(slow_image, 4)
    w = make_window(p, slow)
    w.show()
    p.set_active_range((0, 59))
    before = p.detections.total
    w.action("process.blobs_range").trigger()
    assert w.runner.busy
    qtbot.waitUntil(lambda: w.progress.isVisible() and w.progress.value() > 2, timeout=60_000)
    assert w.cancel_button.isVisible()
    # the window stays responsive while the worker runs
    w.set_frame(5)
    settle(qtbot, w)
    assert p.current_frame == 5
    qtbot.mouseClick(w.cancel_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=30_000)
    assert not w.progress.isVisible()
    last = w.stack.history()[-1]
    assert "cancelled" in last.description and len(w.stack) == 1
    # the images finished before Cancel are kept, and only those
    done = w.stack.applied()[-1].result.images
    assert 0 < len(done) < 240 and len(done) <= next(served)
    assert {f for f, _ in done} <= set(range(60))
    assert p.detections.total != before
    w.action("edit.undo").trigger()
    assert p.detections.total == before


def test_cancel_before_any_image_finished_changes_nothing_and_is_no_error(
        make_window, demo, qtbot, monkeypatch):
    """Cancel pressed before the detector finished an image: Detect Blobs has nothing to
    apply and refuses; the window says so in the status bar, with no error box."""
    import carapost.algorithms.blobs as blobs

    def cancelled_detector(get_image, keys, params, *, workers=2, progress=None, **kw):
        # the detector as it is when Cancel comes before its first image is done
        while progress(0, len(keys)):
            time.sleep(0.005)
        return {}

    monkeypatch.setattr(blobs, "detect_blobs_batch", cancelled_detector)
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    before = p.detections.total
    w.action("process.blobs_current").trigger()
    assert w.runner.busy
    qtbot.mouseClick(w.cancel_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=10000)
    settle(qtbot, w)
    assert w.dialogs.errors == [] and w.last_error == ""
    assert w.statusBar().currentMessage() == ("Detect Blobs [Current Frame] cancelled; "
                                              "nothing changed")
    assert len(w.stack) == 0 and p.detections.total == before


def test_detect_blobs_current_frame_finds_the_dots(make_window, demo, qtbot):
    p, frames = demo
    truth = p.detections.centres(7, 1).copy()
    w = make_window(p, frames)
    w.set_frame(7)
    w.action("process.blobs_current").trigger()
    assert w.runner.busy
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=20000)
    found = p.detections.centres(7, 1)
    d = np.hypot(*(truth[:, None, :] - found[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    assert (d < 1.5).mean() > 0.8
    assert w.stack.undo_text() == "Detect Blobs [Current Frame]"


def test_process_failure_logged_red_and_shown_once(make_window, demo, qtbot, monkeypatch):
    p, frames = demo
    from carapost.commands.recipe import Job
    from carapost.session import Session

    class Failing(Job):
        description = "Initialize 3D"

        def compute(self, progress=None):
            progress(1, 2)
            raise RuntimeError("no seed points")

    monkeypatch.setattr(Session, "prepare_initialize_3d", lambda self, **kw: Failing())
    w = make_window(p, frames)
    w.action("process.init3d").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=5000)
    settle(qtbot, w)
    assert len(w.dialogs.errors) == 1 and "no seed points" in w.dialogs.errors[0][1]
    qtbot.waitUntil(lambda: any("no seed points" in r[3] for r in log_rows(w)), timeout=3000)
    row = next(r for r in log_rows(w) if "no seed points" in r[3])
    assert row[1] == "Error" and row[4].red() > 200
    assert len(w.stack) == 0


def test_save_reopen_prompt_autosave_and_recovery(make_window, demo, tmp_path, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    activate(qtbot, w)  # shortcuts need an active window
    target = tmp_path / "saved.cara"
    w.dialogs.save_paths.append(str(target))
    qtbot.keyClick(w, Qt.Key.Key_S, Qt.KeyboardModifier.ControlModifier)
    assert target.exists() and w.stack.is_clean
    p.set_selection(points=[int(p.points.ids[0])])
    w.action("edit.delete").trigger()
    assert w.isWindowModified()
    # autosave copy beside the file, then "crash": reopen offers the copy
    file_menu.autosave(w.context)
    w.context.autosaver.wait()  # written on a thread of its own
    assert autosave_path(target).exists()
    w.dialogs.ask_save_answers.append("cancel")
    assert not w.close()  # the unsaved-changes prompt can cancel closing
    w2 = make_window()
    w2.dialogs.confirm_answers.append(True)
    assert w2.open_project(str(target))
    assert w2.project.n_points == p.n_points and w2.project.modified
    assert w2.isWindowModified() and "saved.cara" in w2.windowTitle()
    # saving again writes the edit and removes the autosave
    w.dialogs.ask_save_answers.append("save")
    assert w.close()
    assert not autosave_path(target).exists()
    again = load_project(target)
    assert again.n_points == p.n_points
    assert np.array_equal(again.points.ids, p.points.ids)
    # recent files persist in the private settings
    w3 = make_window()
    assert w3.menus["File/Recent Files"].actions()[0].text() == str(target)


def test_properties_pane_edits_through_commands(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    props = w.pane("Properties")
    editor = props.editors["black_threshold"]
    editor.setValue(0.55)
    assert p.properties["black_threshold"] == pytest.approx(0.55)
    assert "Black Threshold" in w.stack.undo_text()
    edit_menu.undo(w.context)
    settle(qtbot, w)
    assert p.properties["black_threshold"] == pytest.approx(0.4)
    assert editor.value() == pytest.approx(0.4)
    assert "between 0 and 1" in editor.toolTip()
    props.editors["max_allowed_depth"].setValue(40)
    props.restore_button.click()
    assert p.properties["max_allowed_depth"] == pytest.approx(35.0)


def test_labelling_colours_assign_and_rename(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    labelling = w.pane("Labelling")
    lst = labelling.list
    names = [lst.item(i).text() for i in range(lst.count())]
    assert names == p.labels
    col = {n: i for i, n in enumerate(p.points.labels) if n}
    unassigned = next(n for n in names if n not in col)
    assert lst.item(names.index(unassigned)).foreground().color().red() > 200
    assigned = names[0]
    c0 = col[assigned]
    p.points.positions[3, c0] = np.nan
    w.set_frame(3)
    settle(qtbot, w)
    assert labelling.label_state(assigned) == "absent"
    # a frame change right after the last refresh is drawn by the scrub's trailing
    # refresh (within 80 ms), not at once
    qtbot.waitUntil(lambda: lst.item(names.index(assigned)).foreground().color().name()
                    == "#ebd228", timeout=2000)
    w.set_frame(4)
    settle(qtbot, w)
    assert labelling.label_state(assigned) == "assigned"
    # click on a label with one point selected assigns it
    target = int(np.flatnonzero([not lab for lab in p.points.labels])[0])
    p.set_selection(points=[int(p.points.ids[target])])
    lst.itemClicked.emit(lst.item(names.index(unassigned)))
    assert p.points.labels[target] == unassigned
    # double-click renames the label (and the point carrying it)
    w.dialogs.texts.append("Chin")
    lst.itemDoubleClicked.emit(lst.item(names.index(unassigned)))
    assert "Chin" in p.labels and p.points.labels[target] == "Chin"
    # Delete Selected Labels takes the labels selected in the pane
    settle(qtbot, w)
    lst.clearSelection()
    lst.item([lst.item(i).text() for i in range(lst.count())].index("Chin")).setSelected(True)
    assert w.context.label_selection == ["Chin"]
    w.action("edit.delete_labels").trigger()
    assert "Chin" not in p.labels


def test_continuity_click_expand_and_fewest_gaps(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    w.workspace.containers[0].set_spec("continuity")
    settle(qtbot, w)
    chart = w.workspace.containers[0].view
    assert chart.kind == "continuity" and len(chart._rows) == p.n_points
    chart.click_row(2.5, Qt.KeyboardModifier.NoModifier, False)
    assert p.selection.points == {int(p.points.ids[2])}
    chart.click_row(2.5, Qt.KeyboardModifier.NoModifier, True)
    assert len(chart._rows) == p.n_points + p.n_cameras
    assert chart._rows[3] == (2, 0)
    chart.collapse_all()
    assert len(chart._rows) == p.n_points
    chart.expand_all()
    assert len(chart._rows) == p.n_points * (1 + p.n_cameras)
    # Ctrl+drag on the chart sets the active range (one undo entry)
    chart.range_drag(12.2, 33.7, True)
    assert p.active_range == (12, 33) and w.stack.undo_text() == "Set Active Range 12-33"
    qtbot.keyClick(w, Qt.Key.Key_A, Qt.KeyboardModifier.ControlModifier)
    from carapost.model.queries import gap_counts

    counts = gap_counts(p, p.active_range)
    sel = p.selected_columns()
    assert len(sel) == 1 and counts[sel[0]] == counts[counts > 0].min()
    # Selected Point pane: the point's bar plus one per camera
    settle(qtbot, w)
    assert len(w.pane("Selected Point").chart._rows) == 1 + p.n_cameras


def test_log_pane_levels_and_colours(make_window, qtbot):
    w = make_window()
    logging.getLogger("carapost.test").warning("careful")
    logging.getLogger("carapost.test").info("hello")
    threading.Thread(target=lambda: logging.getLogger("carapost.test").error("from a thread")
                     ).start()
    qtbot.waitUntil(lambda: any("from a thread" in r[3] for r in log_rows(w)), timeout=3000)
    rows = {r[3]: r for r in log_rows(w)}
    assert rows["careful"][2] == "test"
    assert rows["careful"][4].name() == "#ebd228"
    assert rows["hello"][4].name() == "#ebebeb"
    assert rows["from a thread"][4].name() == "#e64646"


def test_views_3d_graph_render_offscreen(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    w.workspace.containers[1].set_spec("3d")
    w.workspace.containers[2].set_spec("graph:1")
    settle(qtbot, w)
    v3 = w.workspace.containers[1].view
    img = v3.grab().toImage()
    colours = {img.pixel(x, y) for x in range(0, img.width(), 7) for y in range(0, img.height(), 7)}
    assert len(colours) > 3  # points, cameras and text were drawn
    xy, _ = v3.to_screen(p.points.positions[0].astype(float))
    inside = (xy[:, 0] > 0) & (xy[:, 0] < v3.width()) & (xy[:, 1] > 0) & (xy[:, 1] < v3.height())
    assert inside.mean() > 0.9  # fitted to the points
    # clicking a point in the 3D view selects it
    v3.click(QPointF(*xy[4]), Qt.KeyboardModifier.NoModifier)
    assert p.selection.points == {int(p.points.ids[4])}
    settle(qtbot, w)
    graph = w.workspace.containers[2].view
    x, y = graph.curves[1][0].getData()      # the y plot, first point
    assert np.allclose(y, p.points.positions[:, 4, 1], equal_nan=True)
    x2, y2 = graph.curves[3][0].getData()     # the u plot
    assert np.allclose(y2, p.points.obs[:, 4, 1, 0], equal_nan=True)
    # a click on the graph's time axis goes to that frame, Ctrl+drag sets the active range
    graph.frame_clicked.emit(23)
    assert p.current_frame == 23
    graph.range_dragged.emit(5, 15)
    assert p.active_range == (5, 15)


def test_layout_panels_and_settings_persist(make_window, qtbot):
    w = make_window()
    w.workspace.set_layout(2)
    w.workspace.containers[1].set_spec("3d")
    w.docks["History"].close()
    w.shutdown()
    w2 = make_window()
    assert w2.workspace.n == 2
    assert w2.workspace.current_specs()[1] == "3d"
    w2.show()
    assert not w2.docks["History"].isVisible()
    w2.docks["History"].toggleViewAction().trigger()
    assert w2.docks["History"].isVisible()
    w2.action("view.toggle_docks").trigger()
    assert not any(d.isVisible() for d in w2.docks.values())
    w2.action("view.toggle_docks").trigger()
    assert w2.docks["Log"].isVisible()


def test_navigation_tools(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    activate(qtbot, w)
    w.dialogs.ints.append(17)
    qtbot.keyClick(w, Qt.Key.Key_G, Qt.KeyboardModifier.ControlModifier)
    assert p.current_frame == 17
    pid = int(p.points.ids[5])
    w.dialogs.texts.append(str(pid))
    w.action("view.select_point").trigger()
    assert p.selection.points == {pid}
    w.action("view.point_info").trigger()
    title, info = w.dialogs.infos[-1]
    assert title == "Get Point Information"
    assert f"id {pid}" in info and "Sensor 3" in info and "caddy 1" in info
    assert info == inspect_menu.point_information(w.context)
    p.set_selection(points=[int(p.points.ids[0]), int(p.points.ids[1])])
    d = inspect_menu.distance_two_points(w.context)
    expect = np.linalg.norm(p.points.positions[17, 0].astype(float)
                            - p.points.positions[17, 1].astype(float))
    assert d == pytest.approx(expect, rel=1e-5)
    # keyframes: Shift+Right jumps to the next keyframe of the selected point
    p.points.keyframe[40, 2, 1] = True
    p.set_selection(points=[int(p.points.ids[2])])
    navigation.step_key(w.context, 1)
    assert p.current_frame == 40
    # Ctrl+1 / Ctrl+2 / Ctrl+3
    w.set_frame(10)
    qtbot.keyClick(w, Qt.Key.Key_1, Qt.KeyboardModifier.ControlModifier)
    w.set_frame(20)
    qtbot.keyClick(w, Qt.Key.Key_2, Qt.KeyboardModifier.ControlModifier)
    assert p.active_range == (10, 20)
    qtbot.keyClick(w, Qt.Key.Key_3, Qt.KeyboardModifier.ControlModifier)
    assert p.active_range == (0, p.n_frames - 1)
    # rotation of the selected sensor
    p.set_selection(cameras=[2])
    qtbot.keyClick(w, Qt.Key.Key_Right, Qt.KeyboardModifier.ControlModifier)
    assert p.take.cameras[2].rotation == 90
    settle(qtbot, w)
    view = sensor_views(w)[2]
    r = view.displayed_rect()
    assert r.width() == pytest.approx(360) and r.height() == pytest.approx(640)


def test_measurement_and_pixel_report(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    settle(qtbot, w)
    view = sensor_views(w)[0]
    view.fit()
    view.start_measurement()
    drag(view.gv.viewport(), image_to_widget(view, (100, 100)), image_to_widget(view, (160, 180)))
    assert view.measurement_length() == pytest.approx(100.0, abs=2.0)
    view.clear_measurement()
    assert view.measurement_length() is None
    w.view_context.options.pixel_report = True
    img = view._current_image
    view._mouse_moved(view.group.mapToScene(QPointF(50, 60)))
    assert view.report.text().endswith(f"grey {int(img[60, 50])}")


def test_context_menu_switches_view_type(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    box = w.workspace.containers[0]
    menu = box.build_menu()
    view_menu = next(a.menu() for a in menu.actions() if a.text() == "View")
    titles = [a.text() for a in view_menu.actions()]
    assert titles == ["3D", "Graph", "Continuity", "Sensor 0", "Sensor 1", "Sensor 2",
                      "Sensor 3"]
    next(a for a in view_menu.actions() if a.text() == "Sensor 3").trigger()
    assert box.view.kind == "sensor" and box.view.camera == 3
    own = [a.text() for a in box.build_menu().actions()]
    assert "Fit To Window" in own and "Start Measurement" in own and "Pixel Report" in own
    menu.deleteLater()
    QApplication.processEvents()


@pytest.mark.parametrize("spec, option, title", [("sensor:1", "errors", "Errors"),
                                                 ("3d", "rays", "Rays")])
def test_context_menu_display_options(make_window, demo, qtbot, spec, option, title):
    """The 2D and 3D views' right-click options toggle the shared display options, and
    Point Labels: All sets the user's Display preference (no History entry, not the
    project's); the Properties pane and the next menu show it."""
    from carapost.ui.settings import preference
    p, frames = demo
    w = make_window(p, frames)
    box = w.workspace.containers[0]
    box.set_spec(spec)
    opts = box.view.ctx.options
    before = getattr(opts, option)
    menu = box.build_menu()
    acts = {a.text(): a for a in menu.actions()}
    assert acts[title].isChecked() == before
    acts[title].trigger()
    assert getattr(opts, option) == (not before)
    assert "point_labels_all" not in p.properties
    assert not acts["Point Labels: All"].isChecked()
    depth = len(w.stack)
    acts["Point Labels: All"].trigger()
    assert preference(w.context.settings, "point_labels_all") is True
    assert len(w.stack) == depth  # a user setting: nothing to undo in the take
    assert w.pane("Properties").preference_editors["point_labels_all"].isChecked()
    again = {a.text(): a for a in box.build_menu().actions()}
    assert again["Point Labels: All"].isChecked()
    again["Point Labels: All"].trigger()
    assert preference(w.context.settings, "point_labels_all") is False
    menu.deleteLater()
    QApplication.processEvents()
