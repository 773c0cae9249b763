"""User settings (carapost.ui.settings): GUI preferences live here, not in the project."""

from __future__ import annotations

import pytest

from carapost.model.properties import MOVED_TO_USER_SETTINGS, Properties
from carapost.ui import settings as mod


def test_preferences_default_and_persist(private_settings):
    store = mod.make_settings()
    for pref in mod.PREFERENCES:
        assert mod.preference(store, pref.key) is pref.default
    mod.set_preference(store, "show_version_check_dialog", False)
    store.sync()
    again = mod.make_settings()  # a new store reads the INI file back
    assert mod.preference(again, "show_version_check_dialog") is False
    assert mod.preference(again, "tracker_update_2d_view_every_frame") is False
    with pytest.raises(KeyError):
        mod.preference(again, "black_threshold")
    with pytest.raises(KeyError):
        mod.set_preference(again, "black_threshold", True)


def test_preferences_are_the_keys_moved_out_of_the_project():
    assert {p.key for p in mod.PREFERENCES} == MOVED_TO_USER_SETTINGS
    assert not MOVED_TO_USER_SETTINGS & set(Properties().keys())


def test_preference_defaults_agree_with_the_guide():
    """The guide's Show Again Flags (and the Tracker pane's display switches) by label."""
    import json
    from pathlib import Path

    data = Path(__file__).resolve().parents[1] / "data" / "guide_defaults.json"
    guide = json.loads(data.read_text(encoding="utf-8"))["sections"]
    by_label = {p.label: p for p in mod.PREFERENCES}
    for name, entry in guide["Show Again Flags"].items():
        assert by_label[name].default is entry["default"]
    for name in ("Update Timeline Every Frame", "Update 2D View Every Frame"):
        assert guide["Tracker pane"][name]["default"] is None  # the guide gives none
        assert "our choice" in by_label[name].help


def test_preferences_are_shown_per_computer_and_are_no_history_entry(make_window, demo):
    """The Properties pane shows the Show Again Flags and the Tracker pane its display
    switches (the guide's places), marked as this computer's; editing one writes the
    user settings, never the project or its History."""
    p, frames = demo
    w = make_window(p, frames)
    props = w.pane("Properties")
    assert set(props.preference_editors) == {"show_version_check_dialog"}
    tracker = w.pane("Tracker").settings
    assert set(tracker.preference_editors) == {"tracker_update_timeline_every_frame",
                                               "tracker_update_2d_view_every_frame"}
    titles = {props.tree.topLevelItem(i).text(0) for i in range(props.tree.topLevelItemCount())}
    assert "Show Again Flags (this computer)" in titles
    before = dict(p.properties.items())
    box = tracker.preference_editors["tracker_update_2d_view_every_frame"]
    assert not box.isChecked()  # the default
    box.setChecked(True)
    props.preference_editors["show_version_check_dialog"].setChecked(False)
    store = w.context.settings
    assert mod.preference(store, "tracker_update_2d_view_every_frame") is True
    assert mod.preference(store, "show_version_check_dialog") is False
    assert len(w.stack) == 0 and not w.context.is_modified
    assert dict(p.properties.items()) == before
    again = make_window(p, frames)  # a new window shows what this computer keeps
    assert again.pane("Tracker").settings.preference_editors[
        "tracker_update_2d_view_every_frame"].isChecked()


@pytest.mark.parametrize("follow", [False, True])
def test_update_2d_view_every_frame_makes_the_views_follow_tracking(make_window, qtbot,
                                                                    synth_take, follow):
    from tests.ui.test_one_path import initialised_session

    s = initialised_session(synth_take)
    p = s.project
    w = make_window(p)
    mod.set_preference(w.context.settings, "tracker_update_2d_view_every_frame", follow)
    shown: list[int] = []
    p.events.subscribe(lambda change: "current_frame" in change.parts
                       and shown.append(p.current_frame))
    w.set_frame(0)
    shown.clear()
    w.action("process.track_fwd_seq").trigger()
    qtbot.waitUntil(lambda: not w.runner.busy, timeout=60_000)
    assert w.last_error == "" and w.stack.undo_text().startswith("Track Forwards")
    if follow:  # the views went through the frames as they were tracked
        assert shown == sorted(shown) and len(set(shown)) >= 3
        assert p.current_frame == p.n_frames - 1
    else:
        assert shown == [] and p.current_frame == 0
