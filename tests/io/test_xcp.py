"""XCP calibration files: real Vicon files, round trips, keyframes, both radial models."""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from carapost.algorithms.camera import (
    CameraIntrinsics,
    camera_centres,
    project,
    quaternion_to_matrix,
    undistort_pixels,
)
from carapost.io.errors import CaraFileError
from carapost.io.xcp import XcpCalibration, read_xcp, write_xcp

KEYFRAME_DEFAULTS = {
    "FRAME": "0",
    "FOCAL_LENGTH": "1000",
    "IMAGE_ERROR": "0.2",
    "ORIENTATION": "0 0 0 1",
    "POSITION": "0 0 -500",
    "PRINCIPAL_POINT": "640 360",
    "VICON_RADIAL2": "Vicon3Parameter 641 359 1e-8 -2e-15 0",
}


def _xcp_text(cameras: list[tuple[dict[str, str], list[dict[str, str]] | None]]) -> str:
    """A small XCP document; ``None`` keyframes means no <KeyFrames> element at all."""
    parts = ['<?xml version="1.0" encoding="UTF-8"?>', '<Cameras VERSION="2.0">']
    for cam_attrib, keyframes in cameras:
        attrs = " ".join(f'{k}="{v}"' for k, v in cam_attrib.items())
        parts.append(f"<Camera {attrs}>")
        if keyframes is not None:
            parts.append("<KeyFrames>")
            for kf in keyframes:
                parts.append("<KeyFrame " + " ".join(f'{k}="{v}"' for k, v in kf.items()) + "/>")
            parts.append("</KeyFrames>")
        parts.append("</Camera>")
    parts.append("</Cameras>")
    return "\n".join(parts)


def _camera(**overrides: str) -> dict[str, str]:
    attrib = {"DEVICEID": "17", "NAME": "cam_A", "PIXEL_ASPECT_RATIO": "1",
              "SENSOR_SIZE": "1280 720"}
    attrib.update(overrides)
    return {k: v for k, v in attrib.items() if v is not None}


def _keyframe(**overrides: str | None) -> dict[str, str]:
    kf: dict[str, str | None] = dict(KEYFRAME_DEFAULTS)
    kf.update(overrides)
    return {k: v for k, v in kf.items() if v is not None}


def _fixture_files(fixtures_dir: Path) -> list[Path]:
    files = sorted((fixtures_dir / "xcp").glob("*.xcp"))
    assert len(files) >= 4
    return files


# --------------------------------------------------------------------------- real files


def test_every_real_file_loads_with_the_verified_convention(fixtures_dir: Path) -> None:
    for path in _fixture_files(fixtures_dir):
        calib = read_xcp(path)
        # An independent parser gives the expected camera list and raw attribute values.
        cams = ET.parse(path).getroot().findall("Camera")
        assert calib.n_cameras == len(cams) > 0
        names = calib.intrinsics.names
        assert all(names) and len(set(names)) == len(names)
        assert calib.intrinsics.radial_model == ["VICON_RADIAL2"] * len(cams)
        assert calib.notes == []
        for c, cam in enumerate(cams):
            kf = cam.find("KeyFrames/KeyFrame")
            np.testing.assert_array_equal(calib.keyframes[c], [int(kf.get("FRAME"))])
            q = np.array(kf.get("ORIENTATION").split(), float)
            centre = np.array(kf.get("POSITION").split(), float)
            R = calib.R[c][0]
            np.testing.assert_allclose(R, quaternion_to_matrix(q / np.linalg.norm(q)),
                                       atol=1e-12)
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
            # POSITION is the camera centre, t = -R C.
            np.testing.assert_allclose(camera_centres(R, calib.t[c][0]), centre, atol=1e-9)
            radial2 = kf.get("VICON_RADIAL2").split()
            np.testing.assert_allclose(calib.intrinsics.distortion_centre[c],
                                       np.array(radial2[1:3], float))
            np.testing.assert_allclose(calib.intrinsics.radial[c], np.array(radial2[3:], float))
            np.testing.assert_allclose(calib.intrinsics.principal_point[c],
                                       np.array(kf.get("PRINCIPAL_POINT").split(), float))
            np.testing.assert_allclose(calib.intrinsics.image_size[c],
                                       np.array(cam.get("SENSOR_SIZE").split(), float))
            assert calib.intrinsics.focal[c] == float(kf.get("FOCAL_LENGTH"))
            assert calib.image_error[c][0] == float(kf.get("IMAGE_ERROR"))
            # Unnamed Vicon cameras are named by their device id.
            if not cam.get("NAME"):
                assert names[c].startswith(cam.get("DEVICEID"))


def test_real_markers_project_inside_every_camera(fixtures_dir: Path) -> None:
    ezc3d = pytest.importorskip("ezc3d")
    calib = read_xcp(fixtures_dir / "xcp" / "leyangwen_vicon-read_Cal.xcp")
    c3d = ezc3d.c3d(str(fixtures_dir / "xcp" / "leyangwen_vicon-read_T10_Missing.c3d"))
    assert c3d["parameters"]["POINT"]["UNITS"]["value"][0] == "mm"
    X = c3d["data"]["points"][:3].transpose(2, 1, 0).reshape(-1, 3)
    X = X[np.isfinite(X).all(axis=1) & (np.abs(X).sum(axis=1) > 0)]  # drop gaps
    assert X.shape[0] > 10_000
    R, t = calib.extrinsics_at([0])
    size = calib.intrinsics.image_size

    def inside_fraction(R: np.ndarray, t: np.ndarray) -> np.ndarray:
        uv, depth = project(X, R, t, calib.intrinsics, distort=True)
        ok = (depth > 0) & np.isfinite(uv).all(axis=-1)
        ok &= (uv >= -0.5).all(axis=-1) & (uv < size - 0.5).all(axis=-1)
        return ok.mean(axis=0)

    fraction = inside_fraction(R[0], t[0])
    assert fraction.shape == (calib.n_cameras,)
    assert np.all(fraction >= 0.95), fraction
    # Control: the reference guide's reading (t = POSITION) puts the markers elsewhere.
    positions = camera_centres(R[0], t[0])
    assert np.all(inside_fraction(R[0], positions) < 0.5)


def test_export_reimport_keeps_cameras_and_unknown_content(
    fixtures_dir: Path, tmp_path: Path
) -> None:
    for path in _fixture_files(fixtures_dir):
        calib = read_xcp(path)
        # extras are plain JSON data, so a project file can carry them.
        calib.extras = json.loads(json.dumps(calib.extras))
        out = tmp_path / path.name
        write_xcp(out, calib)
        again = read_xcp(out)
        assert again.intrinsics.equals(calib.intrinsics, atol=1e-9)
        for c in range(calib.n_cameras):
            np.testing.assert_array_equal(again.keyframes[c], calib.keyframes[c])
            np.testing.assert_allclose(again.R[c], calib.R[c], rtol=0, atol=1e-9)
            np.testing.assert_allclose(again.t[c], calib.t[c], rtol=0, atol=1e-9)
            np.testing.assert_array_equal(again.image_error[c], calib.image_error[c])
        # Unknown attributes and child elements survive, compared with the original file.
        src_root, out_root = ET.parse(path).getroot(), ET.parse(out).getroot()
        assert out_root.attrib == src_root.attrib
        for src_cam, out_cam in zip(src_root.findall("Camera"), out_root.findall("Camera"),
                                    strict=True):
            assert out_cam.attrib == src_cam.attrib  # incl. NAME="" and SYSTEM, TYPE, ...
            assert [ch.tag for ch in out_cam] == [ch.tag for ch in src_cam]
            for tag in ("ThresholdGrid", "Calibration", "IntrinsicsCalibration", "Capture"):
                assert out_cam.find(tag).attrib == src_cam.find(tag).attrib
            src_kf = src_cam.find("KeyFrames/KeyFrame")
            out_kf = out_cam.find("KeyFrames/KeyFrame")
            assert set(out_kf.attrib) == set(src_kf.attrib)
            assert out_kf.get("WORLD_ERROR") == src_kf.get("WORLD_ERROR")
        # Nothing was edited, so the export is the same XML as the file, digit for digit.
        assert ET.canonicalize(from_file=out, strip_text=True) == ET.canonicalize(
            from_file=path, strip_text=True)
        # A second export of the re-import is byte-identical (stable writer).
        write_xcp(tmp_path / "second.xcp", again)
        assert (tmp_path / "second.xcp").read_bytes() == out.read_bytes()


def test_camera_subset_keeps_each_cameras_own_content(
    fixtures_dir: Path, tmp_path: Path
) -> None:
    path = fixtures_dir / "xcp" / "leyangwen_vicon-read_Cal.xcp"
    calib = read_xcp(path)
    pick = [5, 0, 2]
    sub = XcpCalibration(
        calib.intrinsics.subset(pick), [calib.keyframes[i] for i in pick],
        [calib.R[i] for i in pick], [calib.t[i] for i in pick],
        [calib.image_error[i] for i in pick], extras=calib.extras)
    out = tmp_path / "subset.xcp"
    write_xcp(out, sub)
    src = {cam.get("DEVICEID"): cam for cam in ET.parse(path).getroot().findall("Camera")}
    written = ET.parse(out).getroot().findall("Camera")
    assert [cam.get("DEVICEID") for cam in written] == [calib.intrinsics.names[i] for i in pick]
    for cam in written:
        original = src[cam.get("DEVICEID")]
        assert cam.attrib == original.attrib
        assert cam.find("ThresholdGrid").get("DATA") == original.find("ThresholdGrid").get("DATA")
    again = read_xcp(out)
    np.testing.assert_allclose(again.t[0], calib.t[5], rtol=0, atol=1e-9)


def test_edited_pose_is_written_not_the_original_digits(
    fixtures_dir: Path, tmp_path: Path
) -> None:
    calib = read_xcp(fixtures_dir / "xcp" / "isue_cosine_cli_text.xcp")
    calib.t[1][0] += [1.5, -2.0, 0.25]
    calib.intrinsics.focal[2] += 1.0
    out = tmp_path / "edited.xcp"
    write_xcp(out, calib)
    again = read_xcp(out)
    np.testing.assert_allclose(again.t[1], calib.t[1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(again.intrinsics.focal, calib.intrinsics.focal, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(again.t[0], calib.t[0])


# --------------------------------------------------------------------------- keyframes


def _rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))


def _intrinsics(n: int) -> CameraIntrinsics:
    return CameraIntrinsics(
        focal=np.linspace(900, 1100, n),
        principal_point=np.tile([640.5, 360.25], (n, 1)),
        radial=np.tile([2e-8, -1e-15, 3e-22], (n, 1)),
        distortion_centre=np.tile([641.0, 359.5], (n, 1)),
        image_size=np.tile([1280, 720], (n, 1)),
        names=[f"cam{i}" for i in range(n)],
    )


def test_per_frame_extrinsics_round_trip_through_keyframes(
    rng: np.random.Generator, tmp_path: Path
) -> None:
    n_frames, first = 60, 100
    intr = _intrinsics(3)
    R = np.empty((n_frames, 3, 3, 3))
    t = np.empty((n_frames, 3, 3))
    # Camera 0 static, camera 1 moves at frames 10 and 35, camera 2 moves every frame.
    R[:, 0], t[:, 0] = _rotations(rng, 1)[0], [10.0, -20.0, 300.0]
    segments = [(0, 10), (10, 35), (35, n_frames)]
    for (a, b), Rs, ts in zip(segments, _rotations(rng, 3), rng.normal(0, 100, (3, 3)),
                              strict=True):
        R[a:b, 1], t[a:b, 1] = Rs, ts
    R[:, 2], t[:, 2] = _rotations(rng, n_frames), rng.normal(0, 100, (n_frames, 3))

    calib = XcpCalibration.from_arrays(intr, R, t, first_frame=first)
    np.testing.assert_array_equal(calib.keyframes[0], [first])
    np.testing.assert_array_equal(calib.keyframes[1], [first, first + 10, first + 35])
    np.testing.assert_array_equal(calib.keyframes[2], first + np.arange(n_frames))
    frames = first + np.arange(n_frames)
    R_at, t_at = calib.extrinsics_at(frames)
    assert R_at.shape == (n_frames, 3, 3, 3) and t_at.shape == (n_frames, 3, 3)
    np.testing.assert_array_equal(R_at, R)
    np.testing.assert_array_equal(t_at, t)
    # Frames before the first KeyFrame use it; frames after the last keep the last.
    R_out, _ = calib.extrinsics_at([0, first + 500])
    np.testing.assert_array_equal(R_out[0], R[0])
    np.testing.assert_array_equal(R_out[1], R[-1])

    path = tmp_path / "moving.xcp"
    write_xcp(path, calib)
    kfs = [cam.findall("KeyFrames/KeyFrame") for cam in ET.parse(path).getroot()]
    assert [len(k) for k in kfs] == [1, 3, n_frames]
    assert [k.get("FRAME") for k in kfs[1]] == ["100", "110", "135"]
    again = read_xcp(path)
    assert again.intrinsics.equals(intr, atol=1e-9)
    R_back, t_back = again.extrinsics_at(frames)
    np.testing.assert_allclose(R_back, R, rtol=0, atol=1e-9)
    np.testing.assert_allclose(t_back, t, rtol=0, atol=1e-9)

    # Export XCP [Current Frame]: one FRAME="0" KeyFrame per camera, the one in force.
    current = tmp_path / "current.xcp"
    write_xcp(current, again, frame=first + 20)
    single = read_xcp(current)
    R_now, t_now = single.extrinsics_at([0])
    assert all(k.tolist() == [0] for k in single.keyframes)
    np.testing.assert_allclose(R_now[0], R[20], rtol=0, atol=1e-9)
    np.testing.assert_allclose(t_now[0], t[20], rtol=0, atol=1e-9)


def test_from_arrays_catches_slow_drift(rng: np.random.Generator) -> None:
    # Each step is below atol but the drift adds up: KeyFrames must keep the error bounded.
    n_frames, atol = 1000, 1e-3
    R = np.broadcast_to(np.eye(3), (n_frames, 1, 3, 3)).copy()
    t = np.zeros((n_frames, 1, 3))
    t[:, 0, 0] = np.arange(n_frames) * 0.4e-3
    calib = XcpCalibration.from_arrays(_intrinsics(1), R, t, atol=atol)
    _, t_at = calib.extrinsics_at(np.arange(n_frames))
    assert np.max(np.abs(t_at - t)) <= atol
    assert 300 <= calib.keyframes[0].size <= 500  # one every ~3 frames, not one per frame


def test_static_extrinsics_give_one_keyframe_and_validation(rng: np.random.Generator) -> None:
    intr = _intrinsics(2)
    R, t = _rotations(rng, 2), rng.normal(size=(2, 3))
    calib = XcpCalibration.from_arrays(intr, R, t, first_frame=7, image_error=[0.1, 0.2])
    assert [k.tolist() for k in calib.keyframes] == [[7], [7]]
    assert [e.tolist() for e in calib.image_error] == [[0.1], [0.2]]
    with pytest.raises(ValueError, match="R must be"):
        XcpCalibration.from_arrays(intr, R[:1], t[:1])
    t_bad = np.broadcast_to(t, (4, 2, 3)).copy()
    t_bad[2, 1, 0] = np.nan
    with pytest.raises(ValueError, match="frame 2, camera 'cam1'"):
        XcpCalibration.from_arrays(intr, np.broadcast_to(R, (4, 2, 3, 3)), t_bad)


# --------------------------------------------------------------------------- radial models


def test_two_term_vicon_radial_file(tmp_path: Path) -> None:
    w0, w1 = 2.7e-9, -2.0e-16
    text = _xcp_text([
        (_camera(NAME="T160_17980", SKEW="0.5", PIXEL_ASPECT_RATIO="1",
                 SENSOR_SIZE="4704 3456"),
         [_keyframe(VICON_RADIAL2=None, VICON_RADIAL=f"{w0} {w1}",
                    PRINCIPAL_POINT="2400.4 1711.6", FOCAL_LENGTH="4570.1",
                    ORIENTATION="0 0 0.6 0.8")]),
    ])
    path = tmp_path / "two_term.xcp"
    path.write_text(text)
    calib = read_xcp(path)
    intr = calib.intrinsics
    assert intr.radial_model == ["VICON_RADIAL"]
    assert intr.names == ["T160_17980"]
    np.testing.assert_array_equal(intr.radial[0], [w0, w1, 0.0])
    np.testing.assert_array_equal(intr.distortion_centre, intr.principal_point)
    assert intr.skew[0] == 0.5
    # The two-term correction as the format defines it, computed by hand.
    raw = np.array([[100.0, 3000.0]])
    d = raw[0] - [2400.4, 1711.6]
    r2 = d @ d
    expected = [2400.4, 1711.6] + (1 + w0 * r2 + w1 * r2 * r2) * d
    np.testing.assert_allclose(undistort_pixels(raw, intr)[0], expected, rtol=1e-12)

    out = tmp_path / "two_term_out.xcp"
    write_xcp(out, calib)
    kf = ET.parse(out).getroot().find("Camera/KeyFrames/KeyFrame")
    assert "VICON_RADIAL2" not in kf.attrib
    np.testing.assert_array_equal(np.array(kf.get("VICON_RADIAL").split(), float), [w0, w1])
    cam = ET.parse(out).getroot().find("Camera")
    assert cam.get("SKEW") == "0.5" and cam.get("NAME") == "T160_17980"
    assert read_xcp(out).intrinsics.equals(intr, atol=1e-12)

    # A two-term camera that gained a third term is written as VICON_RADIAL2 (lossless).
    calib.intrinsics.radial[0, 2] = 1e-23
    write_xcp(out, calib)
    upgraded = read_xcp(out).intrinsics
    assert upgraded.radial_model == ["VICON_RADIAL2"]
    np.testing.assert_array_equal(upgraded.radial, calib.intrinsics.radial)


def test_mixed_models_round_trip_and_renaming(tmp_path: Path) -> None:
    text = _xcp_text([
        (_camera(NAME="", DEVICEID="", USERID="3"), [_keyframe()]),
        (_camera(NAME="", DEVICEID="", USERID=""),
         [_keyframe(VICON_RADIAL2=None, VICON_RADIAL="1e-9 0", IMAGE_ERROR=None)]),
    ])
    path = tmp_path / "mixed.xcp"
    path.write_text(text)
    calib = read_xcp(path)
    assert calib.intrinsics.names == ["3", "Camera 1"]
    assert calib.intrinsics.radial_model == ["VICON_RADIAL2", "VICON_RADIAL"]
    assert calib.image_error[1].tolist() == [0.0]
    calib.intrinsics.names[1] = "left_top"
    write_xcp(path, calib)
    names = [cam.get("NAME") for cam in ET.parse(path).getroot()]
    assert names == ["", "left_top"]  # unnamed stays unnamed, a renamed camera is named
    again = read_xcp(path)
    assert again.intrinsics.names == ["3", "left_top"]
    assert again.intrinsics.radial_model == ["VICON_RADIAL2", "VICON_RADIAL"]


def test_keyframe_intrinsics_that_vary_are_reported(tmp_path: Path) -> None:
    path = tmp_path / "varying.xcp"
    path.write_text(_xcp_text([(_camera(), [
        _keyframe(FRAME="11", FOCAL_LENGTH="1010"),
        _keyframe(FRAME="0"),
    ])]))
    calib = read_xcp(path)
    assert calib.keyframes[0].tolist() == [0, 11]  # sorted
    assert calib.intrinsics.focal[0] == 1000.0  # first KeyFrame's
    assert len(calib.notes) == 1 and "FOCAL_LENGTH" not in calib.notes[0]
    assert "intrinsics differ" in calib.notes[0] and "cam_A" in calib.notes[0]


def test_near_unit_quaternion_is_normalised(tmp_path: Path) -> None:
    path = tmp_path / "near.xcp"
    path.write_text(_xcp_text([(_camera(), [_keyframe(ORIENTATION="0 0 0.6 0.8004")])]))
    R = read_xcp(path).R[0][0]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


# --------------------------------------------------------------------------- bad input


MALFORMED = {
    "not_xml": ("this is < not xml", "not a valid XML"),
    "wrong_root": ('<?xml version="1.0"?><Subjects><Camera/></Subjects>', "<Cameras>"),
    "no_camera": ('<Cameras VERSION="2.0"></Cameras>', "no <Camera>"),
    "no_keyframes": (_xcp_text([(_camera(), None)]), "cam_A.*no <KeyFrames>"),
    "empty_keyframes": (_xcp_text([(_camera(), [])]), "no <KeyFrame>"),
    "missing_focal": (_xcp_text([(_camera(), [_keyframe(FOCAL_LENGTH=None)])]),
                      "cam_A.*FOCAL_LENGTH is missing"),
    "missing_sensor": (_xcp_text([(_camera(SENSOR_SIZE=None), [_keyframe()])]),
                       "cam_A.*SENSOR_SIZE is missing"),
    "non_numeric": (_xcp_text([(_camera(), [_keyframe(POSITION="1 2 x")])]),
                    "cam_A.*POSITION is not numeric"),
    "non_finite": (_xcp_text([(_camera(), [_keyframe(FOCAL_LENGTH="nan")])]),
                   "FOCAL_LENGTH holds a non-finite"),
    "orientation_3": (_xcp_text([(_camera(), [_keyframe(ORIENTATION="0 0 1")])]),
                      "ORIENTATION must hold 4 numbers, got 3"),
    "non_unit_q": (_xcp_text([(_camera(), [_keyframe(ORIENTATION="0 0 0 2")])]),
                   "not a unit quaternion"),
    "radial2_prefix": (_xcp_text([(_camera(), [_keyframe(VICON_RADIAL2="1 2 3 4 5")])]),
                       "Vicon3Parameter"),
    "radial2_count": (_xcp_text([(_camera(), [_keyframe(VICON_RADIAL2="Vicon3Parameter 1 2")])]),
                      "VICON_RADIAL2 must hold 5 numbers"),
    "radial_count": (_xcp_text([(_camera(), [_keyframe(VICON_RADIAL2=None,
                                                       VICON_RADIAL="1e-9")])]),
                     "VICON_RADIAL must hold 2 numbers"),
    "same_frame": (_xcp_text([(_camera(), [_keyframe(), _keyframe()])]), "same FRAME"),
    "bad_frame": (_xcp_text([(_camera(), [_keyframe(FRAME="1.5")])]), "FRAME must be"),
    "negative_focal": (_xcp_text([(_camera(), [_keyframe(FOCAL_LENGTH="-3")])]),
                       "FOCAL_LENGTH must be positive"),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_files_raise_cara_file_error(case: str, tmp_path: Path) -> None:
    text, pattern = MALFORMED[case]
    path = tmp_path / f"{case}.xcp"
    path.write_text(text)
    with pytest.raises(CaraFileError, match=pattern) as info:
        read_xcp(path)
    assert info.value.path == path
    assert str(path) in str(info.value)


def test_missing_file_raises_cara_file_error(tmp_path: Path) -> None:
    with pytest.raises(CaraFileError, match="cannot be read"):
        read_xcp(tmp_path / "absent.xcp")


def test_failed_write_leaves_existing_file_untouched(tmp_path: Path) -> None:
    path = tmp_path / "cal.xcp"
    path.write_text(_xcp_text([(_camera(), [_keyframe()])]))
    before = path.read_bytes()
    calib = read_xcp(path)
    calib.t[0][0, 2] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        write_xcp(path, calib)
    assert path.read_bytes() == before
    with pytest.raises(CaraFileError, match="does not exist"):
        write_xcp(tmp_path / "no_such_folder" / "cal.xcp", read_xcp(path))
    if os.name == "posix" and os.geteuid() != 0:
        os.chmod(tmp_path, 0o500)
        try:
            with pytest.raises(CaraFileError, match="could not be written|cannot create"):
                write_xcp(path, read_xcp(path))
        finally:
            os.chmod(tmp_path, 0o700)
        assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.xcp"]  # no temp files left


@pytest.mark.skipif(os.name != "posix", reason="POSIX file modes")
def test_written_file_gets_normal_permissions(tmp_path: Path) -> None:
    calib = XcpCalibration.from_arrays(_intrinsics(1), np.eye(3)[None], np.zeros((1, 3)))
    umask = os.umask(0o022)
    os.umask(umask)
    path = tmp_path / "new.xcp"
    write_xcp(path, calib)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask
    os.chmod(path, 0o640)
    write_xcp(path, calib)  # replacing keeps the file's mode
    assert path.stat().st_mode & 0o777 == 0o640
