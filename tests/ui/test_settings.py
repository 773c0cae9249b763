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
