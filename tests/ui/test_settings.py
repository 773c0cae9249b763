"""User settings (carapost.ui.settings): GUI preferences live here, not in the project."""

from __future__ import annotations

import pytest

from carapost.model.properties import MOVED_TO_USER_SETTINGS, Properties
from carapost.ui import settings as mod


def test_preferences_default_and_persist(private_settings):
    store = mod.make_settings()
    for pref in mod.PREFERENCES:
        assert mod.preference(store, pref.key) == pref.default
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
    assert set(props.preference_editors) == {"show_version_check_dialog",
                                             *mod.DISPLAY_PREFERENCES}
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


def test_font_size_preference_is_a_clamped_whole_number(private_settings):
    store = mod.make_settings()
    assert mod.preference(store, "label_font_size") == 10  # the guide's default
    mod.set_preference(store, "label_font_size", 500)
    assert mod.preference(store, "label_font_size") == 72  # the top of its range
    store.setValue("preferences/label_font_size", "not a number")  # hand-edited file
    assert mod.preference(store, "label_font_size") == 10


def _with_old_display_properties(path, values):
    """Rewrite a saved .cara as an older version wrote it: Display in the properties."""
    import json
    import zipfile

    with zipfile.ZipFile(path) as zf:
        members = {info: zf.read(info.filename) for info in zf.infolist()}
    with zipfile.ZipFile(path, "w") as zf:
        for info, data in members.items():
            if info.filename == "manifest.json":
                manifest = json.loads(data)
                manifest["properties"].update(values)
                data = json.dumps(manifest).encode()
            zf.writestr(info, data)


def _manifest(path):
    import json
    import zipfile

    with zipfile.ZipFile(path) as zf:
        return json.loads(zf.read("manifest.json"))


def test_display_preferences_persist_redraw_and_stay_out_of_the_cara(
        make_window, demo, qtbot, tmp_path):
    """Point label visibility and font size are this user's: set in one window's
    Properties pane they redraw the views, are no History entry, persist for the next
    window, and are not written to the .cara; an older .cara holding them opens without
    error and does not change the user's settings."""
    from tests.ui.test_window import settle

    p, frames = demo
    p.points.labels = [f"M{i:02d}" for i in range(p.n_points)]
    p.labels = list(p.points.labels)
    w = make_window(p, frames)
    w.show()
    w.workspace.set_layout(1)
    w.workspace.containers[0].set_spec("sensor:0")
    w.set_frame(5)
    settle(qtbot, w)
    view = w.workspace.containers[0].view
    assert not [item for item in view._labels if item.isVisible()]  # nothing selected
    pane = w.pane("Properties")
    titles = [pane.tree.topLevelItem(i).text(0) for i in range(pane.tree.topLevelItemCount())]
    assert titles[0] == "Display (this computer)" and "Display" not in titles
    pane.preference_editors["label_font_size"].setValue(18)
    pane.preference_editors["point_labels_all"].setChecked(True)
    settle(qtbot, w)
    shown = [item for item in view._labels if item.isVisible()]
    assert shown and {item.textItem.font().pointSize() for item in shown} == {18}
    assert len(w.stack) == 0 and not w.context.is_modified
    # saved: the take has no Display key
    target = tmp_path / "take.cara"
    w.context.session.save(target)
    saved = _manifest(target)["properties"]
    assert not set(mod.DISPLAY_PREFERENCES) & set(saved)
    assert saved["black_threshold"] == p.properties["black_threshold"]
    # an older file with its own Display values: opens, and the user's values stay
    _with_old_display_properties(target, {"point_labels_all": False,
                                          "label_font_size": 30,
                                          "point_labels_selected": False})
    other = make_window()
    assert other.open_project(str(target)) and other.last_error == ""
    assert other.context.view.label_mode() == (True, True, True, 18)
    editors = other.pane("Properties").preference_editors
    assert editors["label_font_size"].value() == 18 and editors["point_labels_all"].isChecked()
    assert mod.preference(mod.make_settings(), "label_font_size") == 18  # on disk too
    # saving the older file drops the keys it held
    other.context.session.save(target)
    assert not set(mod.DISPLAY_PREFERENCES) & set(_manifest(target)["properties"])
