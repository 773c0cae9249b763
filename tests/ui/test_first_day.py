"""A technician's first day in the window: labelling, charts, re-solving, empty states."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF, Qt

from carapost.ui.settings import set_preference
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


class _Drag:
    """The parts of a pyqtgraph mouse drag event the views read."""

    def __init__(self, vb, a: float, b: float, mods, finish: bool = True) -> None:
        y = vb.viewRange()[1][0] + 0.5
        self._a = vb.mapViewToScene(QPointF(a, y))
        self._b = vb.mapViewToScene(QPointF(b, y))
        self._mods, self._finish = mods, finish

    def button(self):
        return Qt.MouseButton.LeftButton

    def modifiers(self):
        return self._mods

    def accept(self):
        pass

    def ignore(self):
        pass

    def isFinish(self):
        return self._finish

    def isStart(self):
        return False

    def buttonDownScenePos(self):
        return self._a

    def scenePos(self):
        return self._b


def _brim_project():
    from carapost.model.project import SOURCE_NONE
    from carapost.synth.demo_project import demo_project

    p = demo_project(60, 24, 4, size=(640, 360), seed=1, brim=6)
    brim = np.flatnonzero(p.points.kind == 1)
    # the brim has 2D at frame 0 only (a solved brim): its 3D holds from the model
    p.points.obs[1:, brim] = np.nan
    p.points.source[1:, brim] = SOURCE_NONE
    return p, brim


def test_continuity_brim_rows_collapsed_in_their_own_colour(make_window, qtbot):
    from carapost.ui.views.continuity import BRIM, BRIM_HEADER, INTERPOLATED, LUT

    p, brim = _brim_project()
    w = make_window(p)
    w.show()
    w.workspace.containers[0].set_spec("continuity")
    settle(qtbot, w)
    chart = w.workspace.containers[0].view
    face = p.n_points - len(brim)
    assert len(chart._rows) == face + 1 and chart._rows[-1] == (BRIM_HEADER, -1)
    assert "Calibration brim (6)" in chart._row_names[-1]
    header = chart.row_codes(chart._rows[-1])
    assert (header[1:] == BRIM).all() and not (header == INTERPOLATED).any()
    chart.scroll_rows(1000)
    chart.render()
    rgba = chart.image.image                    # rows as drawn, bottom row = the brim
    assert not (rgba[-1][:, :3] == LUT[INTERPOLATED][:3]).all(-1).any()
    assert (rgba[-1][:, :3] == LUT[BRIM][:3]).all(-1).any()
    # double-click the header shows the dots, also not "interpolated"
    chart.click_row(len(chart._rows) - 0.5, Qt.KeyboardModifier.NoModifier, True)
    assert len(chart._rows) == face + 1 + len(brim)
    assert all((chart.row_codes((int(c), -1))[1:] == BRIM).all() for c in brim)
    assert "brim model" in chart.describe((int(brim[0]), -1), 30)
    assert "cameras" in chart.describe((0, -1), 30)


def test_continuity_stays_legible_with_300_points(make_window, qtbot):
    from carapost.synth.demo_project import demo_project

    p = demo_project(30, 300, 4, size=(640, 360), seed=2)
    w = make_window(p)
    w.show()
    w.workspace.containers[0].set_spec("continuity")
    settle(qtbot, w)
    chart = w.workspace.containers[0].view
    y0, y1 = chart.vb.viewRange()[1]
    shown = y1 - y0
    assert 5 <= shown < 300 and chart.scroll.isVisible()
    ticks = chart.plot.getAxis("left")._tickLevels[0]
    assert len(ticks) >= int(shown)                     # a name on every visible row
    chart.scroll_rows(50)
    assert chart.vb.viewRange()[1][0] == y0 + 50 and chart.scroll.value() == 50
    chart.zoom_rows(2.0, 60)
    assert chart.vb.viewRange()[1][1] - chart.vb.viewRange()[1][0] > shown


def test_ctrl_drag_sets_the_active_range_and_click_sets_the_frame(make_window, demo, qtbot):
    p, frames = demo
    w = make_window(p, frames)
    w.show()
    ctrl = Qt.KeyboardModifier.ControlModifier
    w.workspace.containers[0].set_spec("continuity")
    settle(qtbot, w)
    chart = w.workspace.containers[0].view
    chart.vb.mouseDragEvent(_Drag(chart.vb, 10.2, 30.6, ctrl))
    assert p.active_range == (10, 30)
    w.workspace.containers[0].set_spec("graph")
    settle(qtbot, w)
    graph = w.workspace.containers[0].view
    p.set_selection(points=[int(p.points.ids[0])])
    settle(qtbot, w)
    vb = graph.plots[0].getViewBox()
    vb.mouseDragEvent(_Drag(vb, 5.0, 40.0, ctrl))
    assert p.active_range == (5, 40)
    assert w.context.session.history()[-1].description.startswith("Set Active Range 5-40")
    graph.frame_clicked.emit(22)
    assert p.current_frame == 22


def test_detach_re_solves_the_point_in_the_same_undo_step(make_window, demo, qtbot):
    from carapost.algorithms.triangulation import triangulate
    from carapost.model.project import RECON_TRIANGULATED
    from tests.commands.test_edit_commands import snapshot

    p, frames = demo
    w = make_window(p, frames)
    f = 12
    full = ~np.isnan(p.points.obs[f, :, :, 0]).any(-1) & (p.points.recon[f] == RECON_TRIANGULATED)
    col = int(np.flatnonzero(full)[0])
    pid = int(p.points.ids[col])
    # a jittery camera: camera 0's observation is 3 px off, and the 3D tracked with it
    p.points.obs[f, col, 0] += 3.0
    cal = p.calibration
    jittered = triangulate(p.points.obs[f:f + 1, col:col + 1].astype(np.float64),
                           cal.R[f:f + 1], cal.t[f:f + 1], cal.intrinsics).points[0, 0]
    p.points.positions[f, col] = jittered
    w.set_frame(f)
    p.set_selection(points=[pid], cameras={0})
    settle(qtbot, w)
    before = snapshot(p)
    entries = len(w.context.session.history())
    w.action("edit.detach_current").trigger()          # Ctrl+H
    assert len(w.context.session.history()) == entries + 1
    assert np.isnan(p.points.obs[f, col, 0]).all()
    rest = p.points.obs[f:f + 1, col:col + 1].astype(np.float64)
    expected = triangulate(rest, p.calibration.R[f:f + 1], p.calibration.t[f:f + 1],
                           p.calibration.intrinsics).points[0, 0]
    assert np.allclose(p.points.positions[f, col], expected, atol=1e-3)   # the 3D moved
    assert np.linalg.norm(p.points.positions[f, col] - jittered) > 0.05
    assert p.points.recon[f, col] == RECON_TRIANGULATED
    w.action("edit.undo").trigger()
    assert snapshot(p) == before                                        # bit-identical


def test_empty_states_say_what_to_do(make_window, demo, qtbot):
    w = make_window()
    w.show()
    settle(qtbot, w)
    assert w.empty_hint.isVisible() and "File &gt; Open" in w.empty_hint.text()
    pane = w.pane("Selected Point").chart
    assert pane.hint.isVisible() and "Select one point" in pane.hint.text()
    p, frames = demo
    w.set_project(p, frames)
    settle(qtbot, w)
    assert not w.empty_hint.isVisible()
    p.set_selection(points=[int(i) for i in p.points.ids[:3]])
    settle(qtbot, w)
    assert "3 points are selected" in pane.hint.text()
    p.set_selection(points=[int(p.points.ids[0])])
    settle(qtbot, w)
    assert not pane.hint.isVisible()
    # the Log pane shows the whole of a multi-line message
    import logging

    logging.getLogger("carapost.ui").warning("first line\nsecond line\nthird line")
    settle(qtbot, w)
    log = w.pane("Log")
    log.table.selectRow(log.model.rowCount() - 1)
    assert log.detail.toPlainText() == "first line\nsecond line\nthird line"


def test_camera_view_draws_the_rom_and_declutters_labels(make_window, demo, qtbot):
    from carapost.model.project import RomReference
    from carapost.synth.demo_project import demo_project

    p, frames = demo
    rom = demo_project(10, 24, 4, size=(640, 360), seed=1)
    p.rom = RomReference(path="rom.cara", project=rom)
    w = make_window(p, frames)
    w.show()
    w.workspace.set_layout(1)
    w.workspace.containers[0].set_spec("sensor:0")
    settle(qtbot, w)
    view = w.workspace.containers[0].view
    assert view.rom.isVisible()
    xy = view.rom.getData()
    assert len(xy[0]) >= 0.8 * rom.n_points     # light-blue ROM markers, projected
    # every point labelled and Point Labels: All: labels never pile up
    p.points.labels = [f"Marker_Long_Name_{i:02d}" for i in range(p.n_points)]
    p.labels = list(p.points.labels)
    set_preference(w.context.settings, "point_labels_all", True)
    w.set_frame(5)
    settle(qtbot, w)
    shown = [item for item in view._labels if item.isVisible()]
    assert 0 < len(shown) < p.n_points
    rects = [item.mapRectToScene(item.boundingRect()) for item in shown]
    overlaps = sum(1 for i, a in enumerate(rects) for b in rects[i + 1:]
                   if a.intersected(b).width() > 3 and a.intersected(b).height() > 3)
    assert overlaps <= len(shown) // 10


def test_show_calibration_brim_svg(make_window, demo, qtbot, tmp_path):
    p, frames = demo
    w = make_window(p, frames)
    w.action("view.brim_svg").trigger()
    assert "did not come from an SVG" in w.dialogs.infos[-1][1]
    svg = tmp_path / "brim.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="50mm" '
                   'viewBox="0 0 100 50">' + "".join(
                       f'<circle cx="{10 + 15 * i}" cy="{10 + 20 * (i % 2)}" r="3"/>'
                       for i in range(6)) + "</svg>")
    w.dialogs.open_paths.append(str(svg))
    w.action("file.import_brim").trigger()
    assert p.take.metadata["brim_svg"] == str(svg.absolute())
    w.action("view.brim_svg").trigger()
    window = w.context.brim_window
    assert window.isVisible() and window.renderer().isValid()
    assert svg.name in window.windowTitle()
    window.close()
    w.action("edit.undo").trigger()
    assert "brim_svg" not in p.take.metadata


def test_process_label_from_template_menu_item(make_window, qtbot, tmp_path):
    from carapost.io.cara import save_project
    from carapost.synth.demo_project import demo_project

    template = demo_project(30, 24, 4, size=(640, 360), seed=1, decorate=False)
    template.points.labels = [f"M{i + 1:02d}" for i in range(template.n_points)]
    template.labels = list(template.points.labels)
    save_project(template, tmp_path / "rom.cara")
    take = demo_project(30, 24, 4, size=(640, 360), seed=1)
    take.points.labels = [""] * take.n_points
    take.labels = []
    w = make_window(take)
    w.dialogs.open_paths.append(str(tmp_path / "rom.cara"))
    w.action("process.label_template").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=20000)
    settle(qtbot, w)
    assert take.points.labels == template.points.labels
    assert w.context.session.history()[-1].description.startswith(
        "Label From Template rom.cara")
    assert "M01" in [w.pane("Labelling").list.item(i).text()
                     for i in range(w.pane("Labelling").list.count())]
