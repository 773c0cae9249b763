"""The Process menu end to end in the real window on a rendered synthetic take.

Import the take's files, Detect Blobs [Active Range], Solve Calibration Brim, Initialize
3D, Track Forwards [Sequence] (which detects the frames Detect Blobs left out), each on
the worker thread and each one undo entry, then check the tracked points against the
take's ground truth.
"""

from __future__ import annotations

import numpy as np

from carapost import api
from carapost.model.project import KIND_BRIM, KIND_FACE


def _run(qtbot, w, action_id: str) -> None:
    before = len(w.stack)
    w.action(action_id).trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    qtbot.waitUntil(lambda: len(w.stack) == before + 1, timeout=5_000)
    assert w.last_error == "", w.last_error


def test_detect_solve_initialise_track_from_the_menus(make_window, qtbot, synth_take):
    project = api.import_take(synth_take)
    assert (project.points.kind == KIND_BRIM).sum() > 10  # the take's brim model
    w = make_window(project)
    F = project.n_frames
    project.set_active_range((0, F - 3))  # the last two frames are left to the tracker
    _run(qtbot, w, "process.blobs_range")
    assert project.detections.counts()[:F - 2].min() > 20
    assert project.detections.counts()[F - 2:].max() == 0
    project.set_active_range((0, F - 1))
    _run(qtbot, w, "process.solve_brim")
    assert project.calibration.solved[0]
    _run(qtbot, w, "process.init3d")
    face = np.flatnonzero(project.points.kind == KIND_FACE)
    assert len(face) > 40
    _run(qtbot, w, "process.track_fwd_seq")
    tracked = np.isfinite(project.points.positions[:, face, 0])
    assert tracked[-1].mean() > 0.8  # still tracked at the last frame
    # the tracker had the take's images: it detected the frames that had no detections
    assert project.detections.counts()[F - 2:].min() > 20

    # every tracked point sits on one truth marker
    truth = np.load(synth_take.parent / "truth.npz")
    X = truth["points3d"]  # (F, M, 3)
    P = project.points.positions[:, face].astype(np.float64)
    d = np.linalg.norm(P[:, :, None] - X[:, None], axis=-1)  # (F, P, M)
    nearest = np.nanargmin(np.where(np.isnan(d), np.inf, d), axis=-1)
    for k in range(len(face)):
        ok = tracked[:, k]
        assert len(set(nearest[ok, k].tolist())) <= 1, "a point changed marker"
    err = d[tracked].min(axis=-1)
    assert np.sqrt(np.mean(err**2)) < 0.5

    # four processing steps, four undo entries, undone in one go through History
    assert [h.description.split(" [")[0] for h in w.stack.history()][-4:] == [
        "Detect Blobs", "Solve Calibration Brim", "Initialize 3D", "Track Forwards"]
    w.stack.goto(len(w.stack) - 4)
    assert project.n_points == (project.points.kind == KIND_BRIM).sum()
    assert project.detections.total == 0


def test_file_import_from_the_menu(make_window, qtbot, synth_take):
    """File > Import Camera Files with the take's .json chosen in the dialog gives the
    project api.import_take builds, with its images, and a fresh history."""
    w = make_window()
    w.dialogs.open_paths.append(str(synth_take))
    w.action("file.import_take").trigger()
    assert w.runner.busy
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert w.last_error == "", w.last_error
    expect = api.import_take(synth_take)
    p = w.project
    assert (p.take.name, p.n_frames, p.n_cameras) == (expect.take.name, expect.n_frames,
                                                      expect.n_cameras)
    assert np.array_equal(p.points.ids, expect.points.ids)
    assert np.array_equal(p.points.positions, expect.points.positions, equal_nan=True)
    assert w.context.frames.has_images and len(w.stack) == 0
    assert expect.take.name in w.windowTitle()
    # the imported take's Detect Blobs [Current Frame] runs from the menu, then undo
    w.action("process.blobs_current").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert len(w.stack) == 1 and p.detections.counts()[p.current_frame].min() > 20
    w.action("edit.undo").trigger()
    assert p.detections.total == 0 and w.action("edit.redo").isEnabled()
