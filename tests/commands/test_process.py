"""Process-menu commands: blob detection, brim, Initialize 3D, bundle; undo bit-identical."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from carapost.commands.process import (
    BundleCurrentFrame,
    DetectBlobs,
    ImportBrimSvg,
    Initialize3D,
    InitializeDefaultBrim,
    SetBrimModel,
    SolveBrimAuto,
    SolveBrimManual,
)
from carapost.commands.stack import CommandError, CommandStack
from carapost.model.project import KIND_BRIM, KIND_FACE, RECON_TRIANGULATED, new_project
from tests.algorithms.test_brim import (
    _scene,
    brim_index,
    camera_errors,
    four_correspondences,
    synthetic_detections,
)
from tests.commands.test_edit_commands import snapshot


def full_snapshot(project):
    snap = snapshot(project)
    cal = project.calibration
    snap["calibration"] = (cal.R.tobytes(), cal.t.tobytes(), cal.solved.tobytes())
    return snap


def synthetic_project(seed=0, markers="standard"):
    """A 2-frame project whose detections are the synthetic truth (noisy, shuffled)."""
    scene = _scene(markers=markers, seed=seed)
    p = new_project(scene.n_frames, scene.n_cameras)
    p.calibration.intrinsics = scene.intrinsics.copy()
    rng = np.random.default_rng(seed)
    idents = []
    images, tables = [], []
    for f in range(scene.n_frames):
        dets, ident = synthetic_detections(scene, f, rng)
        idents.append(ident)
        for c in range(scene.n_cameras):
            n = len(dets[c])
            images.append((f, c))
            tables.append({"centre": dets[c], "axes": np.full((n, 2), 4.0),
                           "angle": np.zeros(n), "colour": np.zeros(n, np.int8),
                           "score": np.ones(n)})
    p.detections.replace_images(images, tables)
    SetBrimModel(scene.brim_labels, scene.brim3d).do(p)
    return p, scene, idents


def roundtrip(project, command):
    """Push, check undo restores bit for bit and redo gives the same result."""
    stack = CommandStack(project)
    before = full_snapshot(project)
    stack.push(command)
    after = full_snapshot(project)
    assert after != before
    assert stack.undo()
    assert full_snapshot(project) == before
    assert stack.redo()
    assert full_snapshot(project) == after


def test_default_brim_command_creates_and_replaces_brim_points():
    p = new_project(3, 4)
    roundtrip(p, InitializeDefaultBrim(p, "v2.0"))
    brim = np.flatnonzero(p.points.kind == KIND_BRIM)
    assert len(brim) == 38 and p.points.labels[brim[0]] == "Brim01"
    assert np.isfinite(p.points.positions[:, brim]).all()
    CommandStack(p).push(InitializeDefaultBrim(p, "v1.0"))
    assert (p.points.kind == KIND_BRIM).sum() == 23
    with pytest.raises(CommandError, match="unknown default brim"):
        InitializeDefaultBrim(p, "v9")


def test_import_brim_svg_command(tmp_path, caplog):
    p = new_project(2, 4)
    good = tmp_path / "brim.svg"
    good.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="50mm" '
                    'viewBox="0 0 100 50">' + "".join(
                        f'<circle cx="{10 * i}" cy="{5 * (i % 2)}" r="2"/>' for i in range(6))
                    + "</svg>")
    roundtrip(p, ImportBrimSvg(p, good))
    assert (p.points.kind == KIND_BRIM).sum() == 6
    bad = tmp_path / "bad.svg"
    bad.write_text("<svg><circle")
    before = full_snapshot(p)
    with caplog.at_level(logging.ERROR, logger="carapost.process"):
        with pytest.raises(CommandError, match="bad.svg"):
            ImportBrimSvg(p, bad)
    assert "not a well-formed SVG" in caplog.text
    assert full_snapshot(p) == before


def test_solve_brim_manual_command_and_undo():
    p, scene, idents = synthetic_project(seed=1)
    bidx = brim_index(idents[0], len(scene.brim3d))
    cmd = SolveBrimManual(p, 0, four_correspondences(bidx))
    roundtrip(p, cmd)
    pos, rot = camera_errors(p.calibration.R[0], p.calibration.t[0], scene.cam_R[0],
                             scene.cam_t[0])
    assert pos.max() <= 0.2 and rot.max() <= 0.05
    assert p.calibration.solved.tolist() == [True, False]
    brim = np.flatnonzero(p.points.kind == KIND_BRIM)
    det = p.points.detection[0, brim]
    assert np.array_equal(det[det >= 0], bidx[det >= 0])
    assert (p.points.recon[0, brim][(det >= 0).any(1)] == RECON_TRIANGULATED).all()
    assert np.nanmax(p.points.residual[0, brim]) < 0.1  # mm


def test_solve_brim_manual_from_attached_detections():
    p, scene, idents = synthetic_project(seed=4)
    bidx = brim_index(idents[0], len(scene.brim3d))
    brim = np.flatnonzero(p.points.kind == KIND_BRIM)
    for c, pairs in four_correspondences(bidx).items():
        for b, k in pairs:
            p.points.detection[0, brim[b], c] = k
    CommandStack(p).push(SolveBrimManual(p, 0))
    pos, _ = camera_errors(p.calibration.R[0], p.calibration.t[0], scene.cam_R[0],
                           scene.cam_t[0])
    assert pos.max() <= 0.2


def test_bad_input_leaves_project_unchanged_with_a_logged_message(caplog):
    p, scene, idents = synthetic_project(seed=2)
    bidx = brim_index(idents[0], len(scene.brim3d))
    corr = four_correspondences(bidx)
    corr[1] = corr[1][:3]
    before = full_snapshot(p)
    with caplog.at_level(logging.ERROR, logger="carapost.process"):
        with pytest.raises(CommandError, match="3 brim correspondence"):
            SolveBrimManual(p, 0, corr)
        with pytest.raises(CommandError, match="not solved"):
            Initialize3D(p, 0)
        with pytest.raises(CommandError, match="rig geometry"):
            SolveBrimAuto(p, 0)
    assert "at least 4 are needed" in caplog.text
    assert full_snapshot(p) == before
    empty = new_project(1, 4)
    empty.calibration.intrinsics = scene.intrinsics.copy()
    with pytest.raises(CommandError, match="no calibration brim"):
        SolveBrimManual(empty, 0, {})
    InitializeDefaultBrim(empty).do(empty)
    with pytest.raises(CommandError, match="no detections in camera"):
        SolveBrimManual(empty, 0, {c: [(0, 0)] * 4 for c in range(4)})
    empty.calibration.set_static(scene.cam_R[0], scene.cam_t[0])
    with pytest.raises(CommandError, match="no detections"):
        Initialize3D(empty, 0)
    no_intr = new_project(1, 4)
    with pytest.raises(CommandError, match="no camera calibration"):
        SolveBrimManual(no_intr, 0, {})


def test_auto_solve_initialize_3d_and_bundle_commands():
    p, scene, idents = synthetic_project(seed=3)
    # an XCP gives the nominal rig for every frame
    p.calibration.set_static(scene.nominal_R, scene.nominal_t)
    roundtrip(p, SolveBrimAuto(p, 1))
    pos, rot = camera_errors(p.calibration.R[1], p.calibration.t[1], scene.cam_R[1],
                             scene.cam_t[1])
    assert pos.max() <= 0.2 and rot.max() <= 0.05
    cmd = Initialize3D(p, 1)
    roundtrip(p, cmd)
    face = np.flatnonzero(p.points.kind == KIND_FACE)
    det = p.points.detection[1, face]
    ident = idents[1]
    ids = []
    for row in det:
        ms = {int(ident[c][k]) for c, k in enumerate(row) if k >= 0}
        assert len(ms) == 1 and min(ms) >= 0  # no mismatch
        ids.append(ms.pop())
    target = np.flatnonzero(scene.visible[1].sum(1) >= 2)
    assert np.isin(target, ids).mean() >= 0.95
    err = np.linalg.norm(p.points.positions[1, face] - scene.points3d[1, ids], axis=1)
    assert np.sqrt(np.mean(err**2)) <= 0.2
    assert (p.points.recon[1, face] == RECON_TRIANGULATED).all()
    assert np.isfinite(p.points.residual[1, face]).all()
    # observations are the attached detections
    c0 = det[:, 0] >= 0
    np.testing.assert_array_equal(p.points.obs[1, face[c0], 0],
                                  p.detections.centres(1, 0)[det[c0, 0]])
    # a second Initialize 3D keeps the existing points as seeds and adds nothing wrong
    n = p.n_points
    CommandStack(p).push(Initialize3D(p, 1))
    assert p.n_points == n
    roundtrip(p, BundleCurrentFrame(p, 1))
    pos, rot = camera_errors(p.calibration.R[1], p.calibration.t[1], scene.cam_R[1],
                             scene.cam_t[1])
    assert pos.max() <= 0.2 and rot.max() <= 0.05


def _disc_image(centres, size=(160, 120)):
    img = np.full((size[1], size[0]), 200, np.uint8)
    for x, y in centres:
        cv2.circle(img, (int(x), int(y)), 6, 30, -1, lineType=cv2.LINE_AA)
    return img


def test_detect_blobs_command_cameras_cancel_and_undo():
    p = new_project(3, 2, image_size=(160, 120))
    spots = {0: [(40, 40), (100, 60)], 1: [(30, 80)]}

    def get_image(f, c):
        return _disc_image([(x + 5 * f, y) for x, y in spots[c]])

    p.set_selection(cameras=[1])
    cmd = DetectBlobs(p, (0, 2), get_image=get_image, workers=1)
    roundtrip(p, cmd)
    counts = p.detections.counts()
    assert counts[:, 1].tolist() == [1, 1, 1] and counts[:, 0].tolist() == [0, 0, 0]
    np.testing.assert_allclose(p.detections.centres(2, 1)[0], (40, 80), atol=0.3)
    # cancel after the first image: the finished image is kept
    calls = []

    def progress(done, total):
        calls.append(done)
        return done < 1

    cmd2 = DetectBlobs(p, (0, 2), cameras=[0], get_image=get_image, progress=progress,
                       workers=1)
    assert cmd2.cancelled
    CommandStack(p).push(cmd2)
    assert 1 <= p.detections.counts()[:, 0].astype(bool).sum() < 3
    with pytest.raises(CommandError, match="no image source"):
        DetectBlobs(p, (0, 0))


def test_session_process_actions_at_the_current_frame():
    """The Process items the window runs (through `carapost.Session`) at the current frame."""
    from carapost.session import Session

    p, scene, _ = synthetic_project(seed=4)
    p.calibration.set_static(scene.nominal_R, scene.nominal_t)
    p.set_current_frame(1)
    session = Session(p)
    # no brim point attached yet: Solve Calibration Brim falls back to the automatic solve
    job = session.prepare("solve_brim")
    assert job.mode == "auto"
    session.apply(job.compute(None))
    pos, rot = camera_errors(p.calibration.R[1], p.calibration.t[1], scene.cam_R[1],
                             scene.cam_t[1])
    assert pos.max() <= 0.2 and rot.max() <= 0.05
    # now the brim is attached at this frame: the same item runs the manual solve
    assert session.prepare("solve_brim").mode == "manual"
    session.initialize_3d()
    assert (p.points.kind == KIND_FACE).sum() >= 0.95 * (scene.visible[1].sum(1) >= 2).sum()
    session.bundle_current_frame()
    session.initialize_default_brim("2.0")
    from carapost.io.brim_svg import default_brim

    labels, xyz = default_brim("v2.0")
    brim = np.flatnonzero(p.points.kind == KIND_BRIM)
    assert [p.points.labels[i] for i in brim] == list(labels)
    np.testing.assert_allclose(p.points.positions[0, brim], xyz, atol=1e-4)
    while session.undo():
        pass
    assert (p.points.kind == KIND_FACE).sum() == 0
