"""A version-1 ``.cara`` project, committed as ``tests/data/cara_v1.cara``, opens forever.

The file was written once by the version-1 writer (``io/cara.py`` at carapost 0.1.0) with
``scripts/make_cara_v1_fixture.py``, from the values this module holds: 5 frames, 4
cameras, 6 points with every reconstruction kind and observation source, detections,
labels, sticks, properties, intrinsics and per-frame extrinsics. Its camera videos and
ROM project never existed, so opening it also exercises the missing-file path.

Never regenerate the file and never change the expected values here to match new code:
when the project format changes, bump ``FORMAT_VERSION``, write the migration from
version 1 in the reader, and keep this test passing against the old file unchanged.
"""

from __future__ import annotations

import json
import logging
import zipfile
from pathlib import Path

import numpy as np
import pytest

from carapost.io.cara import load_project, save_project

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "cara_v1.cara"

F, C, P = 5, 4, 6

# The take, as written into the manifest.
TAKE_NAME = "v1fixture"
FPS = 59.94
TIMECODE = "01:02:03:04"
METADATA = {"performer": "fixture", "session": 1, "notes": "format version 1"}
CAMERA_NAMES = ["headL", "headR", "chinL", "chinR"]
IMAGE_SIZES = [(640, 360), (640, 360), (480, 272), (480, 272)]
ROTATIONS = [0, 90, 180, 270]
FRAME_OFFSETS = [0, 1, 2, 3]
#: Absolute video paths that do not exist anywhere (nor beside the fixture).
VIDEO_PATHS = [f"/nonexistent/carapost-fixture/cara_v1_{n}.mkv" for n in CAMERA_NAMES]
ROM_PATH = "/nonexistent/carapost-fixture/cara_v1_rom.cara"

# Points: ids are not contiguous on purpose (a deleted point leaves a gap).
POINT_IDS = [1, 2, 3, 5, 8, 13]
POINT_LABELS = ["brim_L", "brim_R", "", "lip_top", "lip_bottom", "chin"]
POINT_KINDS = [1, 1, 0, 0, 0, 0]  # KIND_BRIM, KIND_BRIM, then KIND_FACE
NEXT_ID = 14
LABELS = ["lip_top", "lip_bottom", "chin", "brow_L"]
STICKS = [(8, 13, (255, 0, 0)), (1, 2, (255, 255, 0))]

PROPERTIES = {
    "find_black_blobs": False,
    "black_threshold": 0.55,
    "patch_match_size": 21,
    "max_3d_point_error": 7.5,
    "minimum_cameras": 2,
    "export_range": "all",
    "fbx_up_axis": "Z",
}

CURRENT_FRAME = 2
ACTIVE_RANGE = (1, 4)
VIEW_RANGE = (0, 4)
SELECTED_POINTS = {3, 8}
SELECTED_CAMERAS = {0, 2}
IMPORTED_BLOB_PARAMETERS = {"black_threshold": 0.5, "white_min_radius": 1.5, "source": "x"}

INTRINSICS = {
    "focal": [900.5, 910.0, 920.25, 930.0],
    "principal_point": [[320.5, 180.25], [319.0, 181.0], [240.0, 136.0], [241.5, 135.5]],
    "aspect": [1.0, 1.001, 0.999, 1.0],
    "skew": [0.0, 0.0, 0.125, 0.0],
    "radial": [[1e-8, 2e-15, 0.0], [-1e-8, 0.0, 0.0], [2e-8, -1e-15, 3e-22], [0.0, 0.0, 0.0]],
    "distortion_centre": [[320.5, 180.25], [319.0, 181.0], [240.5, 136.5], [241.5, 135.5]],
    "image_size": [[640.0, 360.0], [640.0, 360.0], [480.0, 272.0], [480.0, 272.0]],
    "radial_model": ["VICON_RADIAL2", "VICON_RADIAL", "VICON_RADIAL2", "VICON_RADIAL2"],
    "names": CAMERA_NAMES,
}

# Literal rotations (no trigonometry: the values must be the same on every platform).
ROTATIONS_3X3 = np.array([
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    [[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]],
    [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
    [[1.0, 0.0, 0.0], [0.0, 0.28, -0.96], [0.0, 0.96, 0.28]],
])
SOLVED = [True, True, False, True, False]


def expected_point_arrays() -> dict[str, np.ndarray]:
    """The eight per-point arrays of the fixture, in their storage dtypes.

    Every reconstruction kind 0-4 and every observation source 0-5 occurs; positions,
    residuals and observations are NaN where there is no sample, as the model stores
    them. All values are exact binary fractions.
    """
    f, p = np.meshgrid(np.arange(F), np.arange(P), indexing="ij")
    recon = ((f + p) % 5).astype(np.int8)
    positions = (np.arange(F * P * 3, dtype=np.float32).reshape(F, P, 3) * 0.25 - 10.0)
    positions[recon == 0] = np.nan
    residual = ((f * P + p) * 0.125).astype(np.float32)
    residual[recon == 0] = np.nan
    c = np.arange(C)
    source = ((f[..., None] + p[..., None] + c) % 6).astype(np.int8)
    obs = np.arange(F * P * C * 2, dtype=np.float32).reshape(F, P, C, 2) * 0.5 + 1.0
    obs[source == 0] = np.nan
    counts = expected_detection_counts()
    detection = np.where(source == 1, p[..., None] % counts[:, None, :], -1).astype(np.int32)
    quality = np.where((source == 2) | (source == 4),
                       ((f[..., None] + p[..., None] + c) % 8) / 8, 0.0).astype(np.float16)
    keyframe = source == 3
    return {"positions": positions, "recon": recon, "residual": residual, "obs": obs,
            "source": source, "detection": detection, "quality": quality,
            "keyframe": keyframe}


def expected_detection_counts() -> np.ndarray:
    """Detections per image, shape (F, C): 1 to 3."""
    f, c = np.meshgrid(np.arange(F), np.arange(C), indexing="ij")
    return (1 + (f + 2 * c) % 3).astype(np.int64)


def expected_detections() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """``offsets`` [F*C+1] and the flat detection fields of the fixture."""
    counts = expected_detection_counts().reshape(-1)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    n = int(offsets[-1])
    k = np.arange(n)
    fields = {
        "centre": (np.arange(2 * n, dtype=np.float32).reshape(n, 2) * 0.25 + 3.0),
        "axes": np.stack([2.0 + (k % 4) * 0.5, 1.5 + (k % 3) * 0.25], axis=1).astype(
            np.float16),
        "angle": ((k % 8) * 0.125).astype(np.float16),
        "colour": (k % 2).astype(np.int8),
        "score": ((k % 16) / 16).astype(np.float16),
    }
    return offsets, fields


def expected_calibration() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World->camera ``R`` [F,C,3,3], ``t`` [F,C,3] (mm) and ``solved`` [F]."""
    f, c = np.meshgrid(np.arange(F), np.arange(C), indexing="ij")
    R = ROTATIONS_3X3[(f + c) % 4]
    t = np.stack([c * 10.0, f - 5.0, 100.0 + c * 0.5], axis=-1)
    return R, t, np.array(SOLVED)


@pytest.fixture
def project():
    """The fixture, freshly opened."""
    return load_project(FIXTURE)


def test_the_fixture_is_a_small_version_1_file():
    assert FIXTURE.stat().st_size < 50_000
    with zipfile.ZipFile(FIXTURE) as zf:
        manifest = json.loads(zf.read("manifest.json"))
    assert manifest["format"] == "carapost-project"
    assert manifest["format_version"] == 1


def test_v1_project_opens_with_its_missing_videos_reported(caplog):
    with caplog.at_level(logging.WARNING, logger="carapost"):
        project = load_project(FIXTURE)
    missing = [r.getMessage() for r in caplog.records if "not found" in r.getMessage()]
    assert len(missing) == C
    for name, path, msg in zip(CAMERA_NAMES, VIDEO_PATHS, missing, strict=True):
        assert name in msg and path in msg
    # the missing paths are kept, so Relocate Files can show and replace them
    assert [cam.video_path for cam in project.take.cameras] == VIDEO_PATHS
    assert project.path == str(FIXTURE)
    assert project.modified is False


def test_v1_take_and_metadata(project):
    take = project.take
    assert take.name == TAKE_NAME
    assert (take.n_frames, take.n_cameras, project.n_points) == (F, C, P)
    assert take.fps == FPS
    assert take.timecode_start == TIMECODE
    assert take.metadata == METADATA
    assert [cam.name for cam in take.cameras] == CAMERA_NAMES
    assert [cam.image_size for cam in take.cameras] == IMAGE_SIZES
    assert [cam.rotation for cam in take.cameras] == ROTATIONS
    assert [cam.frame_offset for cam in take.cameras] == FRAME_OFFSETS
    assert project.current_frame == CURRENT_FRAME
    assert tuple(project.active_range) == ACTIVE_RANGE
    assert tuple(project.view_range) == VIEW_RANGE
    assert project.selection.points == SELECTED_POINTS
    assert project.selection.cameras == SELECTED_CAMERAS
    assert project.rom is not None and project.rom.path == ROM_PATH
    assert project.imported_blob_parameters == IMPORTED_BLOB_PARAMETERS


def test_v1_points_labels_and_sticks(project):
    pts = project.points
    assert pts.ids.tolist() == POINT_IDS
    assert pts.labels == POINT_LABELS
    assert pts.kind.tolist() == POINT_KINDS
    assert pts.next_id == NEXT_ID
    expected = expected_point_arrays()
    # sigma and the raw values of filtered samples came after format 1's first files:
    # they open with them unknown (NaN).
    raw = {"raw_positions", "raw_recon", "raw_sigma"}
    assert set(pts.arrays) == set(expected) | {"sigma"} | raw
    assert np.isnan(pts.arrays["raw_positions"]).all()
    assert pts.arrays["sigma"].shape == expected["recon"].shape
    assert pts.arrays["sigma"].dtype == np.float32
    assert np.isnan(pts.arrays["sigma"]).all()
    for name, arr in expected.items():
        got = pts.arrays[name]
        assert got.dtype == arr.dtype, name
        np.testing.assert_array_equal(got, arr, err_msg=name, strict=True)
    assert set(np.unique(expected["recon"]).tolist()) == {0, 1, 2, 3, 4}
    assert set(np.unique(expected["source"]).tolist()) == {0, 1, 2, 3, 4, 5}
    assert project.labels == LABELS
    assert [(s.a, s.b, tuple(s.colour)) for s in project.sticks] == STICKS


def test_v1_detections(project):
    offsets, fields = expected_detections()
    det = project.detections
    np.testing.assert_array_equal(det.offsets, offsets, strict=True)
    np.testing.assert_array_equal(det.counts(), expected_detection_counts(), strict=True)
    assert set(det.arrays) == set(fields)
    for name, arr in fields.items():
        np.testing.assert_array_equal(det.arrays[name], arr, err_msg=name, strict=True)


def test_v1_calibration(project):
    cal = project.calibration
    R, t, solved = expected_calibration()
    np.testing.assert_array_equal(cal.R, R, strict=True)
    np.testing.assert_array_equal(cal.t, t, strict=True)
    np.testing.assert_array_equal(cal.solved, solved, strict=True)
    intr = cal.intrinsics
    assert intr is not None
    for name in ("focal", "principal_point", "aspect", "skew", "radial",
                 "distortion_centre", "image_size"):
        np.testing.assert_array_equal(getattr(intr, name), np.array(INTRINSICS[name]),
                                      err_msg=name)
    assert intr.radial_model == INTRINSICS["radial_model"]
    assert intr.names == INTRINSICS["names"]


def test_v1_properties(project):
    for key, value in PROPERTIES.items():
        assert project.properties[key] == value, key


def test_v1_project_saved_by_this_version_reopens_equal(project, tmp_path):
    again = load_project(save_project(project, tmp_path / "resaved.cara"))
    for name, arr in expected_point_arrays().items():
        np.testing.assert_array_equal(again.points.arrays[name], arr, strict=True)
    np.testing.assert_array_equal(again.detections.offsets, expected_detections()[0])
    np.testing.assert_array_equal(again.calibration.R, expected_calibration()[0])
    assert [cam.video_path for cam in again.take.cameras] == VIDEO_PATHS
    assert again.properties.to_dict() == project.properties.to_dict()
