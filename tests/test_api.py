"""Scripting API: exports mapped from the model, evaluation metrics, Relocate Files, process."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost import api
from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.commands.stack import CommandError, CommandStack
from carapost.io.c3d import read_c3d
from carapost.io.errors import CaraFileError
from carapost.io.xcp import read_xcp
from carapost.model.project import (
    KIND_BRIM,
    RECON_INTERPOLATED,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    new_project,
)
from tests.ufbx_child import fbx_node_names

F, M, C = 40, 6, 3
IMG = (200, 150)


def make_truth(rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Markers 20 mm apart on a grid, moving a few mm; three cameras 300 mm away."""
    grid = np.array([[x, y, 0.0] for x in (-20.0, 0.0, 20.0) for y in (-10.0, 10.0)])
    phase = rng.uniform(0, 2 * np.pi, (M, 3))
    tt = np.arange(F)[:, None, None] / 10.0
    X = grid[None] + 3.0 * np.sin(tt + phase[None])
    intr = CameraIntrinsics(focal=np.full(C, 400.0),
                            principal_point=np.tile([IMG[0] / 2, IMG[1] / 2], (C, 1)),
                            image_size=np.tile(IMG, (C, 1)), names=["c0", "c1", "c2"])
    R = np.broadcast_to(np.eye(3), (C, 3, 3)).copy()
    t = np.array([[-40.0, 0, 300], [0.0, 0, 300], [40.0, 0, 300]])
    uv, _ = project(X, R, t, intr)  # [F, M, C, 2]
    visible = rng.random((F, M, C)) > 0.1
    return {"points3d": X, "labels": np.array([f"M{i}" for i in range(M)]),
            "visible": visible, "uv": uv, "cam_R": R, "cam_t": t, "K": intr.K(),
            "_intr": intr}


def project_from_truth(truth: dict, *, labelled: bool = True):
    p = new_project(F, C, fps=60.0, name="synthtake", image_size=IMG)
    p.take.timecode_start = "01:00:00:00"
    cols = p.points.append(M, labels=list(truth["labels"]) if labelled else None)
    pts = p.points
    pts.positions[:, cols] = truth["points3d"]
    pts.recon[:, cols] = RECON_TRIANGULATED
    pts.residual[:, cols] = 0.25
    vis = truth["visible"]
    pts.obs[:, cols] = np.where(vis[..., None], truth["uv"], np.nan)
    pts.source[:, cols] = np.where(vis, SOURCE_BLOB, 0)
    p.calibration.intrinsics = truth["_intr"].copy()
    p.calibration.set_static(truth["cam_R"], truth["cam_t"])
    return p


def save_truth(path: Path, truth: dict) -> Path:
    np.savez(path, **{k: v for k, v in truth.items() if not k.startswith("_")})
    return path


@pytest.fixture
def truth(rng):
    return make_truth(rng)


# --------------------------------------------------------------------------- evaluate


def test_evaluate_perfect_project(tmp_path, truth):
    tp = save_truth(tmp_path / "truth.npz", truth)
    p = project_from_truth(truth)
    r = api.evaluate(p, tp)
    json.dumps(r)  # serialisable
    assert r["rmse_mm"] == pytest.approx(0.0, abs=1e-4)
    assert set(r["per_marker_rmse_mm"]) == {f"M{i}" for i in range(M)}
    assert r["coverage"] == 1.0
    assert r["swaps"] == 0 and r["spurious_points"] == 0
    assert r["n_points"] == M and r["n_matched"] == M
    assert r["reprojection_rms_px"] == pytest.approx(0.0, abs=1e-3)
    # the same from a saved project, unlabelled points (matched by distance alone)
    p2 = project_from_truth(truth, labelled=False)
    path = api.save_project(p2, tmp_path / "p.cara")
    r2 = api.evaluate(str(path), str(tp))
    assert r2["n_matched"] == M and r2["rmse_mm"] == pytest.approx(0.0, abs=1e-4)


def test_evaluate_noise_gives_expected_rmse_and_reprojection(tmp_path, truth, rng):
    tp = save_truth(tmp_path / "truth.npz", truth)
    p = project_from_truth(truth)
    sigma = 0.5
    p.points.positions[:] += rng.normal(0, sigma, p.points.positions.shape).astype(np.float32)
    p.points.obs[:] += rng.normal(0, 0.3, p.points.obs.shape).astype(np.float32)
    r = api.evaluate(p, tp)
    assert r["rmse_mm"] == pytest.approx(sigma * np.sqrt(3), rel=0.1)
    assert r["reprojection_rms_px"] == pytest.approx(0.3 * np.sqrt(2), rel=0.1)
    # 0.87 mm RMS noise: nearly every sample stays within 2 mm
    assert 0.9 < r["coverage"] <= 1.0


def test_evaluate_detects_identity_swap(tmp_path, truth):
    tp = save_truth(tmp_path / "truth.npz", truth)
    p = project_from_truth(truth, labelled=False)
    pos = p.points.positions
    half = F // 2
    pos[half:, [0, 1]] = pos[half:, [1, 0]]  # points 0 and 1 exchange identities
    r = api.evaluate(p, tp)
    assert r["swaps"] == 2
    assert sorted(r["swapped_points"]) == ["Point 1", "Point 2"]
    assert r["n_matched"] == M - 2  # their mean distance to either marker is ~10 mm
    assert r["coverage"] < 1.0


def test_evaluate_counts_spurious_points_but_not_brim_or_empty(tmp_path, truth):
    tp = save_truth(tmp_path / "truth.npz", truth)
    p = project_from_truth(truth)
    c = p.points.append(3)
    p.points.positions[:, c[0]] = [200.0, 0, 0]  # spurious face point
    p.points.positions[:, c[1]] = [0.0, 200, 0]  # brim point: never spurious
    p.points.kind[c[1]] = KIND_BRIM
    # c[2]: a face point without any 3D sample is not counted
    r = api.evaluate(p, tp)
    assert r["spurious_points"] == 1 and r["n_points"] == M + 1 and r["n_matched"] == M


def test_evaluate_coverage_counts_missing_frames(tmp_path, truth):
    tp = save_truth(tmp_path / "truth.npz", truth)
    p = project_from_truth(truth)
    p.points.positions[: F // 2, 0] = np.nan
    r = api.evaluate(p, tp)
    seen = truth["visible"].sum(-1) >= 2
    expected = 1.0 - seen[: F // 2, 0].sum() / seen.sum()
    assert r["coverage"] == pytest.approx(expected)
    assert r["rmse_mm"] == pytest.approx(0.0, abs=1e-4)


def test_evaluate_bad_truth_file(tmp_path, truth):
    p = project_from_truth(truth)
    with pytest.raises(CaraFileError, match="no such file"):
        api.evaluate(p, tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    np.savez(bad, something=np.zeros(3))
    with pytest.raises(CaraFileError, match="has no 'points3d'"):
        api.evaluate(p, bad)


# --------------------------------------------------------------------------- exports


def test_export_c3d_maps_model_to_file(tmp_path, truth):
    p = project_from_truth(truth)
    pts = p.points
    pts.recon[10:14, 2] = RECON_INTERPOLATED
    pts.source[10:14, 2] = 0
    pts.positions[20:22, 3] = np.nan
    pts.recon[20:22, 3] = 0
    pts.residual[20:22, 3] = np.nan
    b = p.points.append(1, labels=["Brim01"], kind=KIND_BRIM)
    pts.positions[:, b] = [1.0, 2.0, 3.0]
    p.set_active_range((5, 29))
    out = api.export_c3d(p, tmp_path / "a.c3d", frame_range="active")
    d = read_c3d(out)
    assert d.labels == [f"M{i}" for i in range(M)]  # brim excluded by default
    assert d.rate == 60.0 and d.first_frame == 6
    assert d.positions.shape == (25, M, 3)
    np.testing.assert_allclose(d.positions, pts.positions[5:30, :M], atol=1e-4, equal_nan=True)
    assert d.processed[10 - 5 : 14 - 5, 2].all() and not d.processed[:, 0].any()
    assert np.isnan(d.positions[20 - 5 : 22 - 5, 3]).all()
    vis = truth["visible"][5:30]
    np.testing.assert_array_equal(d.camera_mask[:, 0, :C], vis[:, 0])
    assert d.camera_names == ["cam0", "cam1", "cam2"]
    assert d.timecode_start == "01:00:00:05"
    with_brim = read_c3d(api.export_c3d(p, tmp_path / "b.c3d", include_brim=True))
    assert with_brim.labels[-1] == "Brim01" and with_brim.positions.shape[0] == F


def test_export_fbx_and_xcp(tmp_path, truth):
    pytest.importorskip("ufbx")
    p = project_from_truth(truth)
    out = api.export_fbx(p, tmp_path / "a.fbx", up_axis="z", include_cameras=True)
    names = set(fbx_node_names(out))
    assert {f"M{i}" for i in range(M)} <= names
    assert not any("-" in n for n in names)  # no sticks unless asked
    from carapost.model.project import Stick

    ids = p.points.ids
    p.sticks = [Stick(int(ids[0]), int(ids[1])), Stick(int(ids[1]), 10**6)]  # 2nd: no such point
    out = api.export_fbx(p, tmp_path / "s.fbx", include_sticks=True)
    assert [n for n in fbx_node_names(out) if n == "M0-M1"] == ["M0-M1"]
    p.set_current_frame(7)
    x = read_xcp(api.export_xcp(p, tmp_path / "a.xcp"))
    assert x.n_cameras == C
    np.testing.assert_allclose(x.intrinsics.focal, 400.0)
    R, t = x.extrinsics_at([0])
    np.testing.assert_allclose(t[0], truth["cam_t"], atol=1e-6)


def test_export_errors_leave_no_file(tmp_path, truth):
    empty = new_project(10, 2)
    with pytest.raises(ValueError, match="no face points"):
        api.export_c3d(empty, tmp_path / "e.c3d")
    with pytest.raises(ValueError, match="no camera calibration"):
        api.export_xcp(empty, tmp_path / "e.xcp")
    p = project_from_truth(truth)
    with pytest.raises(CaraFileError, match="does not exist"):
        api.export_c3d(p, tmp_path / "missing" / "a.c3d")
    with pytest.raises(ValueError, match="must end in .fbx"):
        api.export_fbx(p, tmp_path / "a.c3d")
    with pytest.raises(ValueError, match="frame_range"):
        api.export_c3d(p, tmp_path / "a.c3d", frame_range="some")
    with pytest.raises(ValueError, match="stabilis"):
        api.export_c3d(p, tmp_path / "a.c3d", stabilized=True)
    p.calibration.solved[3] = False
    with pytest.raises(ValueError, match="not solved at frame 3"):
        api.export_xcp(p, tmp_path / "a.xcp", frame=3)
    # a writer failing mid-way (labels it refuses) leaves nothing behind either
    p.points.labels[0] = " "
    with pytest.raises(ValueError):
        api.export_c3d(p, tmp_path / "a.c3d")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- files


def _video(path: Path, n: int = 5, size=IMG) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, size, isColor=False)
    for i in range(n):
        w.write(np.full((size[1], size[0]), i * 10, np.uint8))
    w.release()
    return path


def test_relocate_files_after_moving_videos(tmp_path):
    src = tmp_path / "shoot"
    src.mkdir()
    for c in ("cam0", "cam1"):
        _video(src / f"T_{c}.mkv")
    project = api.import_take(src)
    (tmp_path / "proj").mkdir()
    saved = api.save_project(project, tmp_path / "proj" / "T.cara")
    moved = tmp_path / "archive"
    shutil.move(str(src), str(moved))
    reopened = api.open_project(saved)
    assert set(api.missing_files(reopened)) == {"cam0", "cam1"}
    stack = CommandStack(reopened)
    api.relocate_files(reopened, moved, stack=stack)
    assert api.missing_files(reopened) == {}
    assert Path(reopened.take.cameras[1].video_path) == moved / "T_cam1.mkv"
    stack.undo()
    assert set(api.missing_files(reopened)) == {"cam0", "cam1"}
    stack.redo()
    # explicit mapping by name and index; a video of another size is refused
    _video(tmp_path / "other.mkv", size=(64, 48))
    with pytest.raises(CommandError, match="64x48"):
        api.relocate_files(reopened, {"cam0": tmp_path / "other.mkv"})
    with pytest.raises(CommandError, match="no camera named"):
        api.relocate_files(reopened, {"camX": moved / "T_cam0.mkv"})
    with pytest.raises(CaraFileError, match="nope.mkv"):
        api.relocate_files(reopened, {1: tmp_path / "nope.mkv"})
    cmd = api.relocate_files(reopened, {1: moved / "T_cam0.mkv"})
    assert reopened.take.cameras[1].video_path.endswith("T_cam0.mkv")
    cmd.undo(reopened)
    assert reopened.take.cameras[1].video_path.endswith("T_cam1.mkv")


def test_open_project_finds_videos_beside_it(tmp_path):
    folder = tmp_path / "a"
    folder.mkdir()
    _video(folder / "T_cam0.mkv")
    api.save_project(api.import_take(folder), folder / "T.cara")
    shutil.move(str(folder), str(tmp_path / "b"))
    reopened = api.open_project(tmp_path / "b" / "T.cara")
    assert api.missing_files(reopened) == {}


def test_process_take_without_calibration_says_why_and_writes_nothing(tmp_path):
    take = tmp_path / "take"
    take.mkdir()
    for c in ("cam0", "cam1"):
        _video(take / f"T_{c}.mkv", n=6)
    with pytest.raises(ValueError, match="no XCP calibration and no ROM"):
        api.process_take(take / "T_cam0.mkv", output=tmp_path / "out.cara",
                         c3d=tmp_path / "out.c3d")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take"]


def test_process_take_rejects_bad_input_before_any_work(tmp_path):
    take = tmp_path / "take"
    take.mkdir()
    _video(take / "T_cam0.mkv")
    out = tmp_path / "o.cara"
    with pytest.raises(CaraFileError, match="no such file"):
        api.process_take(tmp_path / "nothing", output=out)
    with pytest.raises(CaraFileError, match="ROM project not found"):
        api.process_take(take, output=out, rom=tmp_path / "rom.cara")
    bad = tmp_path / "b.csv"
    bad.write_text("B1,1,1,1\nB2,zz,1,1\n")
    with pytest.raises(CaraFileError, match="line 2"):
        api.process_take(take, output=out, brim=bad)
    with pytest.raises(CaraFileError, match="does not exist"):
        api.process_take(take, output=out, fbx=tmp_path / "no" / "x.fbx")
    assert not out.exists()


def test_api_does_not_import_qt():
    import subprocess
    import sys

    code = ("import sys, carapost.api, carapost.demo; "
            "print(any(m.startswith(('PySide6', 'PyQt', 'pyqtgraph')) for m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert res.stdout.strip() == "False"


def test_evaluate_reads_the_synthetic_truth_format(tmp_path):
    synth = pytest.importorskip("carapost.synth")
    scene = synth.build_scene(synth.SynthConfig(frames=6, size=(160, 96), n_cameras=2,
                                                markers="sparse35"))
    tp = tmp_path / "truth.npz"
    synth.write_truth(tp, scene)
    p = new_project(scene.n_frames, scene.n_cameras, image_size=(160, 96))
    n = scene.points3d.shape[1]
    cols = p.points.append(n, labels=list(scene.labels))
    p.points.positions[:, cols] = scene.points3d
    p.points.recon[:, cols] = RECON_TRIANGULATED
    p.points.obs[:, cols] = np.where(scene.visible[..., None], scene.uv, np.nan)
    r = api.evaluate(p, tp)
    assert r["n_matched"] == n and r["spurious_points"] == 0 and r["swaps"] == 0
    assert r["rmse_mm"] == pytest.approx(0.0, abs=1e-3)
    assert r["coverage"] == 1.0
    assert r["reprojection_rms_px"] == pytest.approx(0.0, abs=1e-3)
