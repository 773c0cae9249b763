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
    assert pane.sigma_label.text().startswith(f"Frame 20: sigma {sig[20]:.3f} mm")
    p.current_frame = 50
    pane.refresh(None)
    assert pane.sigma_label.text() == "Frame 50: sigma unknown"
