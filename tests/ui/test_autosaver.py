"""The window's autosave copy is written off the GUI thread, and never half.

The copy is written on a worker thread to a ``.partial`` file, then moved into place
on the GUI thread, unless the project changed meanwhile (the copy could hold half an
edit) or was saved or discarded; the previous copy then stays as it was.
"""

import threading
from pathlib import Path

from carapost.io.autosave import autosave_path
from carapost.io.cara import load_project, save_project
from carapost.ui.autosaver import PARTIAL_SUFFIX
from carapost.ui.handlers import file as file_menu
from tests.fuzz.harness import _small_project


def _saved_window(make_window, tmp_path: Path):
    path = tmp_path / "take.cara"
    save_project(_small_project(), path)
    w = make_window()
    assert file_menu.open_project(w.context, str(path))
    return w, path


def _held_writer(monkeypatch):
    """Make the autosave's writer wait for ``release`` (and say which thread wrote)."""
    import carapost.io.cara as cara

    release, entered = threading.Event(), threading.Event()
    threads: list[str] = []
    real = cara.save_project

    def held(project, path, *, autosave=False):
        threads.append(threading.current_thread().name)
        entered.set()
        assert release.wait(30)
        return real(project, path, autosave=autosave)

    monkeypatch.setattr(cara, "save_project", held)
    return release, entered, threads


def test_the_copy_is_written_on_a_worker_and_moved_into_place(make_window, tmp_path,
                                                              monkeypatch, qtbot):
    w, path = _saved_window(make_window, tmp_path)
    release, entered, threads = _held_writer(monkeypatch)
    w.context.session.set_active_range(1, 4)
    file_menu.autosave(w.context)
    # the GUI thread is back at once: the writer waits, nothing is in place yet
    assert entered.wait(10) and w.context.autosaver.running
    assert not autosave_path(path).exists()
    file_menu.autosave(w.context)  # a second tick while one is written starts nothing
    release.set()
    qtbot.waitUntil(lambda: not w.context.autosaver.running, timeout=30_000)
    assert threads == ["carapost-autosave"]
    copy = autosave_path(path)
    assert copy.exists() and not copy.with_name(copy.name + PARTIAL_SUFFIX).exists()
    assert load_project(copy).active_range == (1, 4)
    assert w.project.session_autosave == copy


def test_a_change_during_the_write_throws_the_copy_away(make_window, tmp_path,
                                                        monkeypatch, qtbot):
    w, path = _saved_window(make_window, tmp_path)
    w.context.session.set_active_range(1, 4)
    file_menu.autosave(w.context)
    w.context.autosaver.wait()
    copy = autosave_path(path)
    before = copy.read_bytes()
    release, entered, _ = _held_writer(monkeypatch)
    w.context.session.set_active_range(2, 5)
    file_menu.autosave(w.context)
    assert entered.wait(10)
    w.context.session.set_active_range(0, 3)  # an edit while the copy is written
    w.set_frame(2)  # moving to another frame changes nothing that is saved
    release.set()
    qtbot.waitUntil(lambda: not w.context.autosaver.running, timeout=30_000)
    # the half-new copy is gone; the last whole one stays
    assert copy.read_bytes() == before
    assert not copy.with_name(copy.name + PARTIAL_SUFFIX).exists()
    # the next tick writes the project as it is now
    monkeypatch.undo()
    file_menu.autosave(w.context)
    w.context.autosaver.wait()
    assert load_project(copy).active_range == (0, 3)


def test_a_copy_being_written_when_the_changes_are_discarded_is_not_kept(
        make_window, tmp_path, monkeypatch, qtbot):
    w, path = _saved_window(make_window, tmp_path)
    release, entered, _ = _held_writer(monkeypatch)
    w.context.session.set_active_range(1, 4)
    file_menu.autosave(w.context)
    assert entered.wait(10)
    w.dialogs.ask_save_answers.append("discard")
    assert file_menu.maybe_save(w.context)
    release.set()
    qtbot.waitUntil(lambda: not w.context.autosaver.running, timeout=30_000)
    copy = autosave_path(path)
    assert not copy.exists() and not copy.with_name(copy.name + PARTIAL_SUFFIX).exists()
