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


def test_a_ghost_matched_across_caddies_is_removed_with_its_reason():
    """A point made of marker a in one camera of caddy 0 and a neighbour b in one camera
    of caddy 1 (the dense held-out take's ghost): it moves with the skin and its blobs
    are a marker's, but its rays do not meet. Every real marker stays."""
    from carapost.algorithms.codes import RECON_TRIANGULATED
    from carapost.algorithms.triangulation import TriangulationParameters, triangulate
    from carapost.commands.quality import spurious_points

    project, scene, _ = scene_project(frames=60, size=(640, 360))
    pts = project.points
    cal = project.calibration
    rng = np.random.default_rng(1)
    obs = pts.obs.astype(np.float64) + rng.normal(0, 0.1, pts.obs.shape)  # blob noise
    pts.obs[:] = obs
    face = np.flatnonzero(pts.kind == 0)
    seen = np.isfinite(obs[..., 0])
    both = seen[:, face][:, :, 1].all(0) & seen[:, face][:, :, 2].all(0)
    a = face[np.flatnonzero(both)[0]]
    rest = np.nanmedian(pts.positions[:, face], 0)
    d = np.linalg.norm(rest - rest[face == a], axis=-1)
    d[~both | (d < 1e-6)] = np.inf
    params = TriangulationParameters(minimum_cameras=2, use_outlier_rejection=False)

    def ghost(b):
        g = np.full(obs.shape[:1] + (1,) + obs.shape[2:], np.nan)
        g[:, 0, 1], g[:, 0, 2] = obs[:, a, 1], obs[:, b, 2]
        res = triangulate(g, cal.R, cal.t, cal.intrinsics, params)
        return g, res.points, float(np.median(res.residual))

    # of its five nearest neighbours, the one furthest off the epipolar line
    near = face[np.argsort(d)[:5]]
    b = max(near, key=lambda k: ghost(k)[2])
    g, X, _ = ghost(b)
    assert np.isfinite(X).all()
    col = int(pts.append(1, labels=["Ghost"])[0])
    pts.positions[:, col] = X[:, 0]
    pts.recon[:, col] = RECON_TRIANGULATED
    pts.obs[:, col] = g[:, 0]
    found = spurious_points(project)
    assert [lab for _, lab, _ in found] == ["Ghost"], found
    assert found[0][2].startswith("rays do not meet")


def test_points_without_camera_observations_are_not_judged():
    """Imported points (a C3D, no 2D) are never removed: the rules are for points
    tracked on this rig (a head-rig marker moves unlike the skin around it)."""
    project, _, _ = scene_project(frames=60, size=(640, 360))
    pts = project.points
    pts.obs[:] = np.nan
    pts.positions[5:, 3] = np.nan   # would be "too few frames" if it were tracked here
    pts.recon[5:, 3] = 0
    session = Session(project)
    with pytest.raises(CommandError, match="no tracked point to judge"):
        session.remove_spurious_points()


def test_no_marker_of_a_facial_c3d_fixture_is_judged_spurious():
    import os
    from pathlib import Path

    from carapost.commands.quality import spurious_points

    root = os.environ.get("CARAPOST_FIXTURES")
    path = Path(root or "/nonexistent") / "c3d" / "facial_Sing_sample29.c3d"
    if not path.is_file():
        pytest.skip("CARAPOST_FIXTURES not set or the facial C3D fixture is absent")
    session = Session.import_c3d(path)
    assert spurious_points(session.project) == []
