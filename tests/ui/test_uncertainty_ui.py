"""The sample uncertainty in the window: Graph view band and Selected Point pane."""

from __future__ import annotations

import numpy as np


def test_graph_band_and_selected_point_sigma(make_window, demo, qtbot):
    p, frames = demo
    face = 4
    sig = np.full(p.n_frames, np.nan, np.float32)
    sig[10:40] = np.linspace(0.05, 0.5, 30)
    p.points.arrays["sigma"][:, face] = sig
    w = make_window(p, frames)
    w.show()
    w.workspace.containers[2].set_spec("graph:1")
    p.selection = type(p.selection)(points={int(p.points.ids[face])},
                                    cameras=p.selection.cameras)
    w.flush()
    qtbot.wait(30)
    graph = w.workspace.containers[2].view
    graph.refresh(None)
    # one band per 3D curve, +-sigma around the curve where sigma is known
    band = graph.bands[1]
    x = band.opts["x"]
    assert np.array_equal(x, np.arange(10, 40))
    assert np.allclose(band.opts["height"], 2 * sig[10:40])
    assert np.allclose(band.opts["y"], p.points.positions[10:40, face, 1])
    graph._toggle("sigma_band", False)
    assert all(len(b.opts["x"]) == 0 for b in graph.bands)
    pane = w.pane("Selected Point")
    p.current_frame = 20
    pane.refresh(None)
    assert f"at frame 20: triangulated, sigma {sig[20]:.3f} mm" in pane.sample.text()
    p.current_frame = 50
    pane.refresh(None)
    assert "at frame 50: triangulated, sigma unknown" in pane.sample.text()


def test_3d_view_uncertainty_option_colours_points_by_sigma(make_window, demo, qtbot):
    from PySide6.QtGui import QColor
    from PySide6.QtWidgets import QMenu

    from carapost.ui.views.sigma_colours import sigma_rgb

    p, frames = demo
    f = 0
    sig = p.points.arrays["sigma"]
    sig[:] = np.nan
    sig[f, 4], sig[f, 5] = 0.02, 0.9     # well determined (blue), doubtful (red)
    w = make_window(p, frames)
    w.show()
    w.workspace.containers[1].set_spec("3d")
    w.flush()
    qtbot.wait(30)
    v3 = w.workspace.containers[1].view
    menu = QMenu()
    v3.add_menu_items(menu)
    item = next(a for a in menu.actions() if a.text() == "Uncertainty")
    assert item.isCheckable() and not item.isChecked()   # off by default
    xy, _ = v3.to_screen(p.points.positions[f].astype(float))

    def colour_at(col):
        img = v3.grab().toImage()
        return QColor(img.pixel(int(round(xy[col, 0])), int(round(xy[col, 1]))))

    off = colour_at(4)
    item.trigger()                                         # the menu toggles the option
    assert v3.ctx.options.uncertainty
    w.flush()
    qtbot.wait(30)
    for col in (4, 5, 6):                                  # 6: sigma unknown -> grey
        want = sigma_rgb(np.array([sig[f, col]]))[0]
        got = colour_at(col)
        assert abs(got.red() - int(want[0])) < 25 and abs(got.blue() - int(want[2])) < 25, col
    assert colour_at(4) != off
    assert colour_at(4).blue() > colour_at(4).red() and colour_at(5).red() > colour_at(5).blue()
