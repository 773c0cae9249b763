"""Detect Blobs in the window runs in the detector processes, never on a thread of the
window (where the detector would hold the GIL and stall its drawing), and the
processes are started in the background when a take with images opens."""

from __future__ import annotations

import numpy as np
import pytest

from carapost import api
from carapost.algorithms.blobs import BlobParameters, detect, detect_blobs
from carapost.algorithms.params import from_mapping
from carapost.model.project import new_project
from carapost.ui.settings import make_settings, set_preference


@pytest.fixture
def detector_at_open():
    """The user's preference on (the test settings turn it off); the processes stopped
    afterwards."""
    set_preference(make_settings(), "start_detector_after_import", True)
    yield
    detect.shutdown_workers()


def test_opening_a_take_starts_the_processes_only_when_the_user_wants(
        make_window, qtbot, synth_take, monkeypatch):
    import carapost.ui.context as context

    started: list[int] = []
    monkeypatch.setattr(context, "start_detector_processes", lambda: started.append(1))
    monkeypatch.setattr(context, "DETECTOR_START_DELAY_MS", 50)
    make_window(api.import_take(synth_take))
    qtbot.wait(300)
    assert started == []  # the preference is off in the test settings
    set_preference(make_settings(), "start_detector_after_import", True)
    make_window(api.import_take(synth_take))
    assert started == []  # not while the take's first images are decoded and drawn
    qtbot.waitUntil(lambda: started == [1], timeout=5000)
    make_window(new_project(5, 2))  # no images: nothing to detect in
    qtbot.wait(300)
    assert started == [1]


def test_detect_current_frame_runs_in_the_warm_processes(
        make_window, qtbot, synth_take, detector_at_open, monkeypatch):
    project = api.import_take(synth_take)
    w = make_window(project)
    qtbot.waitUntil(lambda: len(detect._POOL.pids()) == 2, timeout=60_000)
    pids = detect._POOL.pids()

    def on_a_thread(*_args):
        raise AssertionError("Detect Blobs ran on a thread of the window")

    monkeypatch.setattr(detect, "_detect_in_thread", on_a_thread)
    w.set_frame(3)
    w.action("process.blobs_current").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert w.last_error == "", w.last_error
    assert len(w.stack) == 1 and detect._POOL.pids() == pids  # the warm ones
    params = from_mapping(BlobParameters, project.properties)
    for c in range(project.n_cameras):
        expect = detect_blobs(w.context.frames.require(3, c), params)
        got = project.detections.centres(3, c)
        assert len(got) == len(expect) > 20
        np.testing.assert_array_equal(got, expect.centre)
    assert project.detections.counts()[[0, 1, 2, 4]].max() == 0
    # the History script records what was done, not how it was computed
    (step,) = w.context.session._script()["entries"][-1]
    assert step["call"] == "detect_blobs" and step["kwargs"] == {"frames": "current"}


def test_the_window_launches_the_forkserver_when_it_starts(make_window, monkeypatch):
    """The detector processes' forkserver (their ~1.3 s of imports, once per program) is
    launched when the window is created, before a take is open, when the user wants
    the detector started; never beside a take's first images."""
    import carapost.ui.context as context

    launched: list[int] = []
    monkeypatch.setattr(context, "start_detector_server", lambda: launched.append(1))
    make_window(new_project(5, 2))
    assert launched == []  # the preference is off in the test settings
    set_preference(make_settings(), "start_detector_after_import", True)
    make_window(new_project(5, 2))
    assert launched == [1]



_SERVER_CHILD = """
import sys
from carapost.algorithms.blobs import start_server


def kernels_loaded():
    # in the worker: the detector imported and its compiled kernels loaded (a numba
    # dispatcher lists the signatures it holds; the inlined helpers have none)
    from carapost.algorithms.blobs import _refine_jit
    return ("carapost.algorithms.blobs.detect" in sys.modules
            and len(_refine_jit.refine_sums.signatures) > 0)


if __name__ == "__main__":
    assert start_server() is True
    # the window's process imported nothing of the detector (it would hold the GIL)
    print("numba" in sys.modules, "carapost.algorithms.blobs.detect" in sys.modules)
    from carapost.algorithms.blobs import detect
    ex = detect._POOL.executor(1)
    # a worker forked from that forkserver has the detector and its kernels loaded
    print(ex.submit(kernels_loaded).result())
    detect.shutdown_workers()
"""


def test_the_forkserver_launch_imports_nothing_and_its_workers_are_ready(tmp_path):
    import multiprocessing
    import subprocess
    import sys

    if "forkserver" not in multiprocessing.get_all_start_methods():
        pytest.skip("the forkserver is Linux's")
    script = tmp_path / "child.py"
    script.write_text(_SERVER_CHILD)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=180, check=True).stdout.split()
    assert out == ["False", "False", "True"]
