"""JobRunner.start_job: a processing job computed on the worker, its result applied."""

from __future__ import annotations

import threading

from carapost.commands.process import prepare_detect_blobs
from carapost.model.project import new_project
from carapost.session import Session
from carapost.ui.bridge import JobRunner
from tests.commands.test_process import _disc_image


def test_start_job_computes_on_the_worker_and_pushes_on_the_gui_thread(qtbot):
    p = new_project(2, 1, image_size=(160, 120))
    threads = []

    def get_image(f, c):
        threads.append(threading.current_thread())
        return _disc_image([(40 + 5 * f, 40)])

    job = prepare_detect_blobs(p, (0, 1), get_image=get_image, workers=1)
    session = Session(p)
    stack = session.stack
    pushed_on = []

    def apply(result):
        pushed_on.append(threading.current_thread())
        return session.apply(result)

    closed = []
    runner = JobRunner()
    assert runner.start_job(job, apply, finished=lambda r, c: closed.append(c))
    qtbot.waitUntil(lambda: not runner.busy, timeout=20000)
    assert stack.undo_text() == "Detect Blobs [frames 0-1]" and closed == [False]
    assert threading.main_thread() not in threads
    assert pushed_on == [threading.main_thread()]
    assert p.detections.counts()[:, 0].tolist() == [1, 1]
