"""Stabilised exports (C3D read back by ezc3d and by our reader, FBX), the pipeline stage
``stabilise_take`` and ``carapost export-c3d --stabilized``."""

from __future__ import annotations

import copy

import ezc3d
import numpy as np
import pytest

from carapost import Session
from carapost.io.c3d import read_c3d
from carapost.model.project import KIND_FACE
from carapost.model.stabilization import processed_positions
from carapost.synth.demo_project import scene_project


@pytest.fixture(scope="module")
def base_project():
    p, _, _ = scene_project(frames=60, preset="speech", seed=2)
    rng = np.random.default_rng(3)
    p.points.positions[:] += rng.normal(0, 0.06, p.points.positions.shape).astype(np.float32)
    return p


@pytest.fixture
def session(base_project):
    return Session(copy.deepcopy(base_project))


def test_stabilised_c3d_read_by_ezc3d(session, tmp_path):
    from carapost.pipeline import stabilise_take

    s = session
    msg = stabilise_take(s, "auto")
    assert "base frame error" in msg
    labels = list(s.project.points.labels)
    three = [int(s.project.points.ids[labels.index(n)])
             for n in ("Nose_Tip", "Forehead_Hi_L", "Forehead_Hi_R")]
    s.align(three)
    raw_path = s.export_c3d(tmp_path / "raw.c3d", frame_range="all")
    path = s.export_c3d(tmp_path / "stab.c3d", frame_range="all", stabilized=True)
    face = np.flatnonzero(s.project.points.kind == KIND_FACE)
    want = processed_positions(s.project, 0, s.project.n_frames - 1, face)
    e = ezc3d.c3d(str(path))
    pts = np.asarray(e["data"]["points"])[:3].transpose(2, 1, 0)
    assert list(e["parameters"]["POINT"]["LABELS"]["value"]) == [labels[c] for c in face]
    ok = np.isfinite(want).all(-1)
    np.testing.assert_allclose(pts[ok], want[ok], atol=1e-3)
    assert np.isnan(pts[~ok]).all()
    # a rigidly moved measurement keeps its camera mask and residual (file-formats.md)
    a, b = read_c3d(raw_path), read_c3d(path)
    np.testing.assert_array_equal(a.camera_mask, b.camera_mask)
    np.testing.assert_array_equal(a.residuals, b.residuals)
    # the aligned origin is at the first point
    k = list(face).index(int(s.project.points.index_of([three[0]])[0]))
    assert np.abs(pts[s.project.current_frame, k]).max() < 1e-3


def test_stabilised_fbx_and_refusal(session, tmp_path):
    s = session
    with pytest.raises(ValueError, match="needs a stabilised project"):
        s.export_c3d(tmp_path / "x.c3d", stabilized=True)
    with pytest.raises(ValueError, match="needs a stabilised project"):
        s.export_fbx(tmp_path / "x.fbx", stabilized=True)
    assert not (tmp_path / "x.c3d").exists() and not (tmp_path / "x.fbx").exists()
    s.set_active_range(10, 49)
    s.stabilize("auto")
    raw = s.export_fbx(tmp_path / "raw.fbx", frame_range="all", include_cameras=True)
    stab = s.export_fbx(tmp_path / "stab.fbx", frame_range="all", include_cameras=True,
                        stabilized=True)
    assert raw.read_bytes() != stab.read_bytes()
    # frames outside the stabilised range are gaps in a stabilised export
    c = read_c3d(s.export_c3d(tmp_path / "part.c3d", frame_range="all", stabilized=True))
    assert np.isnan(c.positions[:10]).all() and np.isfinite(c.positions[10:50]).any()


def test_pipeline_assisted_stage_and_cli(session, tmp_path):
    from carapost.cli import main
    from carapost.pipeline import stabilise_take

    s = session
    stabilise_take(s, "assisted")
    st = s.project.stabilization
    assert st.mode == "assisted" and st.base_frame == 0 and len(st.point_ids) >= 3
    with pytest.raises(ValueError, match="auto' or 'assisted"):
        stabilise_take(s, "manual")
    cara = s.save(tmp_path / "p.cara")
    out = tmp_path / "cli.c3d"
    assert main(["export-c3d", str(cara), str(out), "--stabilized"]) == 0
    d = read_c3d(out)
    face = np.flatnonzero(s.project.points.kind == KIND_FACE)
    want = processed_positions(s.project, 0, s.project.n_frames - 1, face)
    ok = np.isfinite(want).all(-1)
    np.testing.assert_allclose(d.positions[ok], want[ok], atol=1e-3)
