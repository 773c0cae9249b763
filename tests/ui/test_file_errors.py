"""File > Open, Import Camera Files and Process > Load ROM over damaged files: the
CaraFileError message (file and problem) in a box and in the log, nothing else changes."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import pytest

from tests.fuzz.damaged import damaged_files
from tests.fuzz.harness import _small_project, take_base_files

pytestmark = pytest.mark.gui


@pytest.fixture(scope="module")
def damaged(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, Path]]:
    return damaged_files(tmp_path_factory.mktemp("damaged"))


def _projects(damaged) -> list[Path]:
    return [p for reader, p in damaged.values() if reader == "cara_open"]


def test_open_and_load_rom_show_the_message(make_window, damaged, caplog) -> None:
    w = make_window(_small_project())
    before = w.project
    for path in _projects(damaged):
        for action in ("file.open", "process.load_rom"):
            w.dialogs.errors.clear()
            caplog.clear()
            w.dialogs.open_paths.append(str(path))
            with caplog.at_level(logging.ERROR):
                w.action(action).trigger()
            assert len(w.dialogs.errors) == 1, (action, path.name)
            title, text = w.dialogs.errors[0]
            assert text.startswith(f"{path}: ") and len(text) > len(str(path)) + 10
            assert any(str(path) in r.getMessage() for r in caplog.records), action
            assert w.project is before and w.project.rom is None


def test_import_shows_the_message_of_each_damaged_take_file(make_window, damaged, qtbot,
                                                            tmp_path: Path) -> None:
    base = take_base_files(tmp_path / "_seeds")
    replace = {"take.json": "take_json_nested", "take.xcp": "xcp_frame_2e63",
               "take_brim.csv": "brim_csv_huge_field", "take_cam0.mkv": "video_garbage"}
    w = make_window()
    for k, (name, bad) in enumerate(replace.items()):
        folder = tmp_path / f"take{k}"
        folder.mkdir()
        for fname, raw in base.items():
            (folder / fname).write_bytes(raw)
        shutil.copy(damaged[bad][1], folder / name)
        w.dialogs.errors.clear()
        w.dialogs.open_paths.append(str(folder / "take_cam1.mkv"))
        w.action("file.import_take").trigger()
        qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
        assert len(w.dialogs.errors) == 1, name
        assert str(folder / name) in w.dialogs.errors[0][1], w.dialogs.errors[0]
        assert w.project.n_frames == 0  # no half-imported take


def test_a_never_saved_project_is_autosaved_and_offered_after_a_crash(
        make_window, tmp_path: Path, monkeypatch) -> None:
    from carapost.ui.handlers import file as file_menu

    monkeypatch.setenv("CARAPOST_AUTOSAVE_DIR", str(tmp_path / "auto"))
    w = make_window(_small_project())
    w.context.session.set_active_range(1, 4)  # an unsaved change
    file_menu.autosave(w.context)
    w.context.autosaver.wait()  # written on a thread of its own
    copies = list((tmp_path / "auto").glob("*.cara"))
    assert len(copies) == 1
    # the window "crashed": a new one offers the copy and opens it unsaved, untitled
    w2 = make_window()
    w2.dialogs.confirm_answers.append(True)
    assert file_menu.offer_untitled_recovery(w2.context)
    assert w2.project.path is None and w2.project.active_range == (1, 4)
    assert w2.context.is_modified
    # leaving it without saving removes the copy: it is not offered again
    w2.dialogs.ask_save_answers.append("discard")
    assert file_menu.maybe_save(w2.context)
    assert not copies[0].exists()
    assert not file_menu.offer_untitled_recovery(make_window().context)


def test_discarding_a_saved_project_removes_the_autosave_this_session_wrote(
        make_window, tmp_path: Path) -> None:
    from carapost.io.autosave import autosave_path
    from carapost.io.cara import save_project
    from carapost.ui.handlers import file as file_menu

    path = tmp_path / "take.cara"
    save_project(_small_project(), path)
    # a copy left by an earlier crash, declined at open: this session did not write it
    stale = autosave_path(path)
    stale.write_bytes(b"left by a crash")
    w = make_window()
    w.dialogs.confirm_answers.append(False)
    assert file_menu.open_project(w.context, str(path))
    assert file_menu.maybe_save(w.context)  # nothing changed: the crash's copy stays
    assert stale.read_bytes() == b"left by a crash"
    w.context.session.set_active_range(1, 4)
    file_menu.autosave(w.context)
    w.context.autosaver.wait()  # written on a thread of its own
    assert stale.read_bytes() != b"left by a crash"  # now the session's own copy
    w.dialogs.ask_save_answers.append("discard")
    assert file_menu.maybe_save(w.context)
    assert not stale.exists()  # discarded changes are not offered on the next open


def test_import_xcp_brim_and_labels_show_the_message(make_window, damaged, caplog) -> None:
    w = make_window(_small_project())
    before = (w.project.labels[:], w.project.calibration.intrinsics, len(w.stack))
    cases = [("file.import_xcp", n) for n in damaged if damaged[n][0] == "xcp"]
    cases += [("file.import_labels_cara", n) for n in damaged if damaged[n][0] == "cara_labels"]
    cases += [("file.import_brim", n) for n in damaged if damaged[n][0] == "brim_svg"]
    assert len(cases) >= 5
    for action, name in cases:
        path = damaged[name][1]
        w.dialogs.errors.clear()
        w.dialogs.open_paths.append(str(path))
        with caplog.at_level(logging.ERROR):
            w.action(action).trigger()
        assert len(w.dialogs.errors) == 1, (action, name)
        assert w.dialogs.errors[0][1].startswith(f"{path}: "), w.dialogs.errors[0]
        assert (w.project.labels, w.project.calibration.intrinsics, len(w.stack)) == before
