"""Screenshots of the main window in its common states (``make screenshots``).

Run as ``python -m carapost.ui.screenshots OUTDIR`` (under Xvfb for a real window, or
with ``QT_QPA_PLATFORM=offscreen``). Uses a rendered synthetic take; should rendering
fail, a numpy-filled project with dot images, so the window is still shown.
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

log = logging.getLogger("carapost.ui")


def _settle(app, seconds: float = 0.3) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.01)


def take_screenshots(outdir: str | Path, *, frames: int = 90) -> list[Path]:
    """Write the PNGs into ``outdir``; returns their paths."""
    # private settings: screenshots neither read nor change the user's layout
    os.environ.setdefault("CARAPOST_SETTINGS_DIR", tempfile.mkdtemp(prefix="carapost-shots-"))
    from carapost.ui.app import application

    app = application()
    from carapost.synth.demo_project import demo_project, render_dots, scene_project
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    try:
        project, _scene, render = scene_project(frames, (1280, 720))
        source = ArrayFrameSource(render, cache_size=64)
    except Exception as exc:  # a broken renderer must not hide the window's state
        log.warning("synthetic take unavailable (%s); using dot images", exc)
        project = demo_project(frames, 60, 4, size=(1280, 720), brim=12)
        source = ArrayFrameSource(partial(render_dots, project))
    project.take.name = "synth_speech"
    w = MainWindow(restore=False)
    w.resize(1920, 1050)
    w.set_project(project, source)
    w.show()
    _settle(app, 0.8)
    written: list[Path] = []

    def shot(name: str) -> None:
        _settle(app, 0.4)
        path = out / f"{name}.png"
        w.grab().save(str(path))
        written.append(path)
        log.info("wrote %s", path)

    # 1. four camera views, a few points selected and labelled
    frame = min(40, project.n_frames - 1)
    w.set_frame(frame)
    ids = [int(i) for i in project.points.ids[:3]]
    project.set_selection(points=ids)
    logging.getLogger("carapost.ui").info("Opened synthetic take %s (%d frames, %d cameras)",
                                          project.take.name, project.n_frames,
                                          project.n_cameras)
    logging.getLogger("carapost.ui").warning("Camera 2: video offset not checked")
    shot("main-window-4-cameras")

    # 2. mixed workspace: camera, 3D, continuity, graph
    ws = w.workspace
    ws.containers[1].set_spec("3d")
    ws.containers[2].set_spec("continuity")
    ws.containers[3].set_spec("graph:0")
    project.set_selection(points=ids[:1])
    shot("main-window-views")

    # 3. continuity chart alone, one point expanded per camera
    ws.set_layout(1)
    ws.containers[0].set_spec("continuity")
    chart = ws.containers[0].view
    chart.expanded = {ids[0]}
    chart.refresh(None)
    shot("continuity-chart")

    # 4. 3D view alone
    ws.containers[0].set_spec("3d")
    ws.containers[0].view.yaw = 25
    ws.containers[0].view.pitch = 10
    shot("view-3d")

    # 5. one camera zoomed on the selection with the blob preview
    ws.containers[0].set_spec("sensor:1")
    w.action("view.blob_preview").trigger()
    project.set_selection(points=ids)
    _settle(app, 0.3)
    ws.containers[0].view.center_selection(frame=True)
    shot("camera-blob-preview")
    w.action("view.blob_preview").trigger()

    # 6. a process running: progress bar and Cancel in the status bar
    ws.set_layout(4)
    for i, spec in enumerate(["sensor:0", "sensor:1", "sensor:2", "sensor:3"]):
        ws.containers[i].set_spec(spec)
    project.set_active_range((0, project.n_frames - 1))
    w.action("process.blobs_range").trigger()
    deadline = time.monotonic() + 20
    while w.runner.busy and w.progress.value() < 3 and time.monotonic() < deadline:
        _settle(app, 0.1)
    shot("process-running")
    w.runner.cancel()
    w.runner.wait(60)
    _settle(app, 0.5)
    # 7. History after the cancelled run and an edit
    project.set_selection(points=ids[:2])
    w.action("edit.merge").trigger()
    w.action("edit.undo").trigger()
    w.docks["History"].raise_()
    shot("history-after-undo")
    w.stack.clear()
    w.stack.mark_clean()  # nothing to save: close without the unsaved-changes prompt
    w.close()
    return written


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m carapost.ui.screenshots OUTDIR``."""
    args = sys.argv[1:] if argv is None else argv
    outdir = args[0] if args else "docs/screenshots"
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    paths = take_screenshots(outdir)
    print("\n".join(str(p) for p in paths))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
