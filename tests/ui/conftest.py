"""Fixtures for the GUI tests: offscreen Qt, private settings, a hidden main window."""

from __future__ import annotations

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import logging
from functools import partial
from pathlib import Path

import pytest
from PySide6.QtWidgets import QApplication

# every test in this folder gets the `gui` marker from tests/conftest.py
# (pytest_collection_modifyitems): a `pytestmark` in a conftest marks nothing


class FakeDialogs:
    """Answers every question of the window from queues set by the test."""

    def __init__(self) -> None:
        self.open_paths: list[str | None] = []
        self.save_paths: list[str | None] = []
        self.ask_save_answers: list[str] = []
        self.confirm_answers: list[bool] = []
        self.ints: list[int | None] = []
        self.texts: list[str | None] = []
        self.errors: list[tuple[str, str]] = []
        self.infos: list[tuple[str, str]] = []

    def open_file(self, title, filters, folder=False):
        return self.open_paths.pop(0) if self.open_paths else None

    def save_file(self, title, filters, default=""):
        return self.save_paths.pop(0) if self.save_paths else None

    def ask_save(self, name):
        return self.ask_save_answers.pop(0) if self.ask_save_answers else "discard"

    def confirm(self, title, text):
        return self.confirm_answers.pop(0) if self.confirm_answers else False

    def get_int(self, title, label, value, lo, hi):
        return self.ints.pop(0) if self.ints else None

    def get_text(self, title, label, value=""):
        return self.texts.pop(0) if self.texts else None

    def get_completed_text(self, title, label, value, completions):
        self.completions = list(completions)
        return self.texts.pop(0) if self.texts else None

    def get_colour(self, title):
        return (255, 0, 0)

    def info(self, title, text):
        self.infos.append((title, text))

    def error(self, title, text):
        self.errors.append((title, text))


@pytest.fixture(autouse=True)
def private_settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """QSettings in a temporary folder: the user's own settings are never touched."""
    folder = tmp_path / "settings"
    monkeypatch.setenv("CARAPOST_SETTINGS_DIR", str(folder))
    # no detector processes for every take a test opens (the tests that need them ask)
    from carapost.ui.settings import make_settings, set_preference

    set_preference(make_settings(), "start_detector_after_import", False)
    return folder


@pytest.fixture
def make_window(qtbot):
    """Factory of hidden main windows with fake dialogs; checks nothing leaks."""
    from carapost.ui.mainwindow import MainWindow

    made = []
    handlers_before = list(logging.getLogger().handlers)

    def make(project=None, frames=None):
        w = MainWindow(restore=True)
        w.dialogs = FakeDialogs()
        w.strict = True  # a menu handler that raises fails the test
        qtbot.addWidget(w)
        w.resize(1400, 900)
        if project is not None:
            w.set_project(project, frames)
        made.append(w)
        return w

    yield make
    for w in made:
        w.runner.cancel()
        assert w.runner.wait(20), "a worker thread outlived its window"
        w.shutdown()
        w.close()
        assert not w.runner.busy
    QApplication.processEvents()
    assert logging.getLogger().handlers == handlers_before, "a log handler leaked"
    visible = [t for t in QApplication.topLevelWidgets() if t.isVisible()
               and t.metaObject().className() not in ("QMenu",)]
    for t in visible:  # non-modal message boxes a test opened
        t.close()


@pytest.fixture
def demo():
    """A small tracked-looking project and its dot images."""
    from carapost.synth.demo_project import demo_project, render_dots
    from carapost.ui.frames import ArrayFrameSource

    p = demo_project(60, 24, 4, size=(640, 360), seed=1)
    return p, ArrayFrameSource(partial(render_dots, p))
