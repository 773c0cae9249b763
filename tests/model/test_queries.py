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
