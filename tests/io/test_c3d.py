"""C3D export/import: spec-correct word 4, cross-checked with py-c3d, ezc3d and raw bytes."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import c3d as pyc3d
import ezc3d
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import carapost.io.c3d._write as c3d_writer
from carapost.io.c3d import choose_residual_scale, read_c3d, write_c3d
from carapost.io.errors import CaraFileError

# Facts from fixtures/c3d/README.txt (spec decode of word 4's high byte).
FILES_WITH_REAL_MASKS = {
    "amass_Eb015pi_int.c3d",
    "amass_Eb015pr_float.c3d",
    "oxfordmetrics_gait-pig-nz.c3d",
    "sample26_Capture0002.c3d",
}


def make_take(rng, n_frames=40, n_points=6, n_cams=4, gap_rate=0.1):
    """Synthetic take: positions with gaps, residuals, masks, a few modified samples."""
    pos = rng.normal(0.0, 60.0, (n_frames, n_points, 3))
    gaps = rng.random((n_frames, n_points)) < gap_rate
    pos[gaps] = np.nan
    res = rng.uniform(0.05, 1.9, (n_frames, n_points))
    mask = rng.random((n_frames, n_points, n_cams)) < 0.6
    modified = (rng.random((n_frames, n_points)) < 0.05) & ~gaps
    labels = [f"pt{i:03d}" for i in range(n_points)]
    return pos, res, mask, modified, labels


def raw_point_block(path: Path) -> tuple[np.ndarray, float, float]:
    """Decode the data block straight from the bytes: [F, P, 4] float32, header scale, param."""
    data = path.read_bytes()
    n_points, n_analog = struct.unpack_from("<HH", data, 2)
    first, last = struct.unpack_from("<HH", data, 6)
    (header_scale,) = struct.unpack_from("<f", data, 12)
    (data_start,) = struct.unpack_from("<H", data, 16)
    n_frames = last - first + 1
    stride = 4 * n_points + n_analog
    block = np.frombuffer(
        data, "<f4", count=n_frames * stride, offset=(data_start - 1) * 512
    ).reshape(n_frames, stride)
    return block[:, : 4 * n_points].reshape(n_frames, n_points, 4), header_scale, stride


def expected_words(pos, res, mask, modified, scale):
    valid = ~np.isnan(pos).any(axis=2)
    rbyte = np.clip(np.rint(res / scale), 1, 255).astype(np.int32)
    bits = (mask[..., :7] * (1 << np.arange(min(7, mask.shape[2])))).sum(axis=2)
    word = rbyte | (bits << 8)
    word[modified] = 0
    word[~valid] = -1
    return word


def pyc3d_frames(path: Path):
    with warnings.catch_warnings():
        # py-c3d warns about absent analog data and other harmless things.
        warnings.simplefilter("ignore")
        with open(path, "rb") as fh:
            reader = pyc3d.Reader(fh)
            frames = [(p.copy(), a.copy()) for _, p, a in reader.read_frames()]
            return reader, frames


def test_round_trip_and_raw_word4(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng)
    path = tmp_path / "take.c3d"
    write_c3d(
        path,
        pos,
        labels=labels,
        rate=59.94,
        residuals=res,
        camera_mask=mask,
        modified=modified,
        descriptions=[f"d{i}" for i in range(len(labels))],
        first_frame=101,
        timecode_start="10:20:30:12",
        timecode_rate=29.97,
        camera_names=["c1", "c2", "c3", "c4"],
        extra_groups={"SUBJECTS": {"NAMES": ["actor"], "USED": 1, "GAINS": [1.5, 2.5]}},
    )
    scale = choose_residual_scale(res[~modified & ~np.isnan(pos[..., 0])].max())
    assert scale == 0.01  # residuals up to 1.9 mm: 0.01 mm steps cover 2.55 mm

    # Raw bytes: word 4 is a float holding the signed 16-bit spec word.
    block, header_scale, _ = raw_point_block(path)
    word = block[..., 3]
    assert np.all(word == np.rint(word))
    np.testing.assert_array_equal(
        word.astype(np.int32), expected_words(pos, res, mask, modified, scale)
    )
    invalid = np.isnan(pos).any(axis=2)
    assert np.all(block[invalid][:, :3] == 0)
    assert header_scale == np.float32(-scale)

    d = read_c3d(path)
    valid = ~invalid
    np.testing.assert_array_equal(np.isnan(d.positions[..., 0]), invalid)
    np.testing.assert_array_equal(d.positions[valid], pos[valid].astype(np.float32))
    keep = valid & ~modified
    assert np.max(np.abs(d.residuals[keep] - res[keep])) <= scale / 2 + 1e-6
    assert np.all(d.residuals[modified] == 0) and np.all(d.processed == modified)
    np.testing.assert_array_equal(d.camera_mask[..., :4], mask & keep[..., None])
    assert not d.camera_mask[..., 4:].any()
    assert d.labels == labels and d.descriptions[2] == "d2"
    assert d.rate == pytest.approx(59.94, rel=1e-6) and d.first_frame == 101
    assert d.scale == pytest.approx(-scale) and d.units == "mm"
    assert d.timecode_start == "10:20:30:12" and d.timecode_rate == pytest.approx(29.97)
    assert d.camera_names == ["c1", "c2", "c3", "c4"] and d.has_camera_masks
    assert d.groups["SUBJECTS"]["NAMES"] == ["actor"]
    np.testing.assert_allclose(d.groups["SUBJECTS"]["GAINS"], [1.5, 2.5])
    assert d.groups["MANUFACTURER"]["COMPANY"] == "carapost"
    assert d.groups["POINT"]["SCALE"] == np.float32(-scale)


def test_py_c3d_reads_spec_values(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng)
    path = tmp_path / "take.c3d"
    write_c3d(
        path, pos, labels=labels, rate=120, residuals=res, camera_mask=mask, modified=modified
    )
    reader, frames = pyc3d_frames(path)
    assert len(frames) == pos.shape[0]
    assert reader.point_rate == 120 and reader.first_frame == 1
    assert [s.strip() for s in reader.point_labels] == labels
    pts = np.stack([p for p, _ in frames])  # [F, P, 5]: x y z residual camera-byte
    valid = ~np.isnan(pos).any(axis=2)
    keep = valid & ~modified
    np.testing.assert_allclose(pts[valid][:, :3], pos[valid], atol=1e-4)
    assert np.all(pts[~valid][:, 3] == -1)
    assert np.max(np.abs(pts[keep][:, 3] - res[keep])) <= 0.005 + 1e-6
    bits = (mask * (1 << np.arange(4))).sum(axis=2)
    np.testing.assert_array_equal(pts[keep][:, 4], bits[keep])
    assert np.all(pts[modified][:, 3:] == 0)


def test_ezc3d_reads_values_swapped_as_documented(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng)
    path = tmp_path / "take.c3d"
    write_c3d(
        path, pos, labels=labels, rate=100, residuals=res, camera_mask=mask, modified=modified
    )
    e = ezc3d.c3d(str(path))
    valid = ~np.isnan(pos).any(axis=2)
    keep = valid & ~modified
    pts = e["data"]["points"].transpose(2, 1, 0)  # [F, P, 4]
    np.testing.assert_array_equal(np.isnan(pts[..., 0]), ~valid)
    np.testing.assert_allclose(pts[valid][:, :3], pos[valid], atol=1e-4)
    assert e["parameters"]["POINT"]["LABELS"]["value"] == labels
    assert e["parameters"]["POINT"]["RATE"]["value"][0] == 100
    # ezc3d 1.7.2 swaps the bytes: its "residual" is our mask byte times |scale| and its
    # "camera_masks" are the bits of our residual byte.
    ez_res = e["data"]["meta_points"]["residuals"][0].T  # [F, P]
    ez_mask = e["data"]["meta_points"]["camera_masks"].transpose(2, 1, 0)  # [F, P, 7]
    bits = (mask * (1 << np.arange(4))).sum(axis=2)
    np.testing.assert_allclose(ez_res[keep], bits[keep] * 0.01, atol=1e-6)
    rbyte = np.clip(np.rint(res / 0.01), 1, 255).astype(int)
    ez_byte = (ez_mask * (1 << np.arange(7))).sum(axis=2)
    np.testing.assert_array_equal(ez_byte[keep], rbyte[keep] & 0x7F)


def test_more_than_255_points_and_7_cameras(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng, n_frames=12, n_points=300, n_cams=10)
    path = tmp_path / "big.c3d"
    write_c3d(path, pos, labels=labels, rate=60, residuals=res, camera_mask=mask, modified=modified)
    d = read_c3d(path)
    assert d.labels == labels
    valid = ~np.isnan(pos).any(axis=2)
    keep = valid & ~modified
    np.testing.assert_array_equal(d.camera_mask, mask[..., :7] & keep[..., None])
    assert d.camera_mask_full is not None and d.camera_mask_full.shape == mask.shape
    np.testing.assert_array_equal(d.camera_mask_full, mask & keep[..., None])
    assert d.groups["CARAPOST"]["MASK_LAYOUT"] == "WORD4+ANALOG"

    e = ezc3d.c3d(str(path))
    pe = e["parameters"]["POINT"]
    assert pe["LABELS"]["value"] + pe["LABELS2"]["value"] == labels
    assert e["data"]["points"].shape == (4, 300, 12)
    # The mask channels are plain analog channels at the point rate: bit c = camera c + 1.
    analog = e["data"]["analogs"][0]  # [channels, frames]
    bits = (mask * (1 << np.arange(10))).sum(axis=2) * keep
    np.testing.assert_array_equal(analog.T, bits)
    block, _, _ = raw_point_block(path)
    assert block.shape == (12, 300, 4)


def test_non_ascii_labels(tmp_path, rng):
    pos = rng.normal(size=(3, 2, 3))
    path = tmp_path / "u.c3d"
    write_c3d(path, pos, labels=["lèvre_g", "a"], rate=30, descriptions=["lip", "é"])
    d = read_c3d(path)
    assert d.labels == ["lèvre_g", "a"] and d.descriptions == ["lip", "é"]


def test_long_take_frame_fields(tmp_path):
    n = 70_000  # beyond the 16-bit header frame fields
    pos = np.zeros((n, 1, 3))
    pos[:, 0, 0] = np.arange(n)
    path = tmp_path / "long.c3d"
    write_c3d(path, pos, labels=["a"], rate=200, first_frame=5)
    d = read_c3d(path)
    assert d.positions.shape == (n, 1, 3) and d.first_frame == 5
    assert d.positions[-1, 0, 0] == n - 1
    _, frames = pyc3d_frames(path)
    assert len(frames) == n


def test_vendor_files_load_or_fail_cleanly(fixtures_dir):
    files = sorted((fixtures_dir / "c3d").glob("*.c3d"))
    assert len(files) == 12
    with_masks = set()
    for f in files:
        try:
            d = read_c3d(f)
        except CaraFileError as exc:  # allowed, but must name the file
            assert f.name in str(exc)
            continue
        n_frames, n_points, _ = d.positions.shape
        assert n_frames > 0 and n_points == len(d.labels) > 0
        assert d.residuals.shape == (n_frames, n_points)
        if d.has_camera_masks:
            with_masks.add(f.name)
    print("vendor files with camera masks:", sorted(with_masks))
    assert with_masks == FILES_WITH_REAL_MASKS


def test_vendor_facts(fixtures_dir):
    folder = fixtures_dir / "c3d"
    pi, pr = (
        read_c3d(folder / "amass_Eb015pi_int.c3d"),
        read_c3d(folder / "amass_Eb015pr_float.c3d"),
    )
    # The same data stored as integers and as floats: identical word 4, close positions.
    np.testing.assert_array_equal(pi.camera_mask, pr.camera_mask)
    np.testing.assert_allclose(pi.residuals, pr.residuals, rtol=1e-5)
    np.testing.assert_allclose(pi.positions, pr.positions, atol=abs(pi.scale))
    counts = pi.camera_mask[pi.valid].sum(axis=1)
    assert np.median(pi.residuals[pi.valid]) == pytest.approx(0.83, abs=0.01)
    assert not np.any(counts == 1)  # a real contribution mask never has exactly one camera
    qtm = read_c3d(folder / "qualisys_qtm217.c3d")
    assert qtm.valid.all() and np.median(qtm.residuals) == pytest.approx(1.98, abs=0.01)
    # 65535.0 is a vendor sentinel for "invalid" (wraps to -1 as int16).
    pig = read_c3d(folder / "oxfordmetrics_gait-pig-nz.c3d")
    assert pig.valid.mean() == pytest.approx(0.922, abs=0.001)
    sing = read_c3d(folder / "facial_Sing_sample29.c3d")  # neither library opens this one
    assert sing.positions.shape == (3000, 38, 3) and sing.labels[0] == "root-1"
    opto = read_c3d(folder / "ndi_optotrak.c3d")  # header claims 1149 frames, file holds 29
    assert opto.positions.shape[0] == 29 and not opto.has_camera_masks


@pytest.mark.parametrize(
    "content", [b"", b"hello", b"\x02\x50" + b"\0" * 510, bytes(range(256)) * 8]
)
def test_bad_files_raise_cara_file_error(tmp_path, content):
    path = tmp_path / "bad.c3d"
    path.write_bytes(content)
    with pytest.raises(CaraFileError, match="bad.c3d"):
        read_c3d(path)


def test_truncated_parameter_section(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng)
    good = tmp_path / "good.c3d"
    write_c3d(good, pos, labels=labels, rate=60, residuals=res)
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(good.read_bytes()[:700])
    with pytest.raises(CaraFileError, match="cut.c3d"):
        read_c3d(cut)
    with pytest.raises(CaraFileError, match="missing.c3d"):
        read_c3d(tmp_path / "missing.c3d")


def test_bad_arrays_raise_value_error(tmp_path, rng):
    pos, res, mask, modified, labels = make_take(rng)
    path = tmp_path / "x.c3d"
    with pytest.raises(ValueError, match="positions"):
        write_c3d(path, pos[..., :2], labels=labels, rate=60)
    with pytest.raises(ValueError, match="labels"):
        write_c3d(path, pos, labels=labels[:-1], rate=60)
    with pytest.raises(ValueError, match="residuals"):
        write_c3d(path, pos, labels=labels, rate=60, residuals=res[:, :2])
    with pytest.raises(ValueError, match="camera_mask"):
        write_c3d(path, pos, labels=labels, rate=60, camera_mask=mask.astype(int))
    with pytest.raises(ValueError, match="camera_mask"):
        write_c3d(
            path, pos, labels=labels, rate=60, camera_mask=np.ones((*pos.shape[:2], 17), bool)
        )
    with pytest.raises(ValueError, match="rate"):
        write_c3d(path, pos, labels=labels, rate=0)
    with pytest.raises(ValueError, match="timecode"):
        write_c3d(path, pos, labels=labels, rate=60, timecode_start="noon")
    assert not list(tmp_path.iterdir())  # nothing written for bad input


def test_failed_write_leaves_old_file_and_no_temp(tmp_path, rng, monkeypatch):
    pos, res, mask, modified, labels = make_take(rng)
    path = tmp_path / "take.c3d"
    write_c3d(path, pos, labels=labels, rate=60)
    before = path.read_bytes()

    def boom(*_a, **_k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(c3d_writer, "_pack_mask", boom)  # fail mid-write
    with pytest.raises(RuntimeError):
        write_c3d(path, pos, labels=labels, rate=60, camera_mask=mask)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.c3d"]
    with pytest.raises(CaraFileError, match="does not exist"):
        write_c3d(tmp_path / "no" / "x.c3d", pos, labels=labels, rate=60)


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    n_frames=st.integers(1, 30),
    n_points=st.integers(1, 12),
    n_cams=st.integers(1, 16),
    seed=st.integers(0, 2**32 - 1),
    res_max=st.sampled_from([0.2, 1.0, 3.0, 40.0]),
)
@example(n_frames=5, n_points=11, n_cams=1, seed=132259, res_max=0.2)  # a halfway residual
def test_round_trip_property(tmp_path, n_frames, n_points, n_cams, seed, res_max):
    rng = np.random.default_rng(seed)
    pos = rng.normal(0, 200, (n_frames, n_points, 3))
    pos[rng.random((n_frames, n_points)) < 0.2] = np.nan
    res = rng.uniform(0.0, res_max, (n_frames, n_points))
    mask = rng.random((n_frames, n_points, n_cams)) < 0.5
    path = tmp_path / "prop.c3d"
    write_c3d(
        path,
        pos,
        labels=[f"p{i}" for i in range(n_points)],
        rate=60,
        residuals=res,
        camera_mask=mask,
    )
    d = read_c3d(path)
    valid = ~np.isnan(pos).any(axis=2)
    np.testing.assert_array_equal(d.valid, valid)
    np.testing.assert_array_equal(d.positions[valid], pos[valid].astype(np.float32))
    q = abs(d.scale)
    assert 255 * q >= res[valid].max(initial=0) - 1e-9
    # the writer quantises with the nominal quantum (0.001, 0.002, ...); the file stores it
    # as a float32, so a residual halfway between two steps must be rounded with the former
    q_nominal = choose_residual_scale(float(res[valid].max(initial=0)))
    assert q == pytest.approx(q_nominal, rel=1e-6)
    # a measured sample never reads as processed
    expect = np.maximum(np.rint(res / q_nominal), 1) * q
    np.testing.assert_allclose(d.residuals[valid], expect[valid], rtol=1e-5)
    np.testing.assert_array_equal(
        d.camera_mask[..., : min(7, n_cams)], (mask & valid[..., None])[..., :7]
    )
    if n_cams > 7:
        np.testing.assert_array_equal(d.camera_mask_full, mask & valid[..., None])
