"""Every Edit command: do it, check the model, undo (bit-identical), redo (same result)."""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np
import pytest

from carapost.commands import edit
from carapost.commands.stack import CommandError, CommandStack
from carapost.model.project import (
    KIND_BRIM,
    RECON_INTERPOLATED,
    RECON_NONE,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    SOURCE_NONE,
    Project,
    new_project,
)

F, C, P = 30, 4, 6


def make_project(rng: np.random.Generator) -> Project:
    """A small project: detections in every image, points attached to some of them."""
    project = new_project(F, C)
    det = project.detections
    images, tables = [], []
    for f in range(F):
        for c in range(C):
            n = 8
            images.append((f, c))
            tables.append(
                {
                    "centre": rng.uniform(0, 1000, size=(n, 2)).astype(np.float32),
                    "axes": rng.uniform(3, 6, size=(n, 2)).astype(np.float16),
                    "angle": rng.uniform(0, 3, size=n).astype(np.float16),
                    "colour": np.zeros(n, np.int8),
                    "score": rng.uniform(0.5, 1, size=n).astype(np.float16),
                }
            )
    det.replace_images(images, tables)
    pts = project.points
    pts.append(P, labels=["Nose_Tip", "", "Chin", "", "", "Brim_1"])
    pts.kind[5] = KIND_BRIM
    # point p uses detection p in every image, except gaps
    for p in range(P):
        pts.detection[:, p, :] = p
        for c in range(C):
            pts.obs[:, p, c] = det.arrays["centre"][det.offsets[np.arange(F) * C + c] + p]
        pts.source[:, p, :] = SOURCE_BLOB
        pts.quality[:, p, :] = 1.0
    pts.positions[:] = rng.normal(size=(F, P, 3)).astype(np.float32)
    pts.recon[:] = RECON_TRIANGULATED
    pts.residual[:] = rng.uniform(0, 0.3, size=(F, P)).astype(np.float32)
    # a gap and some interpolated frames
    pts.positions[10:13, 1] = np.nan
    pts.recon[10:13, 1] = RECON_NONE
    pts.recon[20:23, 2] = RECON_INTERPOLATED
    pts.obs[20:23, 2] = np.nan
    pts.source[20:23, 2] = SOURCE_NONE
    pts.detection[20:23, 2] = -1
    project.labels = ["Nose_Tip", "Chin", "Brow_L"]
    project.current_frame = 15
    project.active_range = (5, 24)
    project.view_range = (0, F - 1)
    return project


def snapshot(project: Project) -> dict:
    """Everything an edit can change, as bytes (for bit-identity)."""
    pts = project.points
    return {
        "ids": pts.ids.tobytes(),
        "labels": list(pts.labels),
        "kind": pts.kind.tobytes(),
        "arrays": {k: (v.dtype.str, v.shape, v.tobytes()) for k, v in pts.arrays.items()},
        "next_id": pts.next_id,
        "det_offsets": project.detections.offsets.tobytes(),
        "det": {k: v.tobytes() for k, v in project.detections.arrays.items()},
        "label_list": list(project.labels),
        "sticks": copy.deepcopy(project.sticks),
        "props": project.properties.to_dict(),
        "ranges": (project.active_range, project.view_range),
        "selection": project.selection,
        "cameras": copy.deepcopy(project.take.cameras),
        "target_sizes": dict(project.target_sizes),
    }


def run_roundtrip(
    project: Project, make: Callable[[Project], edit.Command], check: Callable[[Project], None]
) -> None:
    """Do, check, undo (bit-identical), redo (bit-identical to the first do)."""
    stack = CommandStack(project)
    before = snapshot(project)
    size = model_nbytes(project)
    cmd = stack.push(make(project))
    check(project)
    after = snapshot(project)
    assert after != before, "the command changed nothing"
    assert stack.undo()
    assert snapshot(project) == before
    assert stack.redo()
    assert snapshot(project) == after
    # the History entry reports what the command holds for undo: something, and no more
    # than a few copies of the model (old state saved plus any result kept for redo)
    memory = stack.history()[0].memory
    assert memory == cmd.memory() > 0
    assert memory <= 4 * max(size, model_nbytes(project)) + 4096


def model_nbytes(project: Project) -> int:
    """Bytes of the per-point arrays and the detections."""
    return (sum(a.nbytes for a in project.points.arrays.values())
            + sum(a.nbytes for a in project.detections.arrays.values())
            + project.detections.offsets.nbytes)


@pytest.fixture
def project(rng: np.random.Generator) -> Project:
    return make_project(rng)


def test_create_points_from_detections(project: Project) -> None:
    dets = [(3, 0, 7), (3, 1, 6)]

    def check(p: Project) -> None:
        assert p.n_points == P + 2
        np.testing.assert_array_equal(p.points.obs[3, P, 0], p.detections.centres(3, 0)[7])
        assert p.points.detection[3, P + 1, 1] == 6
        assert p.points.source[3, P, 0] == SOURCE_BLOB
        assert np.isnan(p.points.positions[:, P:]).all()
        assert len(set(p.points.ids.tolist())) == P + 2

    run_roundtrip(project, lambda p: edit.CreatePointsFromDetections(p, dets), check)


def test_delete_selected_points(project: Project) -> None:
    ids = project.points.ids[[1, 3]].tolist()
    project.set_selection(points=ids)

    def check(p: Project) -> None:
        assert p.n_points == P - 2
        assert not set(ids) & set(p.points.ids.tolist())
        assert p.points.labels == ["Nose_Tip", "Chin", "", "Brim_1"]

    run_roundtrip(project, edit.DeleteSelected, check)


def test_delete_selected_detections_remaps_point_references(project: Project) -> None:
    # delete detection 0 of image (4, 2): point 0 loses it, points 1.. shift down by one
    def check(p: Project) -> None:
        assert len(p.detections.centres(4, 2)) == 7
        assert p.points.detection[4, 0, 2] == -1 and np.isnan(p.points.obs[4, 0, 2]).all()
        assert p.points.detection[4, 3, 2] == 2
        np.testing.assert_array_equal(
            p.detections.centres(4, 2)[p.points.detection[4, 3, 2]], p.points.obs[4, 3, 2]
        )
        assert p.points.detection[5, 3, 2] == 3  # other frames untouched

    run_roundtrip(project, lambda p: edit.DeleteSelected(p, [], [(4, 2, 0)]), check)


def test_split_selected_point(project: Project) -> None:
    pid = int(project.points.ids[0])
    project.set_selection(points=[pid])
    orig = project.points.positions[:, 0].copy()

    def check(p: Project) -> None:
        assert p.n_points == P + 1
        assert np.isnan(p.points.positions[15:, 0]).all()
        np.testing.assert_array_equal(p.points.positions[:15, 0], orig[:15])
        np.testing.assert_array_equal(p.points.positions[15:, P], orig[15:])
        assert np.isnan(p.points.positions[:15, P]).all()
        assert p.selection.points == {int(p.points.ids[P])}

    run_roundtrip(project, edit.SplitSelectedPoint, check)


def test_merge_points_fills_gaps(project: Project) -> None:
    pts = project.points
    # point 3 only has data where point 1 has its gap
    pts.positions[:, 3] = np.nan
    pts.positions[10:13, 3] = 7.0
    pts.recon[:, 3] = RECON_NONE
    pts.recon[10:13, 3] = RECON_TRIANGULATED
    pts.obs[:10, 3] = np.nan
    pts.obs[13:, 3] = np.nan
    pts.obs[10:13, 1] = np.nan
    ids = pts.ids[[1, 3]].tolist()

    def check(p: Project) -> None:
        assert p.n_points == P - 1
        col = int(p.points.index_of([ids[0]])[0])
        assert (p.points.positions[10:13, col] == 7.0).all()
        assert not np.isnan(p.points.obs[10:13, col]).any()
        assert p.selection.points == {ids[0]}

    run_roundtrip(project, lambda p: edit.Merge(p, ids, []), check)


def test_merge_detections_creates_point(project: Project) -> None:
    dets = [(2, 0, 5), (2, 1, 4), (2, 3, 1)]

    def check(p: Project) -> None:
        assert p.n_points == P + 1
        assert (p.points.detection[2, P, [0, 1, 3]] == [5, 4, 1]).all()

    run_roundtrip(project, lambda p: edit.Merge(p, [], dets), check)


def test_merge_refuses_two_detections_in_one_image(project: Project) -> None:
    with pytest.raises(CommandError, match="same image"):
        edit.Merge(project, [], [(2, 0, 5), (2, 0, 4)])


@pytest.mark.parametrize("which", ["current_frame", "active_range"])
def test_clear_selected(project: Project, which: str) -> None:
    pid = int(project.points.ids[2])
    project.set_selection(points=[pid])
    frames = slice(15, 16) if which == "current_frame" else slice(5, 25)

    def check(p: Project) -> None:
        assert np.isnan(p.points.positions[frames, 2]).all()
        assert (p.points.recon[frames, 2] == RECON_NONE).all()
        assert (p.points.detection[frames, 2] == -1).all()
        assert not np.isnan(p.points.positions[:5, 2]).any()
        assert p.detections.total == F * C * 8  # detections stay

    run_roundtrip(project, getattr(edit.ClearSelected, which), check)


def test_clear_active_range(project: Project) -> None:
    def check(p: Project) -> None:
        assert np.isnan(p.points.positions[5:25]).all()
        assert not np.isnan(p.points.positions[:5, 0]).any()
        assert not np.isnan(p.points.positions[25:, 0]).any()

    run_roundtrip(project, edit.ClearActiveRange, check)


@pytest.mark.parametrize("which", ["current_frame", "active_range"])
def test_detach_respects_explicit_cameras(project: Project, which: str) -> None:
    project.set_selection(points=[int(project.points.ids[0])], cameras=[1, 3])
    frames = slice(15, 16) if which == "current_frame" else slice(5, 25)

    def check(p: Project) -> None:
        assert (p.points.detection[frames, 0][:, [1, 3]] == -1).all()
        assert (p.points.detection[frames, 0][:, [0, 2]] == 0).all()
        assert (p.points.source[frames, 0][:, [1, 3]] == SOURCE_NONE).all()
        # active camera 0 is ignored because cameras are explicitly selected
        assert (p.points.detection[:5, 0] == 0).all()

    run_roundtrip(project, lambda p: getattr(edit.DetachDetections, which)(p, 0), check)


def test_detach_uses_active_camera_without_explicit_selection(project: Project) -> None:
    project.set_selection(points=[int(project.points.ids[0])])

    def check(p: Project) -> None:
        assert p.points.detection[15, 0, 2] == -1
        assert (p.points.detection[15, 0, [0, 1, 3]] == 0).all()

    run_roundtrip(project, lambda p: edit.DetachDetections.current_frame(p, 2), check)


def test_remove_unused_detections(project: Project) -> None:
    def check(p: Project) -> None:
        counts = p.detections.counts()
        # 6 points use detections 0..5, except point 2's interpolated frames 20-22
        assert counts[0, 0] == P
        assert counts[21, 0] == P - 1
        det = p.points.detection
        for f in (0, 21):
            for c in range(C):
                used = det[f, :, c] >= 0
                np.testing.assert_array_equal(
                    p.detections.centres(f, c)[det[f, used, c]], p.points.obs[f, used, c]
                )

    run_roundtrip(project, edit.RemoveUnusedDetections, check)


def test_remove_interpolated_3d_points(project: Project) -> None:
    def check(p: Project) -> None:
        assert (p.points.recon[20:23, 2] == RECON_NONE).all()
        assert np.isnan(p.points.positions[20:23, 2]).all()
        assert not np.isnan(p.points.positions[19, 2]).any()

    run_roundtrip(project, edit.RemoveInterpolated3DPoints, check)


def test_rename_point_moves_label(project: Project) -> None:
    pid = int(project.points.ids[1])

    def check(p: Project) -> None:
        assert p.points.labels[1] == "Nose_Tip"
        assert p.points.labels[0] == ""  # a label names one point

    run_roundtrip(project, lambda p: edit.RenamePoint(p, pid, "Nose_Tip"), check)
    with pytest.raises(CommandError, match="space"):
        edit.RenamePoint(project, pid, "Nose Tip")


def test_assign_new_label_adds_it_to_list(project: Project) -> None:
    pid = int(project.points.ids[3])

    def check(p: Project) -> None:
        assert p.points.labels[3] == "Lip_Upper"
        assert "Lip_Upper" in p.labels

    run_roundtrip(project, lambda p: edit.AssignLabel(p, pid, "Lip_Upper"), check)


def test_unlabel_selected_points(project: Project) -> None:
    project.set_selection(points=project.points.ids[[0, 2]].tolist())

    def check(p: Project) -> None:
        assert p.points.labels[0] == "" and p.points.labels[2] == ""
        assert p.points.labels[5] == "Brim_1"

    run_roundtrip(project, edit.UnlabelSelectedPoints, check)


def test_clear_all_labels(project: Project) -> None:
    def check(p: Project) -> None:
        assert p.labels == []

    run_roundtrip(project, edit.ClearAllLabels, check)


def test_delete_selected_labels(project: Project) -> None:
    def check(p: Project) -> None:
        assert p.labels == ["Nose_Tip", "Brow_L"]

    run_roundtrip(project, lambda p: edit.DeleteSelectedLabels(p, ["Chin"]), check)


def test_add_labels_appends_copy_suffix(project: Project) -> None:
    def check(p: Project) -> None:
        assert p.labels == ["Nose_Tip", "Chin", "Brow_L", "Nose_Tip - Copy", "Ear_L"]

    run_roundtrip(project, lambda p: edit.AddLabels(p, ["Nose_Tip", "Ear_L"]), check)


def test_sticks(project: Project) -> None:
    ids = project.points.ids[[0, 1]].tolist()
    project.set_selection(points=ids)

    def check(p: Project) -> None:
        assert len(p.sticks) == 1 and {p.sticks[0].a, p.sticks[0].b} == set(ids)

    run_roundtrip(project, edit.CreateStick, check)
    run_roundtrip(
        project,
        lambda p: edit.EditStickColor(p, [0], (255, 0, 0)),
        lambda p: None if p.sticks[0].colour == (255, 0, 0) else pytest.fail("colour"),
    )
    with pytest.raises(CommandError, match="already"):
        edit.CreateStick(project)


def test_properties_commands(project: Project) -> None:
    def check_set(p: Project) -> None:
        assert p.properties["black_threshold"] == 0.55

    run_roundtrip(project, lambda p: edit.SetProperties(p, {"black_threshold": 0.55}), check_set)
    with pytest.raises(CommandError, match="Black Threshold"):
        edit.SetProperties(project, {"black_threshold": 3.0})
    CommandStack(project).push(edit.SetProperties(project, {"black_threshold": 0.7}))

    def check_defaults(p: Project) -> None:
        assert p.properties["black_threshold"] == 0.4

    run_roundtrip(project, edit.RestorePropertiesToDefaults, check_defaults)


def test_revert_blob_parameters(project: Project) -> None:
    project.imported_blob_parameters = {"black_threshold": 0.3}
    run_roundtrip(
        project,
        edit.RevertBlobParameters,
        lambda p: None if p.properties["black_threshold"] == 0.3 else pytest.fail("threshold"),
    )


def test_increment_offset_and_rotate(project: Project) -> None:
    project.set_selection(cameras=[2])
    run_roundtrip(
        project,
        edit.IncrementImageSequenceOffset,
        lambda p: None if [c.frame_offset for c in p.take.cameras] == [0, 0, 1, 0]
        else pytest.fail("offset"),
    )
    run_roundtrip(
        project,
        lambda p: edit.RotateSelectedSensors(p, clockwise=False),
        lambda p: None if p.take.cameras[2].rotation == 270 else pytest.fail("rotation"),
    )
    project.set_selection(cameras=[])
    with pytest.raises(CommandError, match="select one or more camera"):
        edit.IncrementImageSequenceOffset(project)


def test_ranges(project: Project) -> None:
    project.current_frame = 8
    run_roundtrip(project, edit.SetRange.active_start,
                  lambda p: None if p.active_range == (8, 24) else pytest.fail("start"))
    project.current_frame = 20
    run_roundtrip(project, edit.SetRange.active_end,
                  lambda p: None if p.active_range == (8, 20) else pytest.fail("end"))
    run_roundtrip(project, edit.SetRange.reset_active,
                  lambda p: None if p.active_range == (0, F - 1) else pytest.fail("reset"))
    project.active_range = (5, 24)
    run_roundtrip(project, edit.SetRange.view_to_active,
                  lambda p: None if p.view_range == (5, 24) else pytest.fail("view"))
    project.view_range = (3, 9)
    run_roundtrip(project, edit.SetRange.reset_view,
                  lambda p: None if p.view_range == (0, F - 1) else pytest.fail("view"))


def test_refusals_leave_project_unchanged(project: Project) -> None:
    before = snapshot(project)
    for make in (
        lambda p: edit.DeleteSelected(p),
        lambda p: edit.SplitSelectedPoint(p),
        lambda p: edit.CreateStick(p),
        lambda p: edit.ClearSelected.current_frame(p),
        lambda p: edit.CreatePointsFromDetections(p, [(0, 0, 99)]),
    ):
        with pytest.raises(CommandError):
            make(project)
    assert snapshot(project) == before


def test_history_goto_and_clear(project: Project) -> None:
    stack = CommandStack(project)
    before = snapshot(project)
    stack.push(edit.ClearActiveRange(project))
    stack.push(edit.ClearAllLabels(project))
    stack.goto(0)
    assert snapshot(project) == before
    hist = stack.history()
    assert [h.undone for h in hist] == [True, True]
    stack.goto(2)
    assert project.labels == []
    freed = stack.clear()
    assert freed > 0 and len(stack) == 0 and not stack.can_undo


def test_events_fire_on_do_and_undo(project: Project) -> None:
    seen = []
    project.events.subscribe(lambda change: seen.append(change.parts))
    stack = CommandStack(project)
    stack.push(edit.ClearAllLabels(project))
    stack.undo()
    assert seen == [frozenset({"labels"}), frozenset({"labels"})]
