"""Screenshot pair of Toggle Show Stabilized: raw and stabilised, same frame and views.

    xvfb-run -a -s "-screen 0 1920x1080x24" python scripts/stabilisation_screenshots.py \
        docs/screenshots

A synthetic speech take (truth positions plus 0.1 mm noise) is stabilised automatically;
its head slip in the helmet is exaggerated six times so that it shows at the Graph's
scale. The window shows the 3D view and the Graph of a skull-fixed point, first raw (the
slip shows as slow drift), then stabilised.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np


def main(outdir: str) -> None:
    os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-shots-"))
    from carapost.synth.demo_project import scene_project
    from carapost.ui.app import application
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow
    from carapost.ui.screenshots import _settle

    app = application()
    project, _scene, render = scene_project(600, (1280, 720), seed=1)
    rng = np.random.default_rng(0)
    # exaggerate the slip (x6 in translation and rotation, about the head centre) so
    # that it shows at the scale of the Graph: the face points move, the brim does not
    from carapost.algorithms.camera import rodrigues_to_matrix
    from carapost.model.project import KIND_FACE

    t = np.arange(project.n_frames) / 60.0
    R = rodrigues_to_matrix(np.radians(6.0) * np.stack(
        [np.sin(2 * np.pi * 0.3 * t), 0.5 * np.sin(2 * np.pi * 0.17 * t + 1), 0 * t], 1))
    tr = 5.0 * np.stack([np.sin(2 * np.pi * 0.21 * t), np.sin(2 * np.pi * 0.13 * t + 2),
                         0 * t], 1)
    face = project.points.kind == KIND_FACE
    X = project.points.positions[:, face].astype(np.float64)
    project.points.positions[:, face] = (np.einsum("fij,fpj->fpi", R, X)
                                         + tr[:, None]).astype(np.float32)
    project.points.positions[:] += rng.normal(0, 0.06, project.points.positions.shape
                                              ).astype(np.float32)
    project.take.name = "synth_speech"
    w = MainWindow(restore=False)
    w.resize(1920, 1050)
    w.set_project(project, ArrayFrameSource(render, cache_size=8))
    w.show()
    _settle(app, 0.8)
    labels = list(project.points.labels)
    ids = [int(project.points.ids[labels.index(n)]) for n in ("Nose_Tip", "Forehead_Hi_L")]
    w.context.session.stabilize("auto")
    _settle(app, 0.5)  # the menu check follows the change
    w.set_frame(420)
    ws = w.workspace
    ws.set_layout(4)
    for i, spec in enumerate(["3d", "graph:0", "sensor:0", "continuity"]):
        ws.containers[i].set_spec(spec)
    project.set_selection(points=ids[:1])
    out = Path(outdir)
    for name, on in (("stabilized-off", False), ("stabilized-on", True)):
        if project.show_stabilized != on:
            w.action("view.show_stabilized").trigger()
        _settle(app, 0.6)
        ws.containers[1].view.fit()
        _settle(app, 0.4)
        w.grab().save(str(out / f"{name}.png"))
        print("wrote", out / f"{name}.png")
    w.stack.clear()
    w.stack.mark_clean()
    w.close()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/screenshots")
