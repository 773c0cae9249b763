"""Tests of the properties registry (carapost.model.properties)."""

from __future__ import annotations

import importlib.util
import json
import logging
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carapost.model import properties as mod
from carapost.model.properties import (
    SECTIONS,
    SPECS,
    Properties,
    PropertyError,
    PropertySpec,
    UnknownPropertyError,
    spec,
    specs_in_section,
)

REPO = Path(__file__).resolve().parents[2]



def _doc_script():
    """scripts/gen_properties_doc.py as a module (scripts/ is not a package)."""
    path = REPO / "scripts" / "gen_properties_doc.py"
    loaded = importlib.util.spec_from_file_location("gen_properties_doc", path)
    module = importlib.util.module_from_spec(loaded)
    loaded.loader.exec_module(module)
    return module


# ---- the table itself --------------------------------------------------------------------
def test_every_section_present_and_in_display_order():
    expected = (
        "Selection",
        "Blob Parameters",
        "Initialize 3D Parameters",
        "Initialize From ROM Parameters",
        "Tracking Parameters",
        "Triangulation Parameters",
        "Label From Template Parameters",
        "Gap-Filling Parameters",
        "Clean-up Parameters",
        "Stabilization Parameters",
        "Export",
        "Target Tracker",
    )
    assert SECTIONS == expected
    for name in SECTIONS:
        assert specs_in_section(name), f"section {name!r} has no property"
    # every spec belongs to a listed section, and sections are contiguous in SPECS
    assert [s.section for s in SPECS] == sorted((s.section for s in SPECS), key=SECTIONS.index)


def test_keys_unique_snake_case_and_labels_unique_within_section():
    keys = [s.key for s in SPECS]
    assert len(keys) == len(set(keys))
    assert all(re.fullmatch(r"[a-z][a-z0-9_]*", k) for k in keys)
    for name in SECTIONS:
        labels = [s.label for s in specs_in_section(name)]
        assert len(labels) == len(set(labels)), name


def test_defaults_are_valid_and_canonical():
    for s in SPECS:
        assert s.validate(s.default) == s.default
        assert type(s.validate(s.default)) is type(s.default), s.key
        assert s.help and len(s.help) < 300, s.key
        if s.kind in ("int", "float"):
            # every number has both bounds, except Max Allowed Depth (the reach steps of
            # Initialize 3D multiply it, so it has no cap)
            assert s.minimum is not None, s.key
            assert s.maximum is not None or s.key == "max_allowed_depth", s.key
            assert s.minimum <= s.default <= (s.maximum or s.default), s.key
        if s.kind == "choice":
            assert s.default in s.choices


def test_labels_match_guide_names():
    assert spec("black_threshold").label == "Black Threshold"
    assert spec("max_symmetric_epipolar_distance").label == (
        "Max Allowed Symmetric Epipolar Distance"
    )
    assert spec("rom_max_3d_point_error").label == "ROM Max Allowed 3D Point Error"
    assert spec("allow_single_sensor_gap_filling").label == (
        "Allow Single Sensor Tracking Gap-Filling"
    )
    assert spec("minimum_cameras").maximum == 16
    assert spec("minimum_cameras").minimum == 1
    # the guide reuses "Allow Single Sensor Tracking" in the Tracker pane: distinct keys
    same = [s for s in SPECS if s.label == "Allow Single Sensor Tracking"]
    assert {s.section for s in same} == {"Tracking Parameters", "Target Tracker"}


def test_specs_are_frozen():
    with pytest.raises(AttributeError):
        SPECS[0].default = 3  # type: ignore[misc]


# ---- validation --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("key", "bad", "pattern"),
    [
        ("black_threshold", 1.5, r"^Black Threshold must be between 0 and 1 \(got 1\.5\)$"),
        ("black_threshold", -0.1, r"Black Threshold .*between 0 and 1"),
        ("minimum_cameras", 0, r"Minimum Cameras for Triangulation.*1 and 16"),
        ("minimum_cameras", 17, r"Minimum Cameras for Triangulation.*1 and 16"),
        ("patch_match_size", 7.5, r"Patch Match Size must be a whole number between 3 and 101"),
        ("black_threshold", float("nan"), r"Black Threshold must be a finite number"),
        ("black_threshold", "0.5", r"Black Threshold must be a number"),
        ("black_threshold", True, r"Black Threshold must be a number"),
        ("find_black_blobs", 1, r"Find Black Blobs must be True or False"),
        ("fbx_up_axis", "X", r"FBX Up Axis must be one of 'Y', 'Z'"),
        ("export_range", None, r"Export Range must be one of 'active', 'all'"),
        ("tracker_break_threshold", 2, r"Break Threshold must be between 0 and 1 \(got 2\)"),
    ],
)
def test_out_of_range_refused_with_label_and_range(key, bad, pattern):
    props = Properties()
    before = props[key]
    with pytest.raises(PropertyError, match=pattern) as info:
        props.set(key, bad)
    assert info.value.key == key
    assert props[key] == before


def test_bounds_are_inclusive_and_coercion():
    props = Properties()
    props.set("black_threshold", 1)  # int accepted for float, stored as float
    assert props["black_threshold"] == 1.0 and type(props["black_threshold"]) is float
    props.set("black_threshold", 0)
    assert props["black_threshold"] == 0.0
    props.set("patch_match_size", 21.0)  # integral float accepted for int
    assert props["patch_match_size"] == 21 and type(props["patch_match_size"]) is int
    props.set("patch_match_size", np.int64(9))
    assert type(props["patch_match_size"]) is int
    props.set("find_white_blobs", np.True_)
    assert props["find_white_blobs"] is True
    props.set("fbx_up_axis", "z")  # choices match ignoring case, stored canonically
    assert props["fbx_up_axis"] == "Z"


def test_np_float_message_is_plain():
    with pytest.raises(PropertyError, match=r"\(got 3\)$"):
        Properties().set("stable_points_percent", np.float64(3.0))


def test_unknown_key_suggests_close_names():
    props = Properties()
    with pytest.raises(UnknownPropertyError, match="black_threshold"):
        props.set("blak_threshold", 0.5)
    with pytest.raises(KeyError):
        props["no_such_thing"]
    with pytest.raises(PropertyError, match="unknown properties section"):
        props.section("Blobs")
    assert props.get("no_such_thing", 7) == 7


def test_parse_from_text():
    assert spec("find_black_blobs").parse("off") is False
    assert spec("find_black_blobs").parse(" Yes ") is True
    assert spec("black_threshold").parse("0.25") == 0.25
    assert spec("tracker_n_frames").parse("12") == 12
    assert spec("fbx_up_axis").parse("y") == "Y"
    with pytest.raises(PropertyError, match="Black Threshold"):
        spec("black_threshold").parse("lots")
    with pytest.raises(PropertyError, match="between 0 and 1"):
        spec("black_threshold").parse("2")
    with pytest.raises(PropertyError, match="Find Black Blobs"):
        spec("find_black_blobs").parse("maybe")


def test_colour_and_string_kinds_validate():
    colour = PropertySpec("Display", "c", "Colour", "colour", "#ff0000", help="x")
    assert colour.validate("#00FF00") == "#00ff00"
    with pytest.raises(PropertyError, match="Colour must be a colour"):
        colour.validate("red")
    text = PropertySpec("Display", "t", "Text", str, "", help="x")
    assert text.validate("abc") == "abc"
    with pytest.raises(PropertyError, match="Text must be text"):
        text.validate(3)


# ---- change notification, update, restore ------------------------------------------------
def test_on_change_fires_only_on_real_change():
    calls: list[set[str]] = []
    props = Properties(on_change=calls.append)
    props.set("black_threshold", 0.4)  # same as default
    props.set("black_threshold", 0.4 * 1)  # same value again
    assert calls == []
    props.set("black_threshold", 0.5)
    assert calls == [{"black_threshold"}]
    props.set("black_threshold", 0.5)
    assert calls == [{"black_threshold"}]
    with pytest.raises(PropertyError):
        props.set("black_threshold", 5)
    assert calls == [{"black_threshold"}]


def test_update_is_all_or_nothing_and_notifies_once():
    calls: list[set[str]] = []
    props = Properties(on_change=calls.append)
    with pytest.raises(PropertyError, match="White Threshold"):
        props.update({"black_threshold": 0.6, "white_threshold": 9})
    assert props["black_threshold"] == 0.4 and calls == []
    changed = props.update({"black_threshold": 0.6, "white_threshold": 0.4})
    assert changed == {"black_threshold"}
    assert calls == [{"black_threshold"}]


def test_restore_defaults_returns_old_values_for_undo():
    calls: list[set[str]] = []
    props = Properties({"black_threshold": 0.7, "fbx_up_axis": "Z"}, on_change=calls.append)
    edited = props.copy()
    old = props.restore_defaults()
    assert props == Properties()
    assert calls == [{"black_threshold", "fbx_up_axis"}]
    assert old["black_threshold"] == 0.7 and set(old) == set(props.keys())
    props.update(old)  # undo
    assert props == edited
    # a second restore of already-default values notifies nobody
    props.restore_defaults()
    calls.clear()
    props.restore_defaults()
    assert calls == []


def test_restore_defaults_of_one_section():
    props = Properties({"black_threshold": 0.7, "patch_match_threshold": 0.5})
    old = props.restore_defaults("Blob Parameters")
    assert props["black_threshold"] == 0.4
    assert props["patch_match_threshold"] == 0.5
    assert set(old) == {s.key for s in specs_in_section("Blob Parameters")}


def test_section_gives_algorithm_parameters():
    props = Properties({"black_min_radius": 2})
    blob = props.section("Blob Parameters")
    assert list(blob) == [s.key for s in specs_in_section("Blob Parameters")]
    assert blob["black_min_radius"] == 2.0 and blob["black_threshold"] == 0.4
    blob["black_threshold"] = 0.0  # a copy: the registry is not modified behind its back
    assert props["black_threshold"] == 0.4
    tri = props.section("Triangulation Parameters")
    assert tri["min_ray_angle_deg"] == 2.0 and tri["target_reprojection_error"] > 0


@pytest.mark.parametrize("cls", mod.PARAMETER_CLASSES, ids=lambda c: c.__name__)
def test_section_feeds_algorithm_parameters(cls):
    """A section's keys, defaults and ranges are the algorithm's parameter fields."""
    from carapost.algorithms.params import from_mapping, property_fields

    declared = property_fields(cls)
    section = declared[0][1].section
    values = Properties().section(section)
    assert list(values) == [info.key or f.name for f, info in declared]
    assert from_mapping(cls, values) == cls() == from_mapping(cls, Properties())
    for f, info in declared:
        s = spec(info.key or f.name)
        assert (s.label, s.default, s.unit, s.help) == (info.label, f.default, info.unit,
                                                         info.help)
        assert (s.minimum, s.maximum, s.min_exclusive, s.max_exclusive) == (
            info.minimum, info.maximum, info.min_exclusive, info.max_exclusive)


def test_one_range_for_the_registry_and_the_algorithm():
    """The registry refuses exactly what the parameter class refuses."""
    from carapost.algorithms.blobs import BlobParameters
    from carapost.algorithms.init3d import Init3DParameters

    for value, ok in ((1000.0, True), (1000.5, False), (0.0, False), (0.25, True)):
        try:
            BlobParameters(white_min_radius=value, white_max_radius=1000.0)
            algorithm_ok = True
        except ValueError:
            algorithm_ok = False
        try:
            spec("white_min_radius").validate(value)
            registry_ok = True
        except PropertyError:
            registry_ok = False
        assert algorithm_ok == registry_ok == ok, value
    with pytest.raises(PropertyError, match="Max Allowed Depth must be greater than 0"):
        Properties().set("max_allowed_depth", 0)
    with pytest.raises(ValueError, match="Max Allowed Depth .* greater than 0"):
        Init3DParameters(max_allowed_depth=0)


def test_gui_preferences_of_old_project_files_are_ignored_quietly(caplog):
    old = {"show_version_check_dialog": False, "tracker_update_2d_view_every_frame": True,
           "tracker_update_timeline_every_frame": False, "point_labels_all": True,
           "point_labels_selected": False, "point_labels_preselected": False,
           "label_font_size": 30, "black_threshold": 0.5}
    with caplog.at_level(logging.WARNING, logger=mod.__name__):
        props = Properties.from_dict(old)
    assert props["black_threshold"] == 0.5
    assert not mod.MOVED_TO_USER_SETTINGS & set(props.keys())
    assert caplog.records == []


def test_copy_is_independent_and_eq():
    props = Properties({"black_threshold": 0.3}, on_change=lambda keys: None)
    other = props.copy()
    assert other == props and other.on_change is None
    other.set("black_threshold", 0.2)
    assert other != props and props["black_threshold"] == 0.3
    assert props != {"black_threshold": 0.3}


def test_constructor_rejects_invalid_values():
    with pytest.raises(PropertyError, match="Black Threshold"):
        Properties({"black_threshold": 1000})
    with pytest.raises(UnknownPropertyError):
        Properties({"font": 10})


def test_problems_reports_inconsistent_combinations():
    assert Properties().problems() == []
    props = Properties({"black_min_radius": 60, "find_black_blobs": False})
    text = " ".join(props.problems())
    assert "Black Min Radius (60) is larger than Black Max Radius (50)" in text
    assert "Neither Find Black Blobs" in text
    props = Properties({"face_point_max_elastic_prediction_distance": 40})
    assert len(props.problems()) == 1


def test_non_defaults_and_repr():
    props = Properties({"black_threshold": 0.7})
    assert props.non_defaults() == {"black_threshold": 0.7}
    assert "black_threshold" in repr(props)
    assert repr(Properties()) == "Properties()"


# ---- persistence -------------------------------------------------------------------------
def _value_strategy(s: PropertySpec) -> st.SearchStrategy:
    if s.kind == "bool":
        return st.booleans()
    if s.kind == "int":
        return st.integers(int(s.minimum), int(s.maximum))
    if s.kind == "float":
        return st.floats(s.minimum, s.maximum if s.maximum is not None else 1e6,
                         exclude_min=s.min_exclusive, exclude_max=s.max_exclusive,
                         allow_nan=False, allow_infinity=False)
    assert s.kind == "choice"
    return st.sampled_from(s.choices)


_values = st.fixed_dictionaries({}, optional={s.key: _value_strategy(s) for s in SPECS})


@settings(max_examples=150, deadline=None)
@given(_values)
def test_to_dict_from_dict_round_trip_through_json(values):
    props = Properties(values)
    text = json.dumps(props.to_dict())
    back = Properties.from_dict(json.loads(text))
    assert back == props
    assert back.to_dict() == props.to_dict()
    for key, value in values.items():
        assert back[key] == spec(key).validate(value)


def test_from_dict_ignores_unknown_and_resets_invalid_with_warnings(caplog):
    with caplog.at_level(logging.WARNING, logger=mod.__name__):
        props = Properties.from_dict(
            {"black_threshold": 3.0, "white_threshold": 0.2, "gone_in_v2": 1, "fbx_up_axis": "W"}
        )
    assert props["black_threshold"] == 0.4  # invalid -> default
    assert props["white_threshold"] == 0.2
    assert props["fbx_up_axis"] == "Y"
    messages = [r.getMessage() for r in caplog.records]
    assert any("gone_in_v2" in m for m in messages)
    assert any("black_threshold" in m and "between 0 and 1" in m for m in messages)
    assert any("fbx_up_axis" in m for m in messages)
    assert len(messages) == 3
    with pytest.raises(PropertyError, match="must be a mapping"):
        Properties.from_dict([("black_threshold", 0.5)])  # type: ignore[arg-type]


def test_module_imports_without_qt():
    code = (
        "import sys, carapost.model.properties; "
        "sys.exit(any(m.startswith(('PySide6', 'pyqtgraph')) for m in sys.modules))"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


# ---- docs ---------------------------------------------------------------------------------
def test_markdown_lists_every_property():
    text = _doc_script().properties_markdown()
    for name in SECTIONS:
        assert f"## {name}" in text
    for s in SPECS:
        assert f"`{s.key}`" in text
    assert "| Black Threshold | `black_threshold` | float | 0.4 | 0 – 1 | 0-1 |" in text
    assert "| `white_max_radius` | float | 50 | greater than 0 and at most 1000 | px |" in text


def test_generated_doc_is_up_to_date():
    path = REPO / "docs" / "properties.md"
    assert path.read_text(encoding="utf-8") == _doc_script().properties_markdown(), (
        "docs/properties.md is stale; run python scripts/gen_properties_doc.py"
    )


def test_examples_run():
    import doctest

    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
