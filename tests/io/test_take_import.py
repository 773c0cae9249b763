"""Import Camera Files: finding a take's files, building the project, clear errors."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from carapost import synth
from carapost.algorithms.camera import CameraIntrinsics, rodrigues_to_matrix
from carapost.io.errors import CaraFileError
from carapost.io.take_import import find_take_files, import_take, read_brim_csv
from carapost.io.xcp import XcpCalibration, write_xcp

W, H = 80, 48


def write_video(path: Path, n: int, rng: np.random.Generator, fourcc: str = "FFV1",
                fps: float = 50.0) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (W, H),
                             isColor=False)
    assert writer.isOpened()
    for i in range(n):
        img = rng.integers(0, 256, (H, W), dtype=np.uint8)
        img[0, 0] = i
        writer.write(img)
    writer.release()
    return path


def make_take(folder: Path, rng: np.random.Generator, channels=("cam0", "cam1", "cam10"),
              counts=(12, 12, 12), name: str = "Speech_01") -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    return [write_video(folder / f"{name}_{c}.mkv", n, rng)
            for c, n in zip(channels, counts, strict=True)]


def calibration(names: list[str], rng: np.random.Generator) -> XcpCalibration:
    C = len(names)
    intr = CameraIntrinsics(focal=np.full(C, 90.0), principal_point=np.tile([W / 2, H / 2], (C, 1)),
                            image_size=np.tile([W, H], (C, 1)), names=names)
    R = rodrigues_to_matrix(rng.normal(0, 0.2, (C, 3)))
    t = rng.normal(0, 50, (C, 3))
    return XcpCalibration.from_arrays(intr, R, t)


def test_import_full_take(tmp_path, rng):
    folder = tmp_path / "takes"
    videos = make_take(folder, rng)
    make_take(folder, rng, channels=("cam0",), counts=(5,), name="Other")  # another take
    (folder / "Speech_01.json").write_text(json.dumps({
        "fps": 59.94, "timecode_start": "10:00:00:12", "logger_name": "Logger A",
        "logger_id": "L-7", "cameras": {"cam1": {"frame_offset": 1, "rotation": 180}},
        "blob_parameters": {"black_min_radius": 2.0, "black_threshold": 0.5,
                            "min_radius": 2.0}}))
    # XCP cameras in another order than the channels: matched by name
    calib = calibration(["cam10", "cam0", "cam1"], rng)
    write_xcp(folder / "Speech_01.xcp", calib)
    (folder / "Speech_01_labels.txt").write_text("Brow_L Brow_R\nNose Nose\n")
    (folder / "Speech_01_brim.csv").write_text("label,x,y,z\nB1,0,0,0\nB2,10,0,0\n")

    project = import_take(videos[1])
    take = project.take
    assert take.name == "Speech_01"
    assert [c.name for c in take.cameras] == ["cam0", "cam1", "cam10"]  # natural order
    assert [Path(c.video_path) for c in take.cameras] == [v.resolve() for v in videos]
    assert all(c.image_size == (W, H) for c in take.cameras)
    assert take.cameras[1].frame_offset == 1 and take.cameras[1].rotation == 180
    assert take.n_frames == 12 and project.n_frames == 12
    assert take.fps == pytest.approx(59.94)
    assert take.timecode_start == "10:00:00:12"
    assert take.metadata["logger_name"] == "Logger A" and take.metadata["logger_id"] == "L-7"
    assert take.metadata["take_folder"] == str(folder.absolute())
    assert take.metadata["brim_file"].endswith("Speech_01_brim.csv")
    # the take's blob parameters are applied and remembered (unknown keys ignored)
    assert project.properties["black_min_radius"] == 2.0
    assert project.imported_blob_parameters["black_threshold"] == 0.5
    assert project.imported_blob_parameters["find_black_blobs"] is True
    assert "min_radius" not in project.imported_blob_parameters
    assert project.labels == ["Brow_L", "Brow_R", "Nose", "Nose - Copy"]
    cal = project.calibration
    assert cal.intrinsics.names == ["cam0", "cam1", "cam10"]
    order = [1, 2, 0]  # channel c is XCP camera order[c]
    R, t = calib.extrinsics_at([0])
    np.testing.assert_allclose(cal.R, np.broadcast_to(R[0, order], (12, 3, 3, 3)), atol=1e-9)
    np.testing.assert_allclose(cal.t[5], t[0, order], atol=1e-6)
    assert cal.solved.all()
    assert project.active_range == (0, 11)


def test_same_take_found_from_folder_json_and_sequence(tmp_path, rng):
    videos = make_take(tmp_path, rng, channels=("a", "b"), counts=(6, 6), name="T")
    seq = tmp_path / "T_c"
    seq.mkdir()
    for i in range(6):
        cv2.imwrite(str(seq / f"{i:03d}.png"), np.full((H, W), i, np.uint8))
    (tmp_path / "T.json").write_text("{}")
    for path in (tmp_path, tmp_path / "T.json", videos[0], seq):
        files = find_take_files(path)
        assert files.name == "T" and files.channels == ["a", "b", "c"]
        assert files.videos[2] == seq.absolute()
        assert files.json == tmp_path.absolute() / "T.json" and files.xcp is None
    project = import_take(seq)
    assert project.n_cameras == 3 and project.n_frames == 6


def test_differing_frame_counts_warn_and_use_common_range(tmp_path, rng, caplog):
    videos = make_take(tmp_path, rng, channels=("cam0", "cam1"), counts=(10, 7))
    with caplog.at_level(logging.WARNING, logger="carapost.io"):
        project = import_take(videos[0])
    assert project.n_frames == 7
    msg = " ".join(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    assert "different frame counts" in msg and "cam0 10" in msg and "cam1 7" in msg


def test_frame_rate_from_video_then_default_with_warning(tmp_path, rng, caplog):
    videos = make_take(tmp_path / "v", rng, channels=("cam0",), counts=(4,))
    assert import_take(videos[0]).take.fps == pytest.approx(50.0)
    seq = tmp_path / "s" / "Take_cam0"
    seq.mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(seq / f"f{i}.tif"), np.full((H, W), 7, np.uint8))
    with caplog.at_level(logging.WARNING, logger="carapost.io"):
        project = import_take(seq)
    assert project.take.fps == 60.0
    assert any("assuming 60 fps" in r.getMessage() for r in caplog.records)


def test_missing_and_unreadable_files_are_named(tmp_path, rng):
    with pytest.raises(CaraFileError, match=r"T_cam0\.mkv: no such file"):
        import_take(tmp_path / "T_cam0.mkv")
    make_take(tmp_path, rng, channels=("cam0",), counts=(4,), name="T")
    (tmp_path / "T_cam1.mkv").write_bytes(b"\x1aE\xdf\xa3 truncated garbage" * 50)
    with pytest.raises(CaraFileError, match=r"T_cam1\.mkv"):
        import_take(tmp_path / "T_cam0.mkv")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CaraFileError, match="holds no camera files"):
        import_take(empty)
    stray = tmp_path / "notes.txt"
    stray.write_text("x")
    with pytest.raises(CaraFileError, match="not a camera file"):
        import_take(stray)


def test_relocate_callback_is_asked_for_a_missing_take(tmp_path, rng):
    videos = make_take(tmp_path, rng, channels=("cam0",), counts=(3,), name="T")
    asked = []

    def relocate(what: str, missing: str) -> str:
        asked.append(missing)
        return str(videos[0])

    project = import_take(tmp_path / "moved" / "T_cam0.mkv", relocate=relocate)
    assert project.n_frames == 3 and asked[0].endswith("T_cam0.mkv")


def test_pico_files_get_an_explanation(tmp_path):
    pico = tmp_path / "Example_0.pico"
    pico.write_bytes(b"\x00" * 64)
    for path in (pico, tmp_path):
        with pytest.raises(CaraFileError) as err:
            import_take(path)
        text = str(err.value)
        assert "Example_0.pico" in text
        assert "proprietary" in text and "undocumented" in text
        assert "<take>_<channel>.mkv" in text


def test_several_takes_in_a_folder_is_an_error(tmp_path, rng):
    make_take(tmp_path, rng, channels=("cam0",), counts=(3,), name="A")
    make_take(tmp_path, rng, channels=("cam0",), counts=(3,), name="B")
    with pytest.raises(CaraFileError, match=r"several takes \(A, B\)"):
        import_take(tmp_path)


def test_bad_json_and_mismatched_xcp(tmp_path, rng):
    videos = make_take(tmp_path, rng, channels=("cam0", "cam1"), counts=(3, 3), name="T")
    (tmp_path / "T.json").write_text("{not json")
    with pytest.raises(CaraFileError, match=r"T\.json: is not valid JSON"):
        import_take(videos[0])
    (tmp_path / "T.json").write_text(json.dumps({"fps": -3}))
    with pytest.raises(CaraFileError, match="fps must be a positive number"):
        import_take(videos[0])
    (tmp_path / "T.json").write_text(json.dumps({"timecode_start": "25:99"}))
    with pytest.raises(CaraFileError, match="timecode_start"):
        import_take(videos[0])
    (tmp_path / "T.json").unlink()
    write_xcp(tmp_path / "T.xcp", calibration(["x", "y", "z"], rng))
    with pytest.raises(CaraFileError, match=r"T\.xcp: holds 3 cameras but the take has 2"):
        import_take(videos[0])


def test_read_brim_csv(tmp_path):
    p = tmp_path / "brim.csv"
    p.write_text("B1, 1, 2, 3\n\n# comment\nB2,4.5,-5,6e1\n")
    labels, xyz = read_brim_csv(p)
    assert labels == ["B1", "B2"]
    np.testing.assert_allclose(xyz, [[1, 2, 3], [4.5, -5, 60]])
    p.write_text("label,x,y,z\nB1,1,2,3\nB2,1,oops,3\n")
    with pytest.raises(CaraFileError, match="line 3: x, y, z must be numbers"):
        read_brim_csv(p)
    p.write_text("B1,1,2\n")
    with pytest.raises(CaraFileError, match="line 1: expected label,x,y,z"):
        read_brim_csv(p)
    p.write_text("B1,1,2,3\nB1,4,5,6\n")
    with pytest.raises(CaraFileError, match="line 2: label 'B1' appears twice"):
        read_brim_csv(p)
    p.write_text("label,x,y,z\n")
    with pytest.raises(CaraFileError, match="holds no brim markers"):
        read_brim_csv(p)


def test_bad_brim_csv_refuses_the_import(tmp_path, rng):
    videos = make_take(tmp_path, rng, channels=("cam0",), counts=(3,), name="T")
    (tmp_path / "T_brim.csv").write_text("B1,1,2,x\nB2,1,2,3\nB3,1,2,?\n")
    with pytest.raises(CaraFileError, match=r"T_brim\.csv: line 3"):
        import_take(videos[0])


def test_import_synthetic_take(tmp_path):
    config = synth.SynthConfig(frames=4, size=(160, 96), n_cameras=2, markers="sparse35",
                               take_name="tiny")
    out = synth.generate_take(tmp_path, config)
    project = import_take(out)
    assert project.take.name == "tiny"
    assert project.n_cameras == 2 and project.n_frames == 4
    assert project.take.cameras[0].image_size == (160, 96)
    assert project.take.fps == pytest.approx(config.fps)
    files = find_take_files(out)
    assert files.xcp is not None and files.brim_csv is not None
    assert project.calibration.intrinsics is not None and project.calibration.solved.all()
    assert project.take.metadata["logger_name"] == "carapost-synth"
    truth = np.load(tmp_path / "truth.npz")
    assert project.labels == [str(s) for s in truth["labels"]]
    # frame-0 calibration of the XCP = the truth cameras of frame 0
    np.testing.assert_allclose(project.calibration.t[0], truth["cam_t"][0], atol=1e-6)
    np.testing.assert_allclose(project.calibration.intrinsics.K(), truth["K"], atol=1e-9)
