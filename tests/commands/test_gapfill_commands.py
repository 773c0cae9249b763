"""Interpolate Gaps, Filter Trajectories, Find Problems and repairs through the Session:
one History entry each, undo bit-identical, redo the same, exports and C3D import."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from carapost import Session
from carapost.algorithms.codes import (
    RECON_FILTERED,
    RECON_INTERPOLATED,
    RECON_NONE,
    RECON_SINGLE_SENSOR,
    RECON_TRIANGULATED,
)
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.project import new_project
from tests.algorithms.test_gapfill import face_take

FIXTURES = os.environ.get("CARAPOST_FIXTURES")


def snapshot(project):
    pts = project.points
    return {k: (v.dtype.str, v.shape, v.tobytes()) for k, v in pts.arrays.items()}


def make_session(frames=600, points=20, seed=0):
    X = face_take(frames=frames, points=points, seed=seed)
    project = new_project(frames, 0, fps=100.0)
    pts = project.points
    pts.append(points, labels=[f"M{i}" for i in range(points)])
    pts.positions[:] = X.astype(np.float32)
    pts.recon[:] = RECON_TRIANGULATED
    pts.residual[:] = 0.1
    project.active_range = (0, frames - 1)
    return Session(project), X


def cut(session, p, s, L, recon=RECON_NONE):
    pts = session.project.points
    if recon == RECON_NONE:
        pts.positions[s:s + L, p] = np.nan
        pts.residual[s:s + L, p] = np.nan
    pts.recon[s:s + L, p] = recon


def test_interpolate_gaps_one_entry_undo_bit_identical_redo_same():
    s, X = make_session()
    cut(s, 3, 100, 20)
    cut(s, 7, 300, 60)
    cut(s, 9, 400, 5, RECON_SINGLE_SENSOR)      # 3D from one camera: filled too
    before = snapshot(s.project)
    cmd = s.interpolate_gaps()
    assert len(s.history()) == 1 and s.history()[0].description.startswith("Interpolate Gaps")
    pts = s.project.points
    assert (pts.recon[100:120, 3] == RECON_INTERPOLATED).all()
    assert (pts.recon[400:405, 9] == RECON_INTERPOLATED).all()
    assert np.isfinite(pts.sigma[300:360, 7]).all() and np.isnan(pts.sigma[:100]).all()
    err = np.linalg.norm(pts.positions[300:360, 7] - X[300:360, 7], axis=-1)
    assert err.max() < 5.0
    after = snapshot(s.project)
    rep = s.gap_report()
    assert rep["filled_samples"] == 85 and {g["label"] for g in rep["gaps"]} == {"M3", "M7", "M9"}
    assert all(g["estimated_rmse_mm"] is not None for g in rep["gaps"])
    s.undo()
    assert snapshot(s.project) == before
    s.redo()
    assert snapshot(s.project) == after
    assert cmd.memory() < 50_000               # a sparse record, not the block


def test_selected_points_range_and_overwrite():
    s, _ = make_session()
    cut(s, 2, 100, 10)
    cut(s, 4, 100, 10)
    cut(s, 4, 500, 10)
    s.project.active_range = (0, 300)
    s.interpolate_gaps(points=[int(s.project.points.ids[4])], method="guide")
    pts = s.project.points
    assert (pts.recon[100:110, 4] == RECON_INTERPOLATED).all()
    assert (pts.recon[100:110, 2] == RECON_NONE).all()       # not selected
    assert (pts.recon[500:510, 4] == RECON_NONE).all()       # outside the active range
    # a second run changes nothing: earlier fills are left alone
    assert s.interpolate_gaps(points=[int(pts.ids[4])]) is None
    old = pts.positions[100:110, 4].copy()
    s.set_property("Gap-Filling Parameters", "overwrite_existing_filled_gaps", True)
    s.interpolate_gaps(points=[int(pts.ids[4])], method="spline")
    assert not np.array_equal(old, pts.positions[100:110, 4])


def test_bad_input_clear_messages_rest_filled(tmp_path):
    s, _ = make_session(frames=300, points=8)
    cut(s, 1, 100, 20)
    cut(s, 5, 0, 300)                            # never known
    rep_path = tmp_path / "gaps.json"
    s.interpolate_gaps(report=rep_path)
    data = json.loads(rep_path.read_text())
    assert any("M5" in m for m in data["messages"])
    assert (s.project.points.recon[100:120, 1] == RECON_INTERPOLATED).all()
    assert (s.project.points.recon[:, 5] == RECON_NONE).all()
    with pytest.raises(CommandError, match="Gap-Filling|method|must be one of"):
        s.interpolate_gaps(method="magic")


def test_remove_interpolated_clears_sigma_and_undoes():
    s, _ = make_session()
    cut(s, 3, 100, 20)
    s.interpolate_gaps()
    mid = snapshot(s.project)
    s.remove_interpolated_3d_points()
    pts = s.project.points
    assert np.isnan(pts.positions[100:120, 3]).all() and np.isnan(pts.sigma).all()
    s.undo()
    assert snapshot(s.project) == mid


def test_filter_trajectories_never_across_a_gap_undo_restores_raw():
    s, X = make_session()
    rng = np.random.default_rng(0)
    pts = s.project.points
    pts.positions[:] += rng.normal(scale=0.3, size=pts.positions.shape).astype(np.float32)
    cut(s, 2, 200, 30)
    raw = snapshot(s.project)
    s.filter_trajectories(6.0, order=4)
    assert (pts.recon[:200, 2] == RECON_FILTERED).all()
    assert np.isnan(pts.positions[200:230, 2]).all()
    e_raw = np.sqrt(np.nanmean((np.frombuffer(raw["positions"][2], np.float32).reshape(X.shape)
                                - X) ** 2))
    e_f = np.sqrt(np.nanmean((pts.positions[50:-50] - X[50:-50]) ** 2))
    assert e_f < 0.5 * e_raw
    s.undo()
    assert snapshot(s.project) == raw
    with pytest.raises(CommandError, match="half the frame rate"):
        s.filter_trajectories(80.0)


def test_find_problems_and_one_click_repairs_undo_bit_identically():
    s, X = make_session(frames=1500, points=25, seed=4)
    pts = s.project.points
    pts.positions[400, 5] += np.array([6.0, 0, 0], np.float32)
    d = np.linalg.norm(X[0][:, None] - X[0][None], axis=-1) + np.eye(25) * 1e9
    j = int(np.argmin(d[11]))
    pts.positions[900:, [11, j]] = pts.positions[900:, [j, 11]]
    g = next(q for q in range(25) if q not in (5, 11, j))
    cut(s, g, 1200, 15)
    probs = s.find_problems()
    kinds = {(p.kind, p.point_ids, p.first) for p in probs}
    ids = pts.ids
    assert ("spike", (int(ids[5]),), 400) in kinds
    assert ("gap", (int(ids[g]),), 1200) in kinds
    swap = [p for p in probs if p.kind == "swap"]
    assert len(swap) == 1 and set(swap[0].point_ids) == {int(ids[11]), int(ids[j])}
    assert len(probs) == 3
    for prob in probs:
        before = snapshot(s.project)
        n = len(s.history())
        s.repair(prob)
        assert len(s.history()) == n + 1
        after = snapshot(s.project)
        s.undo()
        assert snapshot(s.project) == before
        s.redo()
        assert snapshot(s.project) == after
    assert np.linalg.norm(pts.positions[400, 5] - X[400, 5]) < 1.0
    assert np.allclose(pts.positions[1000, [11, j]], X[1000, [11, j]], atol=1e-3)
    assert [p.kind for p in s.find_problems()] == []


def test_interpolated_samples_export_as_modified(tmp_path):
    from carapost.io.c3d import read_c3d

    s, _ = make_session(frames=200, points=6)
    cut(s, 1, 50, 10)
    s.interpolate_gaps()
    out = s.export_c3d(tmp_path / "out.c3d", frame_range="all")
    d = read_c3d(out)
    assert d.processed[50:60, 1].all() and not d.processed[:50, 1].any()
    assert (d.residuals[50:60, 1] == 0).all() and not d.camera_mask[50:60, 1].any()


def test_import_c3d_no_points_is_refused(tmp_path):
    from carapost.io.c3d import write_c3d

    one = tmp_path / "one.c3d"
    write_c3d(one, np.zeros((10, 1, 3)), labels=["A"], rate=100.0)
    raw = bytearray(one.read_bytes())
    raw[2:4] = (0).to_bytes(2, "little")        # header: 0 points
    empty = tmp_path / "empty.c3d"
    empty.write_bytes(bytes(raw))
    with pytest.raises(CaraFileError, match="no 3D points"):
        Session.import_c3d(empty)
    with pytest.raises(CaraFileError, match="no such file"):
        Session.import_c3d(tmp_path / "missing.c3d")


@pytest.mark.skipif(not FIXTURES, reason="CARAPOST_FIXTURES not set")
def test_import_c3d_of_a_real_facial_capture_and_fill():
    path = Path(FIXTURES) / "c3d" / "facial_Sing_sample29.c3d"
    if not path.exists():
        pytest.skip("facial_Sing_sample29.c3d not among the fixtures")
    s = Session.import_c3d(path)
    p = s.project
    assert (p.n_frames, p.points.count, p.take.fps) == (3000, 38, 100.0)
    assert p.points.labels[0] == "root-1" and p.n_cameras == 0
    missing = np.isnan(p.points.positions[..., 0])
    s.interpolate_gaps(max_gap=200)
    filled = p.points.recon == RECON_INTERPOLATED
    assert filled.sum() > 0.8 * (missing[:, :37]).sum()
    labelled = filled[:, :37]                  # the last point (Unlabeled1) is 1 % present
    assert np.isfinite(p.points.sigma[:, :37][labelled]).mean() > 0.9


def test_fill_gaps_command_line_c3d_to_c3d_and_cara(tmp_path, capsys):
    from carapost.cli import main
    from carapost.io.c3d import read_c3d, write_c3d

    X = face_take(frames=400, points=12, seed=2)
    Xg = X.copy()
    Xg[100:130, 4] = np.nan
    Xg[:, 9] = np.nan                              # a marker never seen: left, with a message
    src = tmp_path / "in.c3d"
    write_c3d(src, Xg, labels=[f"L{i}" for i in range(12)], rate=100.0)
    out, rep = tmp_path / "out.c3d", tmp_path / "rep.json"
    assert main(["fill-gaps", str(src), "-o", str(out), "--method", "guide",
                 "--report", str(rep)]) == 0
    d = read_c3d(out)
    assert d.labels[:12] == [f"L{i}" for i in range(12)]
    err = np.linalg.norm(d.positions[100:130, 4] - X[100:130, 4], axis=-1)
    assert err.max() < 3.0 and d.processed[100:130, 4].all()
    assert np.isnan(d.positions[:, 9]).all()
    data = json.loads(rep.read_text())
    assert data["filled_samples"] == 30 and any("L9" in m for m in data["messages"])
    assert "filled 1 of 2 gaps" in capsys.readouterr().out
    cara = tmp_path / "out.cara"
    assert main(["fill-gaps", str(src), "-o", str(cara), "--max-gap", "10"]) == 0
    s = Session.open(cara)
    assert np.isnan(s.project.points.positions[100:130, 4]).all()   # 30 > 10: left
    assert main(["fill-gaps", str(src), "-o", str(tmp_path / "x.txt")]) == 2
