"""carapost.Session: one path per action, one History entry per action, exact undo."""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost import Session, api
from carapost.commands.stack import CommandError
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_BRIM, RECON_TRIANGULATED, Project, Stick, new_project
from carapost.model.rig import caddies, caddy_groups
from tests.commands.test_edit_commands import make_project
from tests.commands.test_edit_commands import snapshot as edit_snapshot


def snapshot(project: Project) -> dict:
    """Everything an action can change, as bytes (for bit identity)."""
    cal = project.calibration
    intr = cal.intrinsics
    return {
        **edit_snapshot(project),
        "cal": (cal.R.tobytes(), cal.t.tobytes(), cal.solved.tobytes(),
                None if intr is None else (intr.focal.tobytes(),
                                           intr.principal_point.tobytes())),
        "rom": None if project.rom is None else project.rom.path,
        "current": project.current_frame,
    }


def roundtrip(session: Session, act: Callable[[Session], object]) -> None:
    """The action makes exactly one History entry, undoes to bit identity, redoes to the
    same result."""
    before = snapshot(session.project)
    n = session.stack.position
    act(session)
    entries = session.history()
    assert len(entries) == session.stack.position == n + 1 and not entries[-1].undone
    after = snapshot(session.project)
    assert after != before, "the action changed nothing"
    assert session.undo()
    assert snapshot(session.project) == before
    assert session.redo()
    assert snapshot(session.project) == after


def project_state(p: Project) -> dict:
    """A project's data and metadata, for comparing two imports."""
    cal = p.calibration
    return {
        "snapshot": edit_snapshot(p),
        "cal": (cal.R.tobytes(), cal.t.tobytes(), cal.solved.tobytes()),
        "intrinsics": None if cal.intrinsics is None else cal.intrinsics.K().tobytes(),
        "metadata": p.take.metadata, "fps": p.take.fps, "name": p.take.name,
        "timecode": p.take.timecode_start, "n_frames": p.n_frames,
        "blob_parameters": p.imported_blob_parameters,
    }


# ----------------------------------------------------------------------------- import


def test_import_take_is_one_path(synth_take):
    """Session.import_take == api.import_take (the window's loaders: tests/ui)."""
    session = Session.import_take(synth_take)
    via_api = api.import_take(synth_take)
    assert project_state(session.project) == project_state(via_api)
    # the brim model of the take is there (the step `carapost gui` used to skip)
    assert (session.project.points.kind == KIND_BRIM).sum() > 0
    assert session.history() == []


def test_session_open_save(tmp_path):
    s = Session(make_project(np.random.default_rng(1)))
    with pytest.raises(CommandError, match="give a path"):
        s.save()
    s.set_active_range(2, 9)
    path = s.save(tmp_path / "a.cara")
    assert s.stack.is_clean and s.save() == path
    opened = Session.open(path)
    assert opened.project.active_range == (2, 9) and opened.history() == []
    with pytest.raises(CaraFileError, match="no such file"):
        Session.open(tmp_path / "none.cara")


def test_from_carapost_and_api_without_renderer():
    import subprocess
    import sys

    code = ("import sys, carapost; from carapost import Session; import carapost.api; "
            "print(Session.__module__, any(m.startswith('carapost.synth') for m in sys.modules))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert res.stdout.split() == ["carapost.session", "False"]


# ----------------------------------------------------------------------------- exports


def export_project() -> Session:
    p = new_project(20, 2, fps=50.0, name="exp", image_size=(200, 150))
    cols = p.points.append(5, labels=["A", "B", "C", "Brim01", "Brim02"])
    p.points.kind[cols[3:]] = KIND_BRIM
    rng = np.random.default_rng(3)
    p.points.positions[:] = rng.normal(size=p.points.positions.shape).astype(np.float32)
    p.points.recon[:] = RECON_TRIANGULATED
    p.points.residual[:] = 0.1
    return Session(p)


def read_back(path: Path) -> tuple[list[str], int, np.ndarray]:
    """Labels, first frame and positions [F, P, 3] read by the independent c3d reader."""
    import warnings

    c3d = pytest.importorskip("c3d")
    with warnings.catch_warnings(), open(path, "rb") as fh:
        warnings.simplefilter("ignore")  # py-c3d warns that there is no analog data
        reader = c3d.Reader(fh)
        labels = [s.strip() for s in reader.point_labels]
        frames = np.array([pts[:, :3].copy() for _, pts, _ in reader.read_frames()])
        return labels, int(reader.first_frame), frames


def test_c3d_export_honours_the_export_properties(tmp_path):
    s = export_project()
    p = s.project
    s.set_active_range(4, 12)
    s.set_property("Export", "Export Range", "active")  # by label
    s.set_property("Export", "export_include_brim_points", True)  # by key
    labels, first, X = read_back(s.export_c3d(tmp_path / "a.c3d"))
    assert labels == ["A", "B", "C", "Brim01", "Brim02"]
    assert first == 5 and X.shape == (9, 5, 3)  # frames 4-12, burnt-in numbers from 1
    np.testing.assert_allclose(X, p.points.positions[4:13], atol=1e-4)
    # a keyword replaces one property; the others still apply
    labels, first, X = read_back(s.export_c3d(tmp_path / "b.c3d", include_brim=False))
    assert labels == ["A", "B", "C"] and X.shape == (9, 3, 3)
    s.set_properties({"export_range": "all", "export_include_brim_points": False})
    labels, first, X = read_back(s.export_c3d(tmp_path / "c.c3d"))
    assert first == 1 and X.shape == (20, 3, 3)
    with pytest.raises(TypeError, match="unknown export option"):
        s.export_c3d(tmp_path / "d.c3d", brim=True)


def test_fbx_export_honours_the_export_properties(tmp_path, monkeypatch):
    import carapost.io.fbx as fbx

    calls = []
    monkeypatch.setattr(fbx, "write_fbx", lambda path, positions, **kw: calls.append(
        (positions.shape, kw)))
    s = export_project()
    ids = s.project.points.ids
    s.project.sticks = [Stick(int(ids[0]), int(ids[1]))]
    s.set_active_range(2, 5)
    s.set_properties({"fbx_up_axis": "Z", "fbx_include_sticks": True,
                      "export_include_brim_points": True})
    s.export_fbx(tmp_path / "a.fbx")  # FBX Include Cameras is on, but no calibration
    shape, kw = calls[-1]
    assert shape == (4, 5, 3) and kw["up_axis"] == "z" and kw["sticks"] == [(0, 1)]
    assert kw["cameras"] is None
    with pytest.raises(ValueError, match="cannot include cameras"):
        s.export_fbx(tmp_path / "b.fbx", include_cameras=True)  # asked for explicitly


# ----------------------------------------------------------------------------- Relocate


def _video(path: Path, size: tuple[int, int], n: int = 4) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, size, isColor=False)
    for i in range(n):
        w.write(np.full((size[1], size[0]), 10 * i, np.uint8))
    w.release()
    return path


def test_relocate_files_refuses_a_video_of_another_size_everywhere(tmp_path):
    from carapost.commands.file import RelocateFiles

    for c in ("cam0", "cam1"):
        _video(tmp_path / f"T_{c}.mkv", (64, 48))
    small = _video(tmp_path / "small.mkv", (32, 24))
    s = Session.import_take(tmp_path / "T_cam0.mkv")
    before = snapshot(s.project)
    with pytest.raises(CommandError, match="32x24 but camera cam1 is 64x48"):
        s.relocate_files({1: small})
    with pytest.raises(CommandError, match="32x24"):
        api.relocate_files(s.project, {"cam1": small})
    with pytest.raises(CommandError, match="32x24"):  # the command they push
        RelocateFiles(s.project, {1: str(small)})
    with pytest.raises(CaraFileError, match="nope.mkv"):
        s.relocate_files({0: tmp_path / "nope.mkv"})
    with pytest.raises(CommandError, match="no camera named"):
        s.relocate_files({"camX": small})
    assert snapshot(s.project) == before and s.history() == []
    other = _video(tmp_path / "other.mkv", (64, 48))
    roundtrip(s, lambda s: s.relocate_files({"cam1": other}))
    assert s.project.take.cameras[1].video_path == str(other)


# ----------------------------------------------------------------------------- Edit


def _ids(s: Session) -> list[int]:
    return [int(i) for i in s.project.points.ids]


def _stick(s: Session) -> None:
    ids = _ids(s)
    s.project.sticks = [Stick(ids[0], ids[2])]


EDITS: dict[str, tuple[Callable[[Session], None] | None, Callable[[Session], object]]] = {
    "create_points": (None, lambda s: s.create_points_from_detections([(15, 0, 7)])),
    "delete_selected": (None, lambda s: s.delete_selected(point_ids=[_ids(s)[1]])),
    "delete_selected_sel": (lambda s: s.select(points=[_ids(s)[3]]),
                            lambda s: s.delete_selected()),
    "split": (None, lambda s: s.split_selected_point(_ids(s)[0])),
    "merge": (None, lambda s: s.merge(point_ids=[_ids(s)[1], _ids(s)[3]])),
    "clear_current": (None, lambda s: s.clear_selected("current", [_ids(s)[0]])),
    "clear_active": (None, lambda s: s.clear_selected("active", [_ids(s)[0]])),
    "clear_frames": (None, lambda s: s.clear_selected((2, 4), [_ids(s)[0]])),
    "clear_active_range": (None, lambda s: s.clear_active_range()),
    "detach_current": (None, lambda s: s.detach_detections("current", cameras=[0],
                                                           point_ids=[_ids(s)[0]])),
    "detach_active": (None, lambda s: s.detach_detections("active", active_camera=1,
                                                          point_ids=[_ids(s)[0]])),
    "increment_offset": (None, lambda s: s.increment_image_sequence_offset([1])),
    "remove_unused": (None, lambda s: s.remove_unused_detections()),
    "remove_interpolated": (None, lambda s: s.remove_interpolated_3d_points([_ids(s)[2]])),
    "rename_point": (None, lambda s: s.rename_point(_ids(s)[1], "Brow_L")),
    "rename_label": (None, lambda s: s.rename_label("Chin", "Jaw")),
    "clear_labels": (None, lambda s: s.clear_all_labels()),
    "delete_labels": (None, lambda s: s.delete_labels(["Brow_L"])),
    "unlabel": (None, lambda s: s.unlabel_selected_points([_ids(s)[0]])),
    "create_stick": (None, lambda s: s.create_stick([_ids(s)[0], _ids(s)[2]])),
    "stick_mesh": (None, lambda s: s.create_stick_mesh()),
    "stick_colour": (_stick, lambda s: s.edit_stick_color([0], (10, 200, 30))),
    "set_property": (None, lambda s: s.set_property("Blob Parameters", "White Min Radius",
                                                    6.0)),
    "set_properties": (None, lambda s: s.set_properties({"export_range": "all",
                                                         "fbx_up_axis": "Z"})),
    "restore_defaults": (lambda s: s.project.properties.update({"export_range": "all"}),
                         lambda s: s.restore_properties_to_defaults()),
    "read_blob_parameters": (
        lambda s: setattr(s.project, "imported_blob_parameters", {"white_min_radius": 7.0}),
        lambda s: s.read_blob_parameters_from_take()),
    "rotate": (None, lambda s: s.rotate_sensors([0], clockwise=False)),
    "active_range": (None, lambda s: s.set_active_range(2, 20)),
    "reset_active": (None, lambda s: s.reset_active_range()),
    "view_range": (None, lambda s: s.set_view_range(3, 9)),
    "default_brim": (None, lambda s: s.initialize_default_brim("2.0")),
}


@pytest.mark.parametrize("name", sorted(EDITS))
def test_edit_methods_make_one_entry_and_undo_exactly(name, rng):
    setup, act = EDITS[name]
    s = Session(make_project(rng))
    if setup is not None:
        setup(s)
    roundtrip(s, act)


def test_file_imports_make_one_entry_and_undo_exactly(tmp_path, rng):
    s = Session(make_project(rng))
    (tmp_path / "l.txt").write_text("Lip_L Lip_R\nChin\n")
    roundtrip(s, lambda s: s.import_labels(tmp_path / "l.txt"))
    assert s.project.labels[-3:] == ["Lip_L", "Lip_R", "Chin - Copy"]  # as the window
    brim = tmp_path / "b.csv"
    brim.write_text("".join(f"B{i},{i},{i * i},{1 + i % 2}\n" for i in range(5)))
    roundtrip(s, lambda s: s.import_brim(brim))
    assert (s.project.points.kind == KIND_BRIM).sum() == 5
    with pytest.raises(CaraFileError, match="must be a .svg or .csv"):
        s.import_brim(tmp_path / "l.txt")
    with pytest.raises(CaraFileError, match="no.xcp"):
        s.import_xcp(tmp_path / "no.xcp")


def test_refusals_name_the_problem_and_change_nothing(rng):
    s = Session(make_project(rng))
    before = snapshot(s.project)
    with pytest.raises(CommandError, match="unknown properties section .Nope."):
        s.set_property("Nope", "x", 1)
    with pytest.raises(CommandError, match="has no property 'nope'"):
        s.set_property("Export", "nope", 1)
    with pytest.raises(CommandError, match="frames must be one of"):
        s.clear_selected("some")
    with pytest.raises(CommandError, match="no image source"):
        s.detect_blobs()
    with pytest.raises(CommandError, match="outside the take"):
        s.current_frame = 99
    with pytest.raises(CommandError, match="no point"):
        s.select(points=[12345])
    with pytest.raises(CommandError, match="contiguous"):
        s.bundle_sequence([1, 3, 4])
    with pytest.raises(CommandError, match="no ROM is loaded"):
        s.initialize_from_rom()
    assert snapshot(s.project) == before and s.history() == []


# ----------------------------------------------------------------------------- Process


def test_process_methods_make_one_entry_and_undo_exactly(synth_take):
    s = Session.import_take(synth_take)
    p = s.project
    assert s.caddies == tuple(tuple(g) for g in p.take.metadata["rig"]["caddies"])
    seen: list[tuple[int, int]] = []

    def progress(done: int, total: int) -> bool:
        seen.append((done, total))
        return True

    with s:
        roundtrip(s, lambda s: s.detect_blobs("current", cameras=[0, 1]))
        s.undo()
        roundtrip(s, lambda s: s.detect_blobs("all", progress=progress))
        assert seen and seen[-1][0] == seen[-1][1] == p.n_frames * p.n_cameras
        roundtrip(s, lambda s: s.solve_brim(frame=0, method="automatic"))
        roundtrip(s, lambda s: s.initialize_3d(frame=0))
        s.current_frame = 0
        roundtrip(s, lambda s: s.track("forwards", use_images=False))
        roundtrip(s, lambda s: s.bundle_current_frame(3))
        roundtrip(s, lambda s: s.bundle_sequence("all"))
        s.current_frame = 5
        roundtrip(s, lambda s: s.track(-1, single_frame=True))
        roundtrip(s, lambda s: s.track_take(frame=0))
    names = [h.description for h in s.history()]
    assert names[0].startswith("Detect Blobs") and names[-1].startswith("Track")
    roundtrip(s, lambda s: s.import_xcp(synth_take.with_suffix(".xcp")))


def test_track_take_gives_the_initialised_frame_a_sigma_and_keeps_its_positions(synth_take):
    """The initialisation measures no sigma; Track Take leaves the initialised frame's
    samples as they were and gives them the tracker's sigma (mm), so no frame of an
    export falls back to the reprojection residual (px)."""
    from carapost.model.project import KIND_FACE, RECON_TRIANGULATED

    s = Session.import_take(synth_take)
    p = s.project
    s.detect_blobs("all")
    s.solve_brim(frame=0, method="automatic")
    s.initialize_3d(frame=0)
    face = p.points.kind == KIND_FACE
    initialised = p.points.positions[0].copy()
    assert np.isnan(p.points.arrays["sigma"][0, face]).all()
    s.track_take(frame=0)
    tri = p.points.recon[:, face] == RECON_TRIANGULATED
    sigma = p.points.arrays["sigma"][:, face]
    assert tri[0].sum() > 50
    assert np.isfinite(sigma[0][tri[0]]).all() and np.isfinite(sigma[tri]).mean() > 0.99
    assert (sigma[tri] > 0).all() and np.median(sigma[0][tri[0]]) < 0.5
    n = initialised.shape[0]
    np.testing.assert_array_equal(p.points.positions[0][:n], initialised)
    s.undo()
    assert np.isnan(p.points.arrays["sigma"][0, face]).all()


def test_cancelled_detection_keeps_the_finished_images(synth_take):
    s = Session.import_take(synth_take)
    calls = []

    def progress(done: int, total: int) -> bool:
        calls.append(done)
        return done < 2

    with s:
        cmd = s.detect_blobs("all", progress=progress)
    assert cmd.cancelled and len(s.history()) == 1
    assert 0 < s.project.detections.counts().astype(bool).sum() < s.project.n_frames * 4


def test_a_job_cancelled_before_it_finished_anything_adds_no_history_entry(synth_take):
    from carapost.commands.results import DetectionsResult

    s = Session.import_take(synth_take)
    with s:
        assert s.apply(DetectionsResult([], [], "Detect Blobs", cancelled=True)) is None
        assert len(s.history()) == 0  # no empty "(cancelled: partial)" entry
        s.detect_blobs("all")
        s.solve_brim(frame=0, method="automatic")
        s.initialize_3d(frame=0)
        s.current_frame = 0
        before = len(s.history())
        # the tracker asks after each frame: cancelling at once keeps the first frame
        cmd = s.track("forwards", use_images=False, progress=lambda d, t: False)
        assert cmd is not None and cmd.cancelled and len(s.history()) == before + 1
        assert cmd.result.result.frames_done >= 1


# ----------------------------------------------------------------------------- caddies


def test_one_definition_of_caddy():
    assert caddies(4) == ((0, 1), (2, 3))
    assert caddies(6) == ((0, 1), (2, 3), (4, 5))  # not halves
    assert caddy_groups(5) == ((0, 1), (2, 3), (4,))
    halves = {"rig": {"caddies": [[0, 1, 2], [3, 4, 5]]}}
    assert caddy_groups(6, halves) == ((0, 1, 2), (3, 4, 5))
    assert caddies(6, halves) == ((0, 1), (1, 2), (3, 4), (4, 5))
    assert caddy_groups(4, {"caddies": [[0, 1], [1, 2]]}) == ((0, 1), (2, 3))  # invalid
    s = Session(copy.deepcopy(new_project(2, 6)))
    assert s.caddies == ((0, 1), (2, 3), (4, 5))


# ----------------------------------------------------------------------------- two steps


def test_two_step_form_is_the_synchronous_method(synth_take):
    """prepare (snapshot) -> compute (any thread) -> apply gives what the one-call
    method gives: the same History entry and bit-identical data."""
    import threading

    from carapost.commands.recipe import Job, Result
    from carapost.session import PROCESS_ACTIONS

    a, b = Session.import_take(synth_take), Session.import_take(synth_take)
    with a, b:
        job = a.prepare("detect_blobs", frames="current")
        assert isinstance(job, Job) and a.history() == []  # nothing changed yet
        out: list[Result] = []
        worker = threading.Thread(target=lambda: out.append(job.compute(None)))
        worker.start()
        worker.join()
        a.apply(out[0])
        b.detect_blobs("current")
        for s in (a, b):
            s.solve_brim(frame=0, method="automatic")
        assert isinstance(a.prepare("initialize_3d", frame=0), Job)
        a.run(a.prepare_initialize_3d(frame=0))
        b.initialize_3d(frame=0)
    assert snapshot(a.project) == snapshot(b.project)
    assert [h.description for h in a.history()] == [h.description for h in b.history()] \
        == ["Detect Blobs [Current Frame]", "Solve Calibration Brim [Automatic] [frame 0]",
            "Initialize 3D [frame 0]"]
    assert all(hasattr(Session, f"prepare_{name}") and hasattr(Session, name)
               for name in PROCESS_ACTIONS)
    with pytest.raises(CommandError, match="not a Process action"):
        a.prepare("merge")
    with pytest.raises(TypeError):
        a.apply("not a result")


def test_open_a_recovered_autosave_stays_unsaved(tmp_path, rng):
    from carapost.io.autosave import autosave_project

    s = Session(make_project(rng))
    path = s.save(tmp_path / "a.cara")
    s.set_active_range(3, 7)
    auto = autosave_project(s.project)
    recovered = Session.open(path, source=auto)
    assert recovered.project.active_range == (3, 7)  # the autosave's data
    assert recovered.project.path == str(path.absolute())  # belongs to the file
    assert recovered.project.modified and not recovered.stack.is_clean
    assert Session.open(path, recover=False).project.active_range != (3, 7)


def test_a_group_of_actions_is_one_history_entry(rng):
    s = Session(make_project(rng))

    def several(s: Session) -> None:
        with s.group("Tidy Up"):
            s.set_active_range(2, 20)
            s.set_property("Blob Parameters", "White Min Radius", 6.0)
            s.rotate_sensors([0], clockwise=False)

    roundtrip(s, several)
    assert s.history()[-1].description == "Tidy Up"


def test_a_group_that_fails_leaves_the_project_as_before(rng):
    s = Session(make_project(rng))
    before = snapshot(s.project)
    with pytest.raises(CommandError), s.group("Half Done"):
        s.set_active_range(2, 20)
        s.set_active_range(50, 10_000)  # refused: no such frame
    assert snapshot(s.project) == before and len(s.history()) == 0
