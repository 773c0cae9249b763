"""Remove Filtering: the raw data of filtered samples come back (selected points, active
range) as one History entry, also after save and reopen; older files open."""

from __future__ import annotations

import numpy as np

from carapost import Session
from carapost.algorithms.codes import RECON_FILTERED, RECON_INTERPOLATED, RECON_TRIANGULATED
from tests.commands.test_gapfill_commands import cut, make_session, snapshot


def _noisy_session():
    s, X = make_session(frames=400, points=12)
    pts = s.project.points
    rng = np.random.default_rng(1)
    pts.positions[:] += rng.normal(scale=0.3, size=pts.positions.shape).astype(np.float32)
    pts.sigma[:] = 0.25
    return s


def test_remove_filtering_restores_raw_bit_for_bit_one_entry_undo_redo():
    s = _noisy_session()
    pts = s.project.points
    raw = {k: pts.arrays[k].copy() for k in ("positions", "recon", "sigma")}
    s.filter_trajectories(6.0)
    assert (pts.recon == RECON_FILTERED).all()
    filtered = snapshot(s.project)
    s.remove_filtering()
    assert [c.description for c in s.history()][-1].startswith("Remove Filtering")
    assert len(s.history()) == 2
    for k, v in raw.items():
        assert np.array_equal(pts.arrays[k], v, equal_nan=True), k
    assert np.isnan(pts.arrays["raw_positions"]).all()
    restored = snapshot(s.project)
    s.undo()
    assert snapshot(s.project) == filtered
    s.redo()
    assert snapshot(s.project) == restored


def test_filtering_twice_keeps_the_first_raw_and_scope_is_points_and_range():
    s = _noisy_session()
    pts = s.project.points
    raw = pts.positions.copy()
    s.filter_trajectories(10.0)
    s.filter_trajectories(4.0)
    s.project.active_range = (100, 199)
    s.remove_filtering(points=[int(pts.ids[3])])
    assert np.array_equal(pts.positions[100:200, 3], raw[100:200, 3])
    assert (pts.recon[100:200, 3] == RECON_TRIANGULATED).all()
    assert (pts.recon[:100, 3] == RECON_FILTERED).all()          # outside the range
    assert not np.array_equal(pts.positions[100:200, 4], raw[100:200, 4])   # not selected
    assert s.remove_filtering(points=[int(pts.ids[3])]) is None  # nothing left there


def test_samples_filled_or_retracked_since_keep_their_new_values():
    s = _noisy_session()
    pts = s.project.points
    s.filter_trajectories(6.0)
    pts.recon[50:60, 1] = RECON_TRIANGULATED                     # tracked again since
    newer = pts.positions[50:60, 1].copy()
    cut(s, 2, 200, 10)
    s.interpolate_gaps(method="guide")                           # new fills: no raw
    assert (pts.recon[200:210, 2] == RECON_INTERPOLATED).all()
    fill = pts.positions[200:210, 2].copy()
    s.remove_filtering()
    assert np.array_equal(pts.positions[50:60, 1], newer)
    assert np.array_equal(pts.positions[200:210, 2], fill)
    assert (pts.recon[:50, 1] == RECON_TRIANGULATED).all()       # restored


def test_raw_values_survive_save_and_reopen_and_unfiltered_files_have_no_raw(tmp_path):
    s = _noisy_session()
    plain = tmp_path / "plain.cara"
    s.save(plain)
    import zipfile

    assert not any("raw_" in n for n in zipfile.ZipFile(plain).namelist())
    raw = s.project.points.positions.copy()
    s.filter_trajectories(6.0)
    path = tmp_path / "filtered.cara"
    s.save(path)
    with Session.open(path) as t:
        t.remove_filtering()
        assert np.array_equal(t.project.points.positions, raw)
    with Session.open(plain) as t:                               # no raw members: blank
        assert np.isnan(t.project.points.arrays["raw_positions"]).all()
        assert t.remove_filtering() is None
