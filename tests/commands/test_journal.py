"""The journal and the stack: masked diffs, change extents, groups, clean state."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.commands import edit
from carapost.commands.process import set_cameras
from carapost.commands.results import ApplyPointData, ReplaceDetections
from carapost.commands.stack import Command, CommandError, CommandStack, Journal
from carapost.model.events import Change, merge_changes
from carapost.model.project import (
    RECON_INTERPOLATED,
    RECON_NONE,
    RECON_TRIANGULATED,
    Project,
    new_project,
)
from tests.commands.test_edit_commands import make_project, snapshot


def record(project: Project) -> list[Change]:
    changes: list[Change] = []
    project.events.subscribe(changes.append)
    return changes


# -- masked diffs ----------------------------------------------------------------------------
def sparse_take(F: int = 3000, P: int = 120, seed: int = 0) -> Project:
    """A long take with a few short interpolated gaps (the case Remove Interpolated meets)."""
    rng = np.random.default_rng(seed)
    p = new_project(F, 4)
    p.points.append(P)
    pts = p.points
    pts.positions[:] = rng.normal(size=pts.positions.shape).astype(np.float32)
    pts.recon[:] = RECON_TRIANGULATED
    pts.residual[:] = rng.uniform(0, 0.3, size=(F, P)).astype(np.float32)
    for col in rng.choice(P, 8, replace=False):
        for start in rng.choice(F - 20, 3, replace=False):
            pts.recon[start:start + int(rng.integers(3, 15)), col] = RECON_INTERPOLATED
    p.active_range = (0, F - 1)
    return p


def test_remove_interpolated_keeps_a_masked_diff_not_the_dense_block():
    p = sparse_take()
    pts = p.points
    interp = pts.recon == RECON_INTERPOLATED
    n = int(interp.sum())
    # what the dense record saved: the active range x every column of three arrays
    dense = sum(pts.arrays[k].nbytes for k in ("positions", "recon", "residual"))
    stack = CommandStack(p)
    before = snapshot(p)
    stack.push(edit.RemoveInterpolated3DPoints(p))
    assert not (pts.recon == RECON_INTERPOLATED).any()
    assert np.isnan(pts.positions[interp]).all() and (pts.recon[interp] == RECON_NONE).all()
    after = snapshot(p)
    masked = stack.history()[0].memory
    # old values (12 + 1 + 4 bytes per sample) and a 4-byte index per sample, plus ids
    assert n * 17 <= masked <= n * 21 + 2048
    assert masked < dense / 500, (masked, dense)
    print(f"Remove Interpolated undo: {n} samples, dense {dense / 1e6:.2f} MB -> "
          f"masked {masked / 1e3:.1f} kB")
    assert stack.undo() and snapshot(p) == before
    assert stack.redo() and snapshot(p) == after


class _MaskEdit(Command):
    """Test command: set observations of a mask to NaN through ``point_mask``."""

    description = "Mask Edit"

    def __init__(self, project: Project, frames: slice, cols: np.ndarray, mask: np.ndarray):
        super().__init__(project)
        self.frames, self.ids, self.mask = frames, project.points.ids[cols].copy(), mask

    def apply(self, project: Project, journal: Journal) -> None:
        pts = project.points
        cols = pts.index_of(self.ids)
        journal.point_mask(self.frames, cols, self.mask, ("obs", "source", "positions"))
        for name, fill in (("obs", np.nan), ("source", 0), ("positions", np.nan)):
            sub = pts.arrays[name][self.frames]
            block = sub[:, cols]
            block[self.mask] = fill
            sub[:, cols] = block


def test_point_mask_round_trip_with_scattered_columns_and_trailing_axes(rng):
    p = make_project(rng)
    cols = np.array([0, 2, 3, 5])
    mask = np.zeros((10, 4), bool)
    mask[[1, 4, 7], [0, 2, 3]] = True
    changes = record(p)
    stack = CommandStack(p)
    before = snapshot(p)
    stack.push(_MaskEdit(p, slice(10, 20), cols, mask))
    assert np.isnan(p.points.obs[11, 0]).all() and np.isnan(p.points.positions[17, 5]).all()
    after = snapshot(p)
    # the change names the bounding box frames and only the columns with masked samples
    assert changes[-1].frames == (11, 17)
    assert changes[-1].points.tolist() == [0, 3, 5]
    assert stack.undo() and snapshot(p) == before
    assert changes[-1].frames == (11, 17) and changes[-1].points.tolist() == [0, 3, 5]
    assert stack.redo() and snapshot(p) == after
    # an empty mask saves and changes nothing
    j = Journal(p)
    j.point_mask(slice(0, 5), cols, np.zeros((5, 4), bool))
    assert j.nbytes() == 0 and not j.parts


# -- change extents --------------------------------------------------------------------------
def test_change_events_name_frames_points_and_cameras(rng):
    p = make_project(rng)
    changes = record(p)
    stack = CommandStack(p)
    ids = [int(p.points.ids[1]), int(p.points.ids[4])]
    stack.push(ApplyPointData((3, 6), ids, {"residual": np.zeros((4, 2))}, "Write"))
    ch = changes[-1]
    assert ch.parts == {"points"} and ch.frames == (3, 6) and ch.points.tolist() == [1, 4]
    # detections of some images: frames and cameras; the detached points named too
    n = 2
    table = {"centre": np.zeros((n, 2), np.float32), "axes": np.ones((n, 2), np.float16),
             "angle": np.zeros(n, np.float16), "colour": np.zeros(n, np.int8),
             "score": np.ones(n, np.float16)}
    stack.push(ReplaceDetections([(8, 1), (9, 3)], [table, table]))
    ch = changes[-1]
    assert ch.parts == {"detections", "points"} and ch.frames == (8, 9)
    assert ch.cameras is None  # the detached points' observations (every camera) changed
    assert set(ch.points.tolist()) == set(range(6))
    # calibration of a block of frames: frames only
    class SetCams(Command):
        def apply(self, project, journal):
            set_cameras(journal, project, slice(2, 5), project.calibration.R[2:5],
                        project.calibration.t[2:5] + 1.0)

    stack.push(SetCams(p))
    ch = changes[-1]
    assert ch.parts == {"cameras"} and ch.frames == (2, 4) and ch.points is None
    # a list attribute: nothing known more precisely
    stack.push(edit.AddLabels(p, ["Lip_U"]))
    ch = changes[-1]
    assert ch.parts == {"labels"} and ch.frames is None and ch.points is None
    # undo sends the same extent as do
    stack.undo()
    stack.undo()
    assert changes[-1].parts == {"cameras"} and changes[-1].frames == (2, 4)


def test_merge_changes_is_the_one_union_used_by_batches():
    a = Change(frozenset({"points"}), (3, 5), np.array([1, 2]))
    b = Change(frozenset({"points"}), (8, 9), np.array([2, 7]))
    m = merge_changes([a, b])
    assert m.frames == (3, 9) and m.points.tolist() == [1, 2, 7] and m.cameras is None
    assert merge_changes([a, Change(frozenset({"labels"}))]).points is None
    p = new_project(10, 2)
    p.points.append(3)
    got = record(p)
    with p.events.batch():
        p.events.emit("points", frames=(3, 5), points=np.array([1]))
        p.events.emit("points", frames=(4, 6), points=np.array([2]))
    assert len(got) == 1 and got[0].frames == (3, 6) and got[0].points.tolist() == [1, 2]
    from carapost.ui import bridge

    assert bridge.merge_changes is merge_changes


# -- groups ----------------------------------------------------------------------------------
def test_group_is_one_history_entry_with_one_undo_and_one_event(rng):
    p = make_project(rng)
    stack = CommandStack(p)
    before = snapshot(p)
    changes = record(p)
    pid = int(p.points.ids[0])
    with stack.group("Drag Keyframe") as grp:
        for k in range(3):
            stack.push(edit.ApplyPointData((4 + k, 4 + k), [pid],
                                           {"residual": np.full((1, 1), k)}, "step"))
        with pytest.raises(RuntimeError, match="group"):
            stack.undo()
    assert len(grp.commands) == 3
    assert len(changes) == 1 and changes[0].frames == (4, 6)  # one merged event
    assert len(stack) == 1 and stack.undo_text() == "Drag Keyframe"
    assert stack.history()[0].memory > 0
    after = snapshot(p)
    assert stack.undo() and snapshot(p) == before
    assert len(changes) == 2 and changes[1].frames == (4, 6)
    assert stack.redo() and snapshot(p) == after


def test_nested_groups_and_failing_step_rolls_the_group_back(rng):
    p = make_project(rng)
    stack = CommandStack(p)
    stack.push(edit.AddLabels(p, ["Lip_U"]))
    before = snapshot(p)
    with stack.group("Outer"):
        stack.push(edit.AddLabels(p, ["Lip_L"]))
        with stack.group("Inner"):
            stack.push(edit.AddLabels(p, ["Jaw"]))
            stack.push(edit.AddLabels(p, ["Brow_R"]))
    assert len(stack) == 2 and len(stack._commands[1].commands) == 2
    after = snapshot(p)
    assert stack.undo() and snapshot(p) == before
    assert stack.redo() and snapshot(p) == after
    # a failing step: the group's earlier steps are undone, nothing is added
    with pytest.raises(CommandError):
        with stack.group("Broken"):
            stack.push(edit.AddLabels(p, ["Cheek_L"]))
            with stack.group("Inner"):
                stack.push(edit.AddLabels(p, ["Cheek_R"]))
            stack.push(edit.RenamePoint(p, int(p.points.ids[0]), "has space"))
    assert snapshot(p) == after and len(stack) == 2
    # an empty group adds no entry
    with stack.group("Nothing"):
        pass
    assert len(stack) == 2


# -- clean state -----------------------------------------------------------------------------
def test_mark_unsaved_after_opening_a_recovered_copy(rng):
    p = make_project(rng)
    calls = []
    stack = CommandStack(p, on_change=lambda: calls.append(1))
    assert stack.is_clean
    stack.mark_unsaved()
    assert not stack.is_clean and p.modified and calls
    stack.push(edit.AddLabels(p, ["Lip_U"]))
    stack.undo()
    assert not stack.is_clean and p.modified  # no position equals a saved file
    stack.mark_clean()
    assert stack.is_clean and not p.modified


def test_journal_helpers_properties_and_whole_calibration(rng):
    p = make_project(rng)
    stack = CommandStack(p)
    before = snapshot(p)
    stack.push(edit.SetProperties(p, {"select_sensors": False}))
    stack.push(edit.RestorePropertiesToDefaults(p))
    assert stack.undo() and stack.undo() and snapshot(p) == before
    old = p.calibration

    class Replace(Command):
        def apply(self, project, journal):
            journal.calibration(None)
            new = project.calibration.copy()
            new.t[:] += 5.0
            project.calibration = new

    stack.push(Replace(p))
    assert p.calibration is not old
    stack.undo()
    assert p.calibration.t.tobytes() == old.t.tobytes()
