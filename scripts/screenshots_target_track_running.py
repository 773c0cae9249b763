"""Screenshot of a Target Tracker run in progress: ``target-track-running.png``.

    xvfb-run -a -s "-screen 0 1920x1080x24" \
        python scripts/screenshots_target_track_running.py [OUTDIR]

A new target-tracked point keyed in the four cameras of a rendered synthetic take and
tracked forwards with Update 2D View Every Frame on, grabbed part-way: the four cameras
tracked in lockstep with the views following, the Pause button, the progress bar below
the play controls and the tracked span growing in the Selected Point pane. The image
source is slowed a little so that the run lasts long enough to be caught.
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0] if args else "docs/screenshots")
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-shots-"))
    from PySide6.QtCore import QPointF, Qt

    from carapost.synth.demo_project import scene_project
    from carapost.ui.app import application
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow
    from carapost.ui.screenshots import _settle
    from carapost.ui.settings import set_preference

    app = application()
    project, scene, render = scene_project(80, (1280, 720))
    project.take.name = "synth_speech"
    cached = functools.lru_cache(maxsize=None)(render)

    def slow(f: int, c: int):
        time.sleep(0.01)
        return cached(f, c)

    w = MainWindow(restore=False)
    w.resize(1920, 1050)
    w.set_project(project, ArrayFrameSource(slow, cache_size=64))
    w.show()

    _settle(app, 1.0)
    set_preference(w.context.settings, "tracker_update_2d_view_every_frame", True)
    w.docks["Tracker"].show()
    w.docks["Tracker"].raise_()
    views = {v.camera: v for v in w.workspace.views() if v.kind == "sensor"}

    def click(c: int, xy) -> None:
        v = views[c]
        v.click(v.group.mapToScene(QPointF(float(xy[0]), float(xy[1]))),
                Qt.KeyboardModifier.NoModifier, False)

    m = list(scene.labels).index("Cheek_L")
    w.action("edit.add_target_track").trigger()
    click(0, scene.uv[0, m, 0])
    w.action("edit.edit_target_track").trigger()
    for c in range(1, scene.n_cameras):
        click(c, scene.uv[0, m, c])
    w.action("edit.stop_point_edit").trigger()
    _settle(app, 0.3)
    w.pane("Tracker").buttons["forward_to_end"].click()
    t0 = time.monotonic()
    shot = False
    while w.runner.busy:
        app.processEvents()
        time.sleep(0.01)
        if not shot and time.monotonic() - t0 > 1.5:
            w.grab().save(str(out / "target-track-running.png"))
            shot = True
    w.stack.clear()
    w.stack.mark_clean()
    w.close()
    print(out / "target-track-running.png")
    return 0 if shot else 1


if __name__ == "__main__":
    sys.exit(main())
