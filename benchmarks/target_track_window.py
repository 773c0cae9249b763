"""Target Tracker speed through the Session and through the window.

    python benchmarks/target_track_window.py [--frames 600] [--size 1280x720]
        [--skip-window] [--runs 3]

One point (Cheek_L of a rendered speech take) keyed in the 4 cameras at frame 0 and
tracked forwards to the end of the take as one run, images in memory (rendered once):

- ``target_track_session_4cam_600_s``: ``Session.prepare_target_track`` ->
  ``job.compute`` -> ``Session.apply`` (the command path: snapshot, lockstep tracking of
  the 4 cameras, 3D re-solved on every frame, one History entry), wall time scaled to
  600 frames per camera; its CPU time and the phases (prepare / compute / apply) apart.
- ``target_track_window_4cam_600_s``: the same run started by the Tracker pane's Track
  forward to end button in a main window (offscreen Qt), until the worker has finished
  and its result is applied; with the Tracker pane's default preferences (Update
  Timeline Every Frame on, Update 2D View Every Frame off), and
  ``target_track_window_follow_4cam_600_s`` with the views following every frame.

Decoding is not in these figures: ``benchmarks/target_track.py`` reports the decode of
the same 2,400 images from the take's videos (``decode_4cam_600_s``) apart.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import sys
import time

import numpy as np


def emit(metric: str, value: float | int | None, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def _load() -> float:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return float("nan")


def take(frames: int, size: tuple[int, int]):
    """(project, scene, images (F, C, H, W) uint8) of a speech take with truth."""
    from carapost.synth.demo_project import scene_project

    project, scene, get = scene_project(frames=frames, size=size, preset="speech", seed=3,
                                        decorate=False)
    imgs = np.stack([np.stack([get(f, c) for c in range(scene.n_cameras)])
                     for f in range(frames)])
    return project, scene, imgs


def project_for(cfg):
    """(project, scene) of the take of a `SynthConfig` with only preset, frames, size
    and seed set (the images rendered from ``build_scene(cfg)`` are its images)."""
    from carapost.synth.demo_project import scene_project

    project, scene, _ = scene_project(frames=cfg.frames, size=cfg.size, preset=cfg.preset,
                                      seed=cfg.seed, decorate=False)
    return project, scene


def _keyed(session, scene, label: str = "Cheek_L") -> int:
    """A new target-tracked point keyed at frame 0 in every camera from the truth."""
    m = list(scene.labels).index(label)
    session.current_frame = 0
    with session.group("New Target Track"):
        session.add_target_track(0, 0, scene.uv[0, m, 0])
        (pid,) = session.project.selection.points
        for c in range(1, scene.n_cameras):
            session.edit_target_track(pid, c, 0, scene.uv[0, m, c])
    return m


def session_speed(project, scene, imgs: np.ndarray, runs: int = 3,
                  decode: float | None = None) -> dict[str, float]:
    """The command path of one run (see the module); returns the median phases (s).
    ``decode``: the time to decode the same images (s), for its share."""
    from carapost import Session

    frames = len(imgs) - 1
    scale = 600.0 / frames
    phases: dict[str, list[float]] = {"prepare": [], "compute": [], "apply": [],
                                      "wall": [], "cpu": []}
    errs = []
    for _ in range(runs):
        s = Session(copy.deepcopy(project), get_image=lambda f, c: imgs[f, c])
        m = _keyed(s, scene)
        t0, c0 = time.perf_counter(), time.process_time()
        job = s.prepare_target_track(+1)
        t1 = time.perf_counter()
        result = job.compute()
        t2 = time.perf_counter()
        s.apply(result)
        t3, c3 = time.perf_counter(), time.process_time()
        for k, v in (("prepare", t1 - t0), ("compute", t2 - t1), ("apply", t3 - t2),
                     ("wall", t3 - t0), ("cpu", c3 - c0)):
            phases[k].append(v * scale)
        col = int(s.project.points.index_of(sorted(s.project.selection.points))[0])
        e = np.linalg.norm(s.project.points.obs[1:, col] - scene.uv[1:, m], axis=-1)
        errs.append(float(np.nanmedian(e)))
        tracked = int(np.isfinite(s.project.points.obs[1:, col, :, 0]).sum())
    med = {k: statistics.median(v) for k, v in phases.items()}
    emit("target_track_session_4cam_600_s", round(med["wall"], 3), "s",
         runs=[round(v, 3) for v in phases["wall"]], cpu_s=round(med["cpu"], 3),
         prepare_s=round(med["prepare"], 4), compute_s=round(med["compute"], 3),
         apply_s=round(med["apply"], 4), observations=tracked, frames=frames,
         median_error_px=round(statistics.median(errs), 4), load_average=_load(),
         note="scaled to 600 frames per camera; images in memory")
    if decode is not None:
        emit("decode_share_session", round(decode / (decode + med["wall"]), 3), "fraction",
             decode_s=round(decode, 3), session_s=round(med["wall"], 3),
             load_average=_load())
    return med


def window_speed(project, scene, imgs: np.ndarray, runs: int = 3,
                 follow: bool = False) -> float:
    """The Tracker pane's Track forward to end in a main window (offscreen)."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtCore import QEventLoop

    from carapost import Session
    from carapost.ui.app import application
    from carapost.ui.frames import ArrayFrameSource
    from carapost.ui.mainwindow import MainWindow
    from carapost.ui.settings import set_preference

    app = application()
    frames = len(imgs) - 1
    walls, cpus, guis, shown = [], [], [], []
    for _ in range(runs):
        w = MainWindow(restore=False)
        w.resize(1600, 1000)
        p = copy.deepcopy(project)
        w.set_project(p, ArrayFrameSource(lambda f, c: imgs[f, c]))
        w.show()
        for _ in range(10):
            app.processEvents()
        set_preference(w.context.settings, "tracker_update_2d_view_every_frame", follow)
        set_preference(w.context.settings, "tracker_update_timeline_every_frame", True)
        s: Session = w.context.session
        _keyed(s, scene)
        w.flush()
        loop = QEventLoop()
        w.runner.finished.connect(loop.quit)
        w.runner.failed.connect(loop.quit)
        t0, c0, g0 = time.perf_counter(), time.process_time(), time.thread_time()
        w.pane("Tracker").buttons["forward_to_end"].click()
        if w.runner.busy:
            loop.exec()
        app.processEvents()
        w.flush()
        walls.append((time.perf_counter() - t0) * 600.0 / frames)
        cpus.append((time.process_time() - c0) * 600.0 / frames)
        guis.append((time.thread_time() - g0) * 600.0 / frames)
        shown.append(p.current_frame)
        assert s.history()[-1].description.startswith("Track Forward"), s.history()[-1]
        w.stack.mark_clean()
        w.shutdown()
        w.close()
        app.processEvents()
    name = ("target_track_window_follow_4cam_600_s" if follow
            else "target_track_window_4cam_600_s")
    emit(name, round(statistics.median(walls), 3), "s",
         runs=[round(v, 3) for v in walls], cpu_s=round(statistics.median(cpus), 3),
         gui_thread_cpu_s=round(statistics.median(guis), 3), follow=follow,
         last_frame_shown=int(shown[-1]), frames=frames, load_average=_load(),
         note="scaled to 600 frames per camera; images in memory")
    return statistics.median(walls)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-window", action="store_true")
    a = ap.parse_args(argv)
    size = tuple(int(v) for v in a.size.split("x"))
    project, scene, imgs = take(a.frames, size)
    session_speed(project, scene, imgs, a.runs)
    if not a.skip_window:
        window_speed(project, scene, imgs, a.runs, follow=False)
        window_speed(project, scene, imgs, a.runs, follow=True)
    emit("load_average", _load(), "")
    return 0


if __name__ == "__main__":
    sys.exit(main())
