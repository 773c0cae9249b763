"""Every section, name, default and unit of the registry agrees with the reference guide.

The guide's tables are read by ``scripts/extract_guide_defaults.py`` into
``tests/data/guide_defaults.json`` (names and values only). The registry is checked
against that file in every checkout; where the guide itself is present (it lives
outside the repository), the file is also checked against the guide.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from carapost.model.properties import SECTIONS, specs_in_section

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "guide_defaults.json"

#: Guide sections that are not Properties sections of ours, and why.
NOT_OURS = {
    "Shortcut": "lists keyboard shortcuts only (they are in carapost.ui.actions)",
    "Show Again Flags": "GUI preferences: user settings (carapost.ui.settings), not project "
                        "properties; tests/ui/test_settings.py checks their defaults",
    "Display": "point label visibility and font size are about the user, not the take: "
               "user settings (carapost.ui.settings); checked below against PREFERENCES",
}
#: Guide sections that are user settings (carapost.ui.settings.PREFERENCES), by label.
USER_SETTINGS = ("Display", "Show Again Flags")
#: Where a guide table lands in the registry when the name differs.
SECTION_OF = {"Tracker pane": "Target Tracker"}
#: Our sections the guide does not have, and why.
OURS_ONLY = {"Triangulation Parameters": "our own triangulation settings (FreeMoCap-style)",
             "Clean-up Parameters": "our own gap-filling method, filtering and Find Problems "
                                    "settings",
             "Label From Template Parameters": "Label From Template is beyond the guide"}
#: Guide rows that are more than one property, or not a property at all.
LABELS_OF = {
    ("Tracker pane", "Stop after N Frames, N="): ("Stop after N Frames", "N"),
    ("Tracker pane", "Update Timeline Every Frame"): (),  # user setting (carapost.ui.settings)
    ("Tracker pane", "Update 2D View Every Frame"): (),  # user setting
}
#: Guide sections whose options the guide does not list: the contents are ours.
CONTENTS_OURS = {"Export": "the guide names the section without listing its options"}
#: (section, guide name) -> reason, where our default intentionally differs from the
#: guide's. None today: every default the guide states is ours.
INTENTIONAL_DIFFERENCES: dict[tuple[str, str], str] = {}


def _guide_data() -> dict:
    return json.loads(DATA.read_text(encoding="utf-8"))["sections"]


def _rows():
    for section, rows in _guide_data().items():
        for name, entry in rows.items():
            yield section, name, entry


def test_every_guide_section_is_accounted_for():
    guide = _guide_data()
    assert len(guide) == 12  # the eleven Properties sections and the Tracker pane
    ours = set(SECTIONS)
    for section in guide:
        if section in NOT_OURS:
            assert section not in ours
        else:
            assert SECTION_OF.get(section, section) in ours, section
    mapped = {SECTION_OF.get(s, s) for s in guide if s not in NOT_OURS}
    assert ours - mapped == set(OURS_ONLY)


@pytest.mark.parametrize(("section", "name", "entry"), list(_rows()),
                         ids=[f"{s}/{n}" for s, n, _ in _rows()])
def test_guide_parameter_has_our_default_and_unit(section, name, entry):
    if section in NOT_OURS:
        ours = [s for sec in SECTIONS for s in specs_in_section(sec) if s.label == name]
        assert ours == [], f"{name} should not be a project property: {NOT_OURS[section]}"
        if section in USER_SETTINGS:  # a preference now: still the guide's default
            from carapost.ui.settings import PREFERENCES

            prefs = {p.label: p for p in PREFERENCES}
            assert name in prefs, f"{section}: no user setting labelled {name!r}"
            default = prefs[name].default
            assert default == entry["default"]
            assert isinstance(default, bool) == isinstance(entry["default"], bool), name
            if "unit" in entry:
                assert prefs[name].unit == entry["unit"], name
        return
    specs = {s.label: s for s in specs_in_section(SECTION_OF.get(section, section))}
    labels = LABELS_OF.get((section, name), (name,))
    for label in labels:
        assert label in specs, f"{section}: no property labelled {label!r}"
        s = specs[label]
        default = entry["default"]
        if default is None:
            assert "our choice" in s.help or "our own" in s.help, (
                f"{label}: the guide gives no default; the help must say ours is our choice")
        elif (section, name) in INTENTIONAL_DIFFERENCES:
            assert s.default != default
        else:
            assert s.default == default and (s.kind == "bool") == isinstance(default, bool)
            if isinstance(default, float):
                assert s.kind == "float", label
        if "unit" in entry:
            assert s.unit == entry["unit"], label


@pytest.mark.parametrize("section", [s for s in _guide_data() if s not in NOT_OURS])
def test_our_section_has_exactly_the_guide_parameters(section):
    if section in CONTENTS_OURS:
        assert specs_in_section(section)
        return
    expected = set()
    for name in _guide_data()[section]:
        expected.update(LABELS_OF.get((section, name), (name,)))
    ours = {s.label for s in specs_in_section(SECTION_OF.get(section, section))}
    assert ours == expected


def test_data_file_still_matches_the_guide():
    path = REPO / "scripts" / "extract_guide_defaults.py"
    loaded = importlib.util.spec_from_file_location("extract_guide_defaults", path)
    script = importlib.util.module_from_spec(loaded)
    loaded.loader.exec_module(script)
    guide = script.find_guide()
    if guide is None:
        pytest.skip("the reference guide is not beside this checkout (set CARAPOST_GUIDE)")
    text = script.dumps(script.extract(guide.read_text(encoding="utf-8")))
    assert DATA.read_text(encoding="utf-8") == text, (
        "the guide changed: rerun python scripts/extract_guide_defaults.py")
