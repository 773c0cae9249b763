"""Per-track Target Tracker sizes: set (undoable), used by the next run, saved."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from carapost import Session
from carapost.algorithms.codes import SOURCE_TARGET
from carapost.commands.stack import CommandError
from carapost.commands.target_track import prepare_target_track
from carapost.io.cara import load_project, save_project
from carapost.synth.demo_project import demo_project, render_dots
from tests.commands.test_edit_commands import snapshot


@pytest.fixture()
def keyed():
    """A demo project with one point keyed (target track) in two cameras at frame 10."""
    p = demo_project(40, 8, 4, size=(320, 240))
    s = Session(p, get_image=lambda f, c: render_dots(p, f, c))
    col = 2
    pid = int(p.points.ids[col])
    s.select(points=[pid])
    s.current_frame = 10
    for c in (0, 1):
        s.edit_target_track(pid, c, 10, p.points.obs[10, col, c].astype(float) + 0.1)
    return s, p, pid


def test_set_size_is_one_undoable_step(keyed):
    s, p, pid = keyed
    before = snapshot(p)
    n = len(s.history())
    s.set_target_track_size(pid, 1, pattern=30)      # even: rounded to odd
    assert p.target_sizes[(pid, 1)] == (31, 81)
    s.set_target_track_size(pid, 1, search=25)       # the box shrinks with the cross
    assert s.target_track_size(pid, 1) == (25, 25)
    s.set_target_track_size(pid, 1, pattern=41)      # the cross grows with the box
    assert s.target_track_size(pid, 1) == (41, 41)
    assert s.target_track_size(pid, 0) == (21, 81)   # the other camera keeps the defaults
    assert len(s.history()) == n + 3
    after = snapshot(p)
    for _ in range(3):
        s.undo()
    assert snapshot(p) == before and p.target_sizes == {}
    for _ in range(3):
        s.redo()
    assert snapshot(p) == after


@pytest.mark.parametrize("kwargs, message", [
    ({"pattern": 3}, "pattern box .* 5-255 px"), ({"search": 2000}, "Search Size"),
    ({}, "give a pattern"),
    ({"pattern": 241}, "larger than the 320 x 240"),
])
def test_bad_sizes_are_refused_with_nothing_changed(keyed, kwargs, message):
    s, p, pid = keyed
    before = snapshot(p)
    with pytest.raises(CommandError, match=message):
        s.set_target_track_size(pid, 0, **kwargs)
    assert snapshot(p) == before
    with pytest.raises(CommandError, match="no point"):
        s.set_target_track_size(99999, 0, pattern=21)
    with pytest.raises(CommandError, match="no camera"):
        s.set_target_track_size(pid, 9, pattern=21)


def test_the_next_run_uses_each_tracks_own_sizes(keyed):
    s, p, pid = keyed
    s.set_target_track_size(pid, 1, pattern=15)
    s.set_target_track_size(pid, 1, search=41)
    ow = {"overwrite_existing_tracks": True}   # the demo point has 2D data next frame
    job = prepare_target_track(p, lambda f, c: render_dots(p, f, c), 1, single_frame=True,
                               **ow)
    sizes = {tr.camera: (tr.params or job.params) for tr in job.tracks}
    assert (sizes[1].pattern_size, sizes[1].search_size) == (15, 41)
    assert (sizes[0].pattern_size, sizes[0].search_size) == (21, 81)
    # an explicit size of the run (a script's override) wins over the track's
    job = prepare_target_track(p, lambda f, c: render_dots(p, f, c), 1, single_frame=True,
                               pattern_size=11, **ow)
    sizes = {tr.camera: (tr.params or job.params) for tr in job.tracks}
    assert sizes[1].pattern_size == 11 and sizes[1].search_size == 41
    assert sizes[0].pattern_size == 11
    # and the run itself goes through with them
    s.target_track(+1, single_frame=True, **ow)
    col = int(p.points.index_of([pid])[0])
    assert np.isfinite(p.points.obs[11, col, :2]).all()
    assert (p.points.source[11, col, :2] == SOURCE_TARGET).all()


def test_sizes_are_saved_and_older_files_open(keyed, tmp_path):
    s, p, pid = keyed
    s.set_target_track_size(pid, 1, pattern=25)
    path = save_project(p, tmp_path / "shot.cara")
    q = load_project(path)
    assert q.target_sizes == {(pid, 1): (25, 81)}
    # an older file (no member) opens with the defaults; bad entries are left out
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
        members = {n: zf.read(n) for n in names}
    manifest_name = next(n for n in names if n.endswith(".json")
                         and b'"target_sizes"' in members[n])
    m = json.loads(members[manifest_name])
    for raw, want in ((None, {}), ([[pid, 1, 25, 81], [pid, 1, "x", 3], [pid, 7, 9, 9],
                                    [424242, 0, 9, 9], [pid, 0, 41, 21]],
                                   {(pid, 1): (25, 81)})):
        if raw is None:
            m.pop("target_sizes")
        else:
            m["target_sizes"] = raw
        out = tmp_path / f"edited{len(str(raw))}.cara"
        with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w") as dst:
            for info in src.infolist():
                data = (json.dumps(m).encode() if info.filename == manifest_name
                        else src.read(info.filename))
                dst.writestr(info, data)
        assert load_project(out).target_sizes == want
