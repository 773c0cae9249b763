"""One path per action: the window, ``carapost gui`` and scripts build and write the same.

* ``carapost gui take.json`` (ui/app.py's loader), File > Import and
  `Session.import_take` give equal projects.
* File > Export C3D / FBX honour the Export section of the Properties pane (read back
  with the independent ``c3d`` reader and with ufbx).
* Relocate Files refuses a video of another image size from the api, the Session and
  Edit > Relocate Files.
* Process items run on the worker through the recipe (``session.prepare``, compute,
  ``session.apply``), make one History entry and undo to bit identity.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from carapost import Session, api
from carapost.commands.recipe import Result
from carapost.commands.stack import CommandError
from carapost.model.project import KIND_BRIM
from carapost.ui.app import open_path
from tests.test_session import _video, export_project, project_state, read_back, snapshot
from tests.ufbx_child import call_in_child


def _idle(qtbot, w, timeout=60_000) -> None:
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=timeout)
    assert w.last_error == "", w.last_error


# ------------------------------------------------------------------------------ import


def test_gui_loader_file_import_and_session_build_equal_projects(make_window, qtbot,
                                                                  synth_take):
    by_gui = make_window()
    assert open_path(by_gui, str(synth_take))  # what `carapost gui take.json` runs
    _idle(qtbot, by_gui)
    by_menu = make_window()
    by_menu.dialogs.open_paths.append(str(synth_take))
    by_menu.action("file.import_take").trigger()
    _idle(qtbot, by_menu)
    by_script = Session.import_take(synth_take)
    expect = project_state(by_script.project)
    assert project_state(by_gui.project) == expect == project_state(by_menu.project)
    assert (by_gui.project.points.kind == KIND_BRIM).sum() > 0  # the take's brim model
    for w in (by_gui, by_menu):  # a fresh History, images of the take, its own Session
        assert len(w.stack) == 0 and w.context.frames.has_images
        assert w.context.session.project is w.project and w.stack is w.context.session.stack


# ------------------------------------------------------------------------------ export


def _set_in_pane(w, key: str, value) -> None:
    """Change a property with its editor in the Properties pane."""
    editor = w.pane("Properties").editors[key]
    if isinstance(value, bool):
        editor.setChecked(value)
    else:
        editor.setCurrentText(value)
    w.flush()
    assert w.project.properties[key] == value


def test_gui_export_c3d_honours_export_range_and_include_brim(make_window, qtbot, tmp_path):
    s = export_project()
    p = s.project
    w = make_window(p)
    w.context.session.set_active_range(4, 12)
    _set_in_pane(w, "export_range", "all")
    _set_in_pane(w, "export_range", "active")
    _set_in_pane(w, "export_include_brim_points", True)
    path = tmp_path / "gui.c3d"
    w.dialogs.save_paths.append(str(path))
    w.action("file.export_c3d").trigger()
    _idle(qtbot, w)
    labels, first, X = read_back(path)
    assert labels == ["A", "B", "C", "Brim01", "Brim02"]  # brim points included
    assert first == 5 and X.shape == (9, 5, 3)  # frames 4-12 only
    np.testing.assert_allclose(X, p.points.positions[4:13], atol=1e-4)
    # the same file as the script's export with the same properties
    assert read_back(w.context.session.export_c3d(tmp_path / "script.c3d"))[0] == labels
    _set_in_pane(w, "export_include_brim_points", False)
    _set_in_pane(w, "export_range", "all")
    w.dialogs.save_paths.append(str(tmp_path / "all.c3d"))
    w.action("file.export_c3d").trigger()
    _idle(qtbot, w)
    labels, first, X = read_back(tmp_path / "all.c3d")
    assert labels == ["A", "B", "C"] and first == 1 and X.shape == (20, 3, 3)


def _fbx_facts(path: Path) -> tuple[bool, list[str], list[str]]:
    """(up axis is +Z, camera names, node names) of an FBX file, read with ufbx (in a
    child process: `tests.ufbx_child`)."""
    pytest.importorskip("ufbx")
    return call_in_child(_read_fbx_facts, path)


def _read_fbx_facts(path: Path) -> tuple[bool, list[str], list[str]]:
    import ufbx

    scene = ufbx.load_file(str(path), strict=True)
    axes = scene.settings.axes
    z_up = bool(axes.up == ufbx.CoordinateAxis.POSITIVE_Z)
    cams = list(scene.cameras)
    nodes = list(scene.nodes)
    return z_up, sorted(str(c.name) for c in cams), [str(n.name) for n in nodes]


def test_gui_export_fbx_honours_up_axis_and_cameras(make_window, qtbot, tmp_path,
                                                    synth_take):
    s = Session.import_take(synth_take)  # XCP cameras and the take's brim points
    w = make_window(s.project)
    _set_in_pane(w, "export_include_brim_points", True)
    _set_in_pane(w, "fbx_up_axis", "Z")
    _set_in_pane(w, "fbx_include_cameras", True)
    w.dialogs.save_paths.append(str(tmp_path / "z.fbx"))
    w.action("file.export_fbx").trigger()
    _idle(qtbot, w)
    z_up, cams, nodes = _fbx_facts(tmp_path / "z.fbx")
    names = sorted(c.name for c in s.project.take.cameras)
    assert z_up and cams == names
    assert {lab for lab in s.project.points.labels if lab} <= set(nodes)  # brim included
    _set_in_pane(w, "fbx_up_axis", "Y")
    _set_in_pane(w, "fbx_include_cameras", False)
    w.dialogs.save_paths.append(str(tmp_path / "y.fbx"))
    w.action("file.export_fbx").trigger()
    _idle(qtbot, w)
    z_up, cams, _ = _fbx_facts(tmp_path / "y.fbx")
    assert not z_up and cams == []


# ------------------------------------------------------------------------------ relocate


def test_relocate_refuses_a_video_of_another_size_from_every_entry_point(make_window, qtbot,
                                                                         tmp_path):
    for c in ("cam0", "cam1"):
        _video(tmp_path / f"T_{c}.mkv", (64, 48))
    small = _video(tmp_path / "small.mkv", (32, 24))
    w = make_window()
    w.dialogs.open_paths.append(str(tmp_path / "T_cam0.mkv"))
    w.action("file.import_take").trigger()
    _idle(qtbot, w)
    p = w.project
    assert p.n_cameras == 2
    before = snapshot(p)
    with pytest.raises(CommandError, match="32x24 but camera cam1 is 64x48"):
        api.relocate_files(p, {"cam1": small})
    with pytest.raises(CommandError, match="32x24 but camera cam1 is 64x48"):
        w.context.session.relocate_files({1: small})
    # Edit > Relocate Files: the dialog keeps camera 0 and answers the small video for 1
    w.dialogs.open_paths += [None, str(small)]
    w.action("edit.relocate").trigger()
    assert "32x24 but camera cam1 is 64x48" in w.last_error
    assert snapshot(p) == before and len(w.stack) == 0
    other = _video(tmp_path / "other.mkv", (64, 48))
    w.context.last_error = ""
    w.dialogs.open_paths += [None, str(other)]
    w.action("edit.relocate").trigger()
    assert w.last_error == "" and p.take.cameras[1].video_path == str(other)
    assert len(w.stack) == 1 and w.stack.undo_text() == "Relocate Files"


# ------------------------------------------------------------------------------ process


def initialised_session(take: Path) -> Session:
    """A session on the take with blobs, a solved brim and Initialize 3D at frame 0
    (the state tracking starts from), made by script."""
    s = Session.import_take(take)
    with s:
        s.detect_blobs("all")
        s.solve_brim(frame=0, method="automatic")
        s.initialize_3d(frame=0)
    s.current_frame = 0
    return s


def test_process_items_run_the_recipe_on_the_worker(make_window, qtbot, synth_take,
                                                    monkeypatch):
    p = initialised_session(synth_take).project
    w = make_window(p)
    session = w.context.session
    computed_on: list[threading.Thread] = []
    applied: list[tuple[threading.Thread, object]] = []
    real_apply = Session.apply

    def spy_apply(self, result):
        applied.append((threading.current_thread(), result))
        return real_apply(self, result)

    monkeypatch.setattr(Session, "apply", spy_apply)
    real_prepare = Session.prepare

    def spy_prepare(self, action, /, **options):
        job = real_prepare(self, action, **options)
        compute = job.compute

        def on_worker(progress=None):
            computed_on.append(threading.current_thread())
            return compute(progress)

        job.compute = on_worker
        return job

    monkeypatch.setattr(Session, "prepare", spy_prepare)

    for item, what in (("process.blobs_current", "Detect Blobs [Current Frame]"),
                       ("process.track_fwd_one", "Track Forwards [Single Frame]")):
        before = snapshot(p)
        n = len(w.stack)
        w.action(item).trigger()
        assert w.runner.busy  # the window goes on while the job computes
        _idle(qtbot, w)
        assert computed_on[-1] is not threading.main_thread()
        assert applied[-1][0] is threading.main_thread()
        assert len(w.stack) == n + 1 and w.stack.undo_text().startswith(what)
        assert isinstance(applied[-1][1], Result) and session.history()[-1].description \
            == w.stack.undo_text()
        after = snapshot(p)
        assert after != before
        w.action("edit.undo").trigger()
        assert snapshot(p) == before  # bit identity
        w.action("edit.redo").trigger()
        assert snapshot(p) == after
    assert len(applied) == len(computed_on) == 2
