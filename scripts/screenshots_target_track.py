"""Screenshots of the Target Tracker: a selected target track and a tracked span.

    xvfb-run -a -s "-screen 0 1920x1080x24" python scripts/screenshots_target_track.py [OUTDIR]

Writes ``target-track-selected.png`` (a camera view zoomed on a selected keyframe: blue
pattern box, green search cross with white handles, centre circle; the Tracker pane)
and ``target-track-selected-point.png`` (the Selected Point pane and continuity chart
after a tracking run: white keyframe lines, the tracked span coloured by score) and
``target-track-sizes.png`` (the same keyframe in two cameras, its pattern box and search
cross resized in camera 0 by their handles, camera 1 at the default sizes).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from PySide6.QtCore import QRectF


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0] if args else "docs/screenshots")
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-shots-"))
    from carapost.synth.demo_project import scene_project
    from carapost.ui.app import application
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow
    from carapost.ui.screenshots import _settle

    app = application()
    project, scene, render = scene_project(60, (1280, 720))
    project.take.name = "synth_speech"
    w = MainWindow(restore=False)
    w.resize(1920, 1050)
    w.set_project(project, ArrayFrameSource(render, cache_size=256))
    w.show()
    _settle(app, 0.8)
    m = list(scene.labels).index("Cheek_L")
    s = w.context.session
    s.current_frame = 0
    s.add_target_track(0, 0, scene.uv[0, m, 0])
    (pid,) = project.selection.points
    s.edit_target_track(pid, 1, 0, scene.uv[0, m, 1])
    s.current_frame = 45
    s.edit_target_track(pid, 0, 45, scene.uv[45, m, 0])
    s.edit_target_track(pid, 1, 45, scene.uv[45, m, 1])
    s.current_frame = 0
    s.target_track(+1)
    w.set_frame(0)
    ws = w.workspace
    ws.set_layout(2)
    ws.containers[0].set_spec("sensor:0")
    ws.containers[1].set_spec("continuity")
    w.docks["Tracker"].raise_()
    _settle(app, 0.4)
    view = ws.containers[0].view
    x, y = scene.uv[0, m, 0]
    view.vb.setRange(QRectF(x - 60, y - 40, 120, 80), padding=0)
    _settle(app, 0.4)
    w.grab().save(str(out / "target-track-selected.png"))
    w.set_frame(20)
    w.docks["Selected Point"].show()
    w.docks["Selected Point"].raise_()
    _settle(app, 0.4)
    w.grab().save(str(out / "target-track-selected-point.png"))
    s.set_target_track_size(pid, 0, pattern=15)
    s.set_target_track_size(pid, 0, search=121)
    w.set_frame(0)
    ws.containers[1].set_spec("sensor:1")
    w.docks["Tracker"].raise_()
    _settle(app, 0.4)
    for c, container in enumerate(ws.containers[:2]):
        x, y = scene.uv[0, m, c]
        container.view.vb.setRange(QRectF(x - 80, y - 55, 160, 110), padding=0)
    _settle(app, 0.4)
    w.grab().save(str(out / "target-track-sizes.png"))
    w.stack.clear()
    w.stack.mark_clean()
    w.close()
    print(out / "target-track-selected.png", out / "target-track-selected-point.png",
          out / "target-track-sizes.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
