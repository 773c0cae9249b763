"""No process outlives the application: killed with SIGKILL while its detector
processes, forkserver and decoder threads run, it leaves nothing behind; an idle
detector pool stops by itself."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="reads /proc to find the application's processes")

# The application: a main window on a small take with videos, Detect Blobs [Active
# Range] running on the detector processes; it prints its descendants and waits.
APP = textwrap.dedent("""
    import os, sys, time
    import cv2, numpy as np
    from PySide6.QtWidgets import QApplication
    folder = sys.argv[1]
    app = QApplication([])
    from carapost.model.project import new_project
    from carapost.ui.mainwindow import MainWindow
    from carapost.algorithms.blobs import detect
    p = new_project(40, 2, image_size=(160, 120))
    for c, cam in enumerate(p.take.cameras):
        path = os.path.join(folder, f"t_cam{c}.mkv")
        w = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"FFV1"), 60, (160, 120), False)
        for f in range(40):
            img = np.full((120, 160), 200, np.uint8)
            cv2.circle(img, (40 + f, 60), 5, 30, -1)
            w.write(img)
        w.release()
        cam.video_path = path
    win = MainWindow(restore=False)
    win.set_project(p)
    win.show()
    p.set_active_range((0, 39))
    win.action("process.blobs_range").trigger()
    t0 = time.time()
    while not detect._POOL.running and time.time() - t0 < 60:
        app.processEvents()
        time.sleep(0.01)
    win.set_frame(20)
    while time.time() - t0 < 60 and len(detect._POOL.pids()) < 2:
        app.processEvents()
        time.sleep(0.01)
    print("READY", flush=True)
    while True:
        app.processEvents()
        time.sleep(0.01)
""")


def _children() -> dict[int, int]:
    """pid -> parent pid of every process."""
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            out[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    return out


def _descendants(root: int) -> set[int]:
    parents = _children()
    found, frontier = set(), {root}
    while frontier:
        frontier = {pid for pid, ppid in parents.items() if ppid in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigkill_of_the_application_leaves_no_process(tmp_path):
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen",
               PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    proc = subprocess.Popen([sys.executable, "-c", APP, str(tmp_path)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        line = proc.stdout.readline()
        assert line.strip() == "READY", proc.stderr.read() if proc.poll() is not None else line
        family = _descendants(proc.pid)
        # the forkserver and at least two detector processes (plus the resource tracker)
        assert len(family) >= 3, family
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        deadline = time.time() + 10
        while time.time() < deadline and any(_alive(p) for p in family):
            time.sleep(0.1)
        left = [p for p in family if _alive(p)]
        assert not left, f"processes outlived the application: {left}"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in _descendants(proc.pid):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        proc.stdout.close()
        proc.stderr.close()


def test_an_idle_pool_stops_its_processes():
    import numpy as np

    from carapost.parallel import ProcessPool, map_arrays

    pool = ProcessPool(preload=["numpy"], idle_s=0.5)
    try:
        out = map_arrays(lambda k: np.full(4, k), range(4), np.sum, pool=pool, workers=2)
        assert sorted(out) == [0, 1, 2, 3]
        pids = pool.pids()
        assert pids and pool.running
        deadline = time.time() + 20
        while time.time() < deadline and (pool.running or any(_alive(p) for p in pids)):
            time.sleep(0.05)
        assert not pool.running and not any(_alive(p) for p in pids)
        # the next batch starts new processes
        out = map_arrays(lambda k: np.full(4, k), range(3), np.sum, pool=pool, workers=2)
        assert sorted(out) == [0, 1, 2]
    finally:
        pool.shutdown()
