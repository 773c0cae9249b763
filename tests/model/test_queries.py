"""Derived queries of the model, against hand-built ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.camera import CameraIntrinsics, project
from carapost.model import queries
from carapost.model.project import (
    RECON_INTERPOLATED,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    new_project,
)


def _project_with_cameras(rng: np.random.Generator):
    F, C, P = 12, 4, 5
    prj = new_project(F, C)
    prj.points.append(P)
    intr = CameraIntrinsics(focal=[900] * C, principal_point=[[640, 360]] * C,
                            radial=[[1e-8, 0, 0]] * C, image_size=[[1280, 720]] * C)
    prj.calibration.intrinsics = intr
    R = np.broadcast_to(np.eye(3), (C, 3, 3)).copy()
    t = np.array([[-30.0 * c, 0, 250] for c in range(C)])
    prj.calibration.set_static(R, t)
    X = rng.uniform(-20, 20, size=(F, P, 3))
    prj.points.positions[:] = X
    prj.points.recon[:] = RECON_TRIANGULATED
    uv, _ = project(X, prj.calibration.R, prj.calibration.t, intr)
    prj.points.obs[:] = uv
    prj.points.source[:] = SOURCE_BLOB
    return prj, uv


def test_contribution_mask_and_count(rng: np.random.Generator) -> None:
    prj, _ = _project_with_cameras(rng)
    pts = prj.points
    pts.obs[3, 1, 2] = np.nan
    pts.source[3, 1, 2] = 0
    pts.recon[5, 2] = RECON_INTERPOLATED
    mask = queries.contribution_mask(prj)
    assert mask.shape == (12, 5, 4)
    assert not mask[3, 1, 2] and mask[3, 1, [0, 1, 3]].all()
    assert not mask[5, 2].any()
    count = queries.contribution_count(prj)
    assert count[3, 1] == 3 and count[5, 2] == 0 and count[0, 0] == 4
    np.testing.assert_array_equal(queries.contribution_count(prj, (3, 5)), count[3:6])


def test_reprojection_error(rng: np.random.Generator) -> None:
    prj, uv = _project_with_cameras(rng)
    err = queries.reprojection_error(prj)
    assert np.nanmax(err) < 1e-3
    prj.points.obs[4, 0, 1] += [3.0, 4.0]  # 5 px off in one of 4 cameras
    err = queries.reprojection_error(prj, chunk=5)
    assert err[4, 0] == pytest.approx(5.0 / 4, abs=1e-3)


def test_gaps_fewest_gaps_next_gap() -> None:
    prj = new_project(20, 2)
    prj.points.append(3)
    pos = prj.points.positions
    pos[:] = 1.0
    pos[0:2, 0] = np.nan  # leading run: not a gap
    pos[5:7, 0] = np.nan
    pos[10:11, 0] = np.nan
    pos[18:, 0] = np.nan  # trailing run: not a gap
    pos[8:9, 1] = np.nan
    np.testing.assert_array_equal(queries.gaps(prj, 0), [[5, 6], [10, 10]])
    np.testing.assert_array_equal(queries.gap_counts(prj), [2, 1, 0])
    assert queries.point_with_fewest_gaps(prj) == 1
    assert queries.next_gap(prj, 0, 6) == (10, 10)
    assert queries.next_gap(prj, 0, 10) is None
    np.testing.assert_array_equal(queries.gaps(prj, 0, (6, 15)), [[10, 10]])
    prj.points.positions[:] = 1.0
    assert queries.point_with_fewest_gaps(prj) is None


def test_events_batch_and_unknown_part() -> None:
    prj = new_project(5, 2)
    seen = []
    prj.events.subscribe(seen.append)
    with prj.events.batch():
        prj.set_current_frame(3)
        prj.set_active_range((1, 3))
    assert len(seen) == 1 and seen[0].parts == {"current_frame", "ranges"}
    prj.set_current_frame(3)  # no real change: no event
    assert len(seen) == 1
    with pytest.raises(ValueError, match="unknown"):
        prj.events.emit("nonsense")
    with pytest.raises(ValueError, match="outside the take"):
        prj.set_active_range((2, 9))


def test_point_information_and_distance(rng: np.random.Generator) -> None:
    prj, uv = _project_with_cameras(rng)
    f, col = 4, 2
    # the point uses detection 1 of camera 3: semi-axes 2.5 x 1.5 px
    table = {"centre": np.array([[0, 0], uv[f, col, 3]], np.float32),
             "axes": np.array([[9, 9], [2.5, 1.5]], np.float16),
             "angle": np.zeros(2, np.float16), "colour": np.zeros(2, np.int8),
             "score": np.ones(2, np.float16)}
    prj.detections.replace_images([(f, 3)], [table])
    prj.points.detection[f, col, 3] = 1
    prj.points.obs[f, col, 1] = np.nan
    info = queries.point_information(prj, col, f)
    X = prj.points.positions[f, col].astype(np.float64)
    assert info.frame == f and info.point_id == int(prj.points.ids[col])
    assert np.array_equal(info.position, X)
    assert np.isnan(info.observations[1]).all()
    assert np.allclose(info.observations[0], uv[f, col, 0], atol=1e-3)
    assert np.isnan(info.blob_size[:3]).all() and np.allclose(info.blob_size[3], [5, 3])
    # R = I: the camera centres are -t = (30 c, 0, -250)
    centres = np.array([[30.0 * c, 0, -250] for c in range(4)])
    want = {"caddy 1": centres[:2].mean(0), "caddy 2": centres[2:].mean(0),
            "all cameras": centres.mean(0)}
    got = dict(info.centroid_distances)
    assert list(got) == ["caddy 1", "caddy 2", "all cameras"]
    for name, centroid in want.items():
        assert got[name] == pytest.approx(np.linalg.norm(centroid - X))
    text = info.text()
    assert "Sensor 1: -" in text and "blob 5.0 x 3.0 px" in text
    assert f"Distance to centroid of caddy 2: {got['caddy 2']:.1f} mm" in text
    # the take's rig metadata decides the caddies (the same as Initialize 3D's)
    prj.take.metadata["rig"] = {"caddies": [[0, 1, 2], [3]]}
    got = dict(queries.point_information(prj, col, f).centroid_distances)
    assert list(got) == ["caddy 1", "caddy 2", "all cameras"]
    assert got["caddy 1"] == pytest.approx(np.linalg.norm(centres[:3].mean(0) - X))
    # no 3D position: no distances
    prj.points.positions[f, col] = np.nan
    none = queries.point_information(prj, col, f)
    assert none.centroid_distances == () and "3D: none" in none.text()
    a, b = prj.points.positions[0, :2].astype(np.float64)
    assert queries.distance_between(prj, 0, 1, 0) == pytest.approx(np.linalg.norm(a - b))
    assert np.isnan(queries.distance_between(prj, col, 0, f))
