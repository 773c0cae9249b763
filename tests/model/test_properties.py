"""Tests of the properties registry (carapost.model.properties)."""

from __future__ import annotations

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
    properties_markdown,
    spec,
    specs_in_section,
)

REPO = Path(__file__).resolve().parents[2]

# Defaults stated in the reference guide (or the triangulation seeds text), by key.
GUIDE_DEFAULTS = {
    "point_labels_all": False,
    "point_labels_selected": True,
    "point_labels_preselected": True,
    "label_font_size": 10,
    "select_points": True,
    "select_sticks": True,
    "white_min_radius": 4,
    "white_max_radius": 50,
    "black_min_radius": 4,
    "black_max_radius": 50,
    "find_black_blobs": True,
    "find_white_blobs": False,
    "black_threshold": 0.4,
    "white_threshold": 0.4,
    "max_allowed_depth": 35,
    "max_3d_distance_to_merge": 5,
    "max_symmetric_epipolar_distance": 5,
    "rom_face_point_tracking_distance": 50,
    "rom_brim_point_tracking_distance": 30,
    "rom_max_3d_point_error": 5,
    "patch_match_threshold": 0.8,
    "face_point_tracking_distance": 35,
    "face_point_max_elastic_prediction_distance": 15,
    "brim_point_tracking_distance": 15,
    "patch_match_size": 15,
    "remove_bad_2d_projections": True,
    "max_2d_projection_error": 5,
    "remove_bad_3d_points": True,
    "max_3d_point_error": 5,
    "allow_single_sensor_tracking": True,
    "single_sensor_tracking_threshold": 0.5,
    "blob_size_difference_threshold": 0.75,
    "overwrite_existing_filled_gaps": False,
    "use_forwards_prediction": True,
    "use_backwards_prediction": True,
    "allow_single_sensor_gap_filling": True,
    "stabilization_use_brim_points": False,
    "base_frame_weighting": 1.0,
    "inter_frame_weighting": 1.0,
    "stable_points_percent": 0.25,
    "max_processing_iterations": 50,
    "show_version_check_dialog": True,
    "tracker_break_threshold": 0.9,
    # Triangulation (FreeMoCap-style parameters, see the seeds text)
    "minimum_cameras": 3,
    "use_outlier_rejection": False,
    "maximum_cameras_to_drop": 1,
    "flatten_single_camera_data": True,
}


# ---- the table itself --------------------------------------------------------------------
def test_every_section_present_and_in_display_order():
    expected = (
        "Display",
        "Selection",
        "Blob Parameters",
        "Initialize 3D Parameters",
        "Initialize From ROM Parameters",
        "Tracking Parameters",
        "Triangulation Parameters",
        "Gap-Filling Parameters",
        "Stabilization Parameters",
        "Export",
        "Show Again Flags",
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
            assert s.minimum is not None and s.maximum is not None, s.key
            assert s.minimum <= s.default <= s.maximum, s.key
        if s.kind == "choice":
            assert s.default in s.choices


@pytest.mark.parametrize(("key", "value"), sorted(GUIDE_DEFAULTS.items()))
def test_default_matches_guide(key, value):
    props = Properties()
    assert props[key] == value
    assert type(props[key]) is type(value) or isinstance(value, int) and spec(key).kind == "float"


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


@pytest.mark.parametrize(
    ("module", "cls", "section"),
    [
        ("carapost.algorithms.blobs", "BlobParameters", "Blob Parameters"),
        (
            "carapost.algorithms.triangulation",
            "TriangulationParameters",
            "Triangulation Parameters",
        ),
    ],
)
def test_section_feeds_algorithm_parameters(module, cls, section):
    """A section's keys and defaults are exactly the algorithm's parameter fields."""
    import dataclasses
    import importlib

    try:
        params_cls = getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError):
        pytest.skip(f"{module}.{cls} not available in this checkout")
    values = Properties().section(section)
    assert params_cls(**values) == params_cls()
    fields = {f.name for f in dataclasses.fields(params_cls)}
    assert set(values) == fields


def test_copy_is_independent_and_eq():
    props = Properties({"label_font_size": 14}, on_change=lambda keys: None)
    other = props.copy()
    assert other == props and other.on_change is None
    other.set("label_font_size", 12)
    assert other != props and props["label_font_size"] == 14
    assert props != {"label_font_size": 14}


def test_constructor_rejects_invalid_values():
    with pytest.raises(PropertyError, match="Font Size"):
        Properties({"label_font_size": 1000})
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
        return st.floats(s.minimum, s.maximum, allow_nan=False, allow_infinity=False)
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


# ---- docs --------------------------------------------------------------------------------
def test_markdown_lists_every_property():
    text = properties_markdown()
    for name in SECTIONS:
        assert f"## {name}" in text
    for s in SPECS:
        assert f"`{s.key}`" in text
    assert "| Black Threshold | `black_threshold` | float | 0.4 | 0 – 1 | 0-1 |" in text


def test_generated_doc_is_up_to_date():
    path = REPO / "docs" / "properties.md"
    if not path.exists():
        pytest.skip("docs/properties.md not present in this checkout")
    assert path.read_text(encoding="utf-8") == properties_markdown(), (
        "docs/properties.md is stale; regenerate it with properties_markdown()"
    )
