"""Remove Spurious Points through the Session, and the uncertainty in the exports."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from carapost import Session
from carapost.commands.stack import CommandError
from carapost.synth.demo_project import scene_project


def test_session_removes_them_in_one_undo_entry():
    project, scene, _ = scene_project(frames=60, size=(640, 360))
    session = Session(project)
    pts = project.points
    n = pts.n_points if hasattr(pts, "n_points") else len(pts.ids)
    with pytest.raises(CommandError):
        session.remove_spurious_points()
    # make one face point a speck: present in 5 frames only
    col = 3
    pts.positions[5:, col] = np.nan
    pts.recon[5:, col] = 0
    label = project.point_label(col)
    cmd = session.remove_spurious_points()
    assert [lab for lab, _ in cmd.removed] == [label]
    assert len(project.points.ids) == n - 1
    session.stack.undo()
    assert len(project.points.ids) == n and project.point_label(col) == label
    session.stack.redo()
    assert len(project.points.ids) == n - 1


def test_c3d_residual_word_carries_sigma_and_the_sidecar_lists_it(tmp_path):
    from carapost.export import export_c3d, export_sigma_csv
    from carapost.io.c3d import read_c3d
    from carapost.io.sigma_csv import sidecar_path

    project, _, _ = scene_project(frames=12, size=(640, 360))
    pts = project.points
    face = np.flatnonzero(pts.kind == 0)
    rng = np.random.default_rng(0)
    sig = rng.uniform(0.02, 0.6, (12, face.size)).astype(np.float32)
    sig[3, 0] = np.nan  # unknown: the ray residual is written instead
    pts.arrays["sigma"][:, face] = sig
    pts.residual[:, face] = 0.9
    out = export_c3d(project, tmp_path / "take.c3d")
    data = read_c3d(out)
    res = data.residuals
    ok = np.isfinite(sig)
    # 0.01 mm steps (the largest value, 0.9 mm, fits 255 of them)
    assert np.allclose(res[ok], sig[ok], atol=0.006)
    assert res[3, 0] == pytest.approx(0.9, abs=0.006)
    rays = read_c3d(export_c3d(project, tmp_path / "rays.c3d", residual="rays")).residuals
    assert np.allclose(rays[np.isfinite(rays)], 0.9, atol=0.006)
    with pytest.raises(ValueError, match="residual"):
        export_c3d(project, tmp_path / "bad.c3d", residual="nope")

    side = export_sigma_csv(project, sidecar_path(out))
    assert side.name == "take.sigma.csv"
    with side.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == int(np.isfinite(pts.positions[:, face, 0]).sum())
    first = rows[0]
    assert first["frame"] == "1" and first["label"] == project.point_label(int(face[0]))
    assert float(first["sigma_mm"]) == pytest.approx(float(sig[0, 0]), abs=1e-4)
    assert first["recon"] == "triangulated"
    blank = [r for r in rows if r["frame"] == "4" and r["label"] == first["label"]]
    assert blank and blank[0]["sigma_mm"] == ""
