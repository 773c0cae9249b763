"""Opening a take in a window on screen draws it in slices: each camera view and pane
in an event-loop turn of its own, each first image in a turn of its own, and any input
or later change draws the rest first (`carapost.ui.opening`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QEvent, Qt
from PySide6.QtGui import QKeyEvent
from PySide6.QtWidgets import QApplication

from carapost.model.project import new_project
from carapost.session import Session
from carapost.ui.opening import OpenSlices

W, H, N, CAMERAS = 160, 120, 30, 4


def _take(folder, name: str, shade: int):
    """A project of four cameras with FFV1 videos, and the images they hold."""
    p = new_project(N, CAMERAS, image_size=(W, H))
    refs = []
    for c, cam in enumerate(p.take.cameras):
        path = folder / f"{name}_cam{c}.mkv"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (W, H),
                                 False)
        frames = []
        for f in range(N):
            img = np.full((H, W), shade, np.uint8)
            cv2.circle(img, (20 + 3 * f, 30 + 20 * c), 6, 255 - shade, -1)
            frames.append(img)
            writer.write(img)
        writer.release()
        cam.video_path = str(path)
        refs.append(frames)
    return p, refs


def _sensors(w):
    return sorted((v for v in w.all_views() if v.kind == "sensor"), key=lambda v: v.camera)


@pytest.fixture
def shown(make_window, tmp_path, qtbot):
    """A window on screen that has shown a first take (its views were drawn once)."""
    w = make_window()
    w.show()
    qtbot.waitExposed(w)
    p, refs = _take(tmp_path, "first", 60)
    w.context.set_session(Session(p))
    qtbot.waitUntil(lambda: all(v.image_frame == 0 for v in _sensors(w)), timeout=10000)
    qtbot.waitUntil(lambda: w.context.view.opening.pending == 0, timeout=10000)
    return w


def test_each_view_and_pane_is_drawn_in_a_turn_of_its_own(shown, tmp_path, qtbot):
    w = shown
    opening = w.context.view.opening
    p, refs = _take(tmp_path, "second", 200)
    p.set_current_frame(11)
    w.context.set_session(Session(p))
    views = _sensors(w)
    # nothing of the new take is drawn in the call itself: it is all waiting for turns
    assert opening.pending >= len(views) + 2
    assert all(v.image_frame != 11 for v in views)
    # a view whose image lands runs its slice out of turn, in the delivery's own event
    # (on a loaded machine that event and the slices' timer can be in one
    # processEvents call): counted apart
    out_of_turn = []
    run_now = opening.run

    def run(key):
        done = run_now(key)
        out_of_turn.append(done)
        return done

    opening.run = run
    runs = []
    while opening.pending:
        before, early = len(opening.ran), sum(out_of_turn)
        QApplication.processEvents()
        runs.append(len(opening.ran) - before - (sum(out_of_turn) - early))
        assert len(runs) < 500, "the opening never finished"
    assert max(runs) == 1  # one slice per event-loop turn, never two
    assert all(len(keys) == 1 for keys in opening.ran)
    ran = [keys[0] for keys in opening.ran]
    panes = {w.pane("Labelling"), w.pane("Selected Point"), w.pane("Properties")}
    for pane in panes:
        assert ran.count(pane) == 1
    # a view is redrawn once, and when its image landed after that, the image is shown
    # in a slice of its own
    for v in views:
        assert 1 <= ran.count(v) <= 2
    # the camera views come before the panes
    assert max(ran.index(v) for v in views) < min(ran.index(pn) for pn in panes)
    qtbot.waitUntil(lambda: all(v.image_frame == 11 for v in views), timeout=10000)
    for v in views:
        np.testing.assert_array_equal(v._current_image, refs[v.camera][11])
    assert w.pane("Labelling").ctx.project is p


def test_input_during_the_opening_draws_the_rest_first(shown, tmp_path, qtbot):
    w = shown
    opening = w.context.view.opening
    p, refs = _take(tmp_path, "second", 200)
    p.set_current_frame(5)
    w.context.set_session(Session(p))
    assert opening.pending
    # a key press reaches no widget before every view and pane shows the new take
    press = QKeyEvent(QEvent.Type.KeyPress, Qt.Key.Key_F35, Qt.KeyboardModifier.NoModifier)
    QApplication.sendEvent(w.workspace, press)
    assert opening.pending == 0
    assert all(v._drawn_frame == 5 for v in _sensors(w))
    # a change made after the opening is shown on a window drawn from the new take
    p2, _ = _take(tmp_path, "third", 120)
    w.context.set_session(Session(p2))
    assert opening.pending
    p2.set_selection(cameras=[1])
    w.flush()
    assert opening.pending == 0
    assert all(v._drawn_frame == 0 for v in _sensors(w))
    assert "selected" in _sensors(w)[1].header.text()


def test_a_frame_change_during_the_opening_is_left_to_the_pending_redraws(
        shown, tmp_path, qtbot):
    w = shown
    opening = w.context.view.opening
    p, refs = _take(tmp_path, "second", 200)
    w.context.set_session(Session(p))
    pending = opening.pending
    # a jump made by a script (no input): the views not yet redrawn show it when their
    # turn comes, nothing is redrawn twice or all at once
    w.set_frame(9)
    w.flush()
    assert opening.pending == pending
    qtbot.waitUntil(lambda: opening.pending == 0, timeout=10000)
    views = _sensors(w)
    assert all(v._drawn_frame == 9 for v in views)
    qtbot.waitUntil(lambda: all(v.image_frame == 9 for v in views), timeout=10000)
    for v in views:
        np.testing.assert_array_equal(v._current_image, refs[v.camera][9])


def test_a_hidden_window_is_drawn_at_once(make_window, tmp_path):
    w = make_window()
    p, _ = _take(tmp_path, "hidden", 90)
    p.set_current_frame(3)
    w.context.set_session(Session(p))
    assert w.context.view.opening.pending == 0
    assert all(v._drawn_frame == 3 for v in _sensors(w))


def test_first_images_jump_the_queue_and_parts_of_a_slice_run_together(qtbot):
    slices = OpenSlices()
    calls: list[str] = []
    slices.begin(visible=True)
    for key in ("v0", "v1", "pane"):
        assert slices.defer(key, lambda k=key: calls.append(f"fit {k}"), "fit")
    for key in ("v0", "v1", "pane"):
        slices.defer(key, lambda k=key: calls.append(f"draw {k}"))
    slices.defer("v0", lambda: calls.append("draw v0 again"))  # replaces the earlier draw
    slices.start(images=["v0", "v1"])
    assert calls == []
    # v1's image landed: its slice runs next, whole; a view already drawn gets the image
    # in a slice of its own
    assert slices.deliver("v1", lambda: calls.append("image v1"))
    slices._next()
    assert calls == ["fit v1", "draw v1"]
    slices._next()
    assert calls[2:] == ["fit v0", "draw v0 again"]
    assert slices.deliver("v0", lambda: calls.append("image v0"))
    assert not slices.deliver("v0", lambda: calls.append("late"))  # only the first image
    slices.flush()
    assert calls[4:] == ["image v0", "fit pane", "draw pane"]
    assert slices.pending == 0
    assert not slices.defer("v0", lambda: None)  # not collecting: the caller draws now


def test_a_take_opened_before_the_last_one_is_drawn_is_drawn_once(shown, tmp_path, qtbot):
    w = shown
    opening = w.context.view.opening
    p1, _ = _take(tmp_path, "second", 200)
    p2, refs = _take(tmp_path, "third", 120)
    p2.set_current_frame(4)
    w.context.set_session(Session(p1))
    w.context.set_session(Session(p2))  # before any slice of the first one ran
    assert opening.ran == []  # nothing of the first one was redrawn meanwhile
    qtbot.waitUntil(lambda: opening.pending == 0, timeout=10000)
    views = _sensors(w)
    qtbot.waitUntil(lambda: all(v.image_frame == 4 for v in views), timeout=10000)
    for v in views:
        np.testing.assert_array_equal(v._current_image, refs[v.camera][4])
    assert w.pane("Labelling").ctx.project is p2
