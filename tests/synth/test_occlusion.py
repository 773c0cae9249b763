"""Partial occlusion and missed markers of the synthetic generator, against their truth."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.blobs.detect import detect_blobs
from carapost.algorithms.blobs.params import BlobParameters
from carapost.synth import SynthConfig, build_scene, render_frame, write_truth
from carapost.synth.occlusion import segment_centroid_offset
from carapost.synth.render import _disc_ink


@pytest.fixture(scope="module")
def speech():
    return build_scene(SynthConfig(preset="speech", frames=60, partial_occlusion=True,
                                   missed_markers=3, seed=7))


def test_segment_centroid_matches_monte_carlo():
    rng = np.random.default_rng(1)
    p = rng.uniform(-1, 1, (400_000, 2))
    p = p[np.hypot(*p.T) < 1]
    offsets = np.array([0.9, 0.3, 0.0, -0.4, -0.8])
    got = segment_centroid_offset(np.ones(5), offsets)
    want = [p[p[:, 0] < o, 0].mean() for o in offsets]
    np.testing.assert_allclose(got, want, atol=3e-3)
    assert segment_centroid_offset(np.array([2.0]), np.array([np.inf]))[0] == 0.0


def test_options_off_leave_the_take_unchanged():
    small = {"preset": "speech", "frames": 60, "seed": 3, "size": (320, 180)}
    plain = build_scene(SynthConfig(**small))
    speech = build_scene(SynthConfig(**small, partial_occlusion=True, missed_markers=3))
    for name in ("cover_dir", "cover_offset", "visible_uv", "contrast", "missed"):
        assert getattr(plain, name) is None
    np.testing.assert_array_equal(plain.uv, speech.uv)
    np.testing.assert_array_equal(plain.visible, speech.visible)
    # a frame where nothing is covered nor faded renders the same image
    quiet = ~np.isfinite(speech.cover_offset).any(1) & ~speech.missed.any(1)
    f = int(np.flatnonzero(quiet)[0])
    np.testing.assert_array_equal(render_frame(plain, f, 1), render_frame(speech, f, 1))


def _ink_centroid(scene, f, m, c, cover):
    ink = np.zeros(scene.size[::-1], np.float32)
    _disc_ink(ink, scene, c, scene.cam_R[f, c], scene.cam_t[f, c],
              scene.seen_points[f, c][None, [m]], scene.seen_normals[f, c][None, [m]],
              scene.marker_radius_mm[[m]], 1.0, cover)
    ys, xs = np.nonzero(ink)
    w = ink[ys, xs].astype(np.float64)
    return np.array([(xs * w).sum(), (ys * w).sum()]) / w.sum(), w.sum()


def test_rendered_visible_part_matches_its_centroid_truth(speech):
    s = speech
    covered = np.isfinite(s.cover_offset)
    lips = [i for i, lab in enumerate(s.labels) if "Lip" in lab and "Lid" not in lab]
    assert covered[:, lips].any(0).all()        # lip curl covers every lip marker sometimes
    errs_vis, errs_centre, checked = [], [], 0
    for m in np.flatnonzero(covered.any(0)):
        for f in np.flatnonzero(covered[:, m] & s.visible[:, m, 0])[:3]:
            cover = (s.cover_dir[f, [m]], s.cover_offset[f, [m]])
            cen, area = _ink_centroid(s, f, m, 0, cover)
            _, full = _ink_centroid(s, f, m, 0, None)
            assert area < full          # part of the disc is hidden
            errs_vis.append(np.hypot(*(cen - s.visible_uv[f, m, 0])))
            errs_centre.append(np.hypot(*(cen - s.uv[f, m, 0])))
            checked += 1
    assert checked >= 10
    # the visible centroid is where the ink is (to the perspective bias of a disc's centre)
    assert np.median(errs_vis) < 0.05 and np.max(errs_vis) < 0.1
    assert np.median(errs_centre) > 0.2
    # the 3D centroid lies on the disc, beside the centre, away from the occluder
    d = s.visible_points3d - s.points3d
    assert np.all(np.linalg.norm(d, axis=-1) <= s.marker_radius_mm[None] + 1e-9)
    along = np.einsum("fmi,fmi->fm", d, s.cover_dir)
    assert np.all(along[covered] <= 1e-12) and np.all(along[~covered] == 0)


def test_missed_marker_is_missed_by_the_blob_detector_only_in_its_stretch(speech):
    s = speech
    ms = np.flatnonzero(s.missed.any(0))
    assert len(ms) == 3 and not s.eyelid[ms].any()
    assert s.visible[:, ms].all()
    params = BlobParameters()
    for m in ms[:2]:
        stretch = np.flatnonzero(s.missed[:, m])
        assert np.all(np.diff(stretch) == 1)
        inside = int(stretch[len(stretch) // 2])
        outside = int(stretch[0] - 1) if stretch[0] > 0 else int(stretch[-1] + 1)
        for f, want in ((inside, False), (outside, True)):
            det = detect_blobs(render_frame(s, f, 0), params)
            found = np.linalg.norm(det.centre - s.uv[f, m, 0], axis=1).min() < 1.5
            assert found == want, (s.labels[m], f)


def test_truth_file_carries_the_new_members(speech, tmp_path):
    write_truth(tmp_path / "truth.npz", speech)
    with np.load(tmp_path / "truth.npz") as z:
        np.testing.assert_array_equal(z["visible_uv"], speech.visible_uv)
        np.testing.assert_array_equal(z["missed"], speech.missed)
        assert z["cover_offset"].shape == speech.visible.shape[:2]
    with pytest.raises(ValueError, match="missed_markers"):
        SynthConfig(missed_markers=-1).validate()


def test_command_line_options(tmp_path):
    from carapost.synth.cli import main_synth

    out = tmp_path / "take"
    assert main_synth([str(out), "--frames", "12", "--size", "160x90", "--quiet",
                       "--workers", "1", "--partial-occlusion", "--missed-markers", "2"]) == 0
    with np.load(out / "truth.npz") as z:
        assert z["missed"].any(0).sum() == 2 and "visible_uv" in z.files
    assert main_synth([str(out), "--missed-markers", "-1", "--quiet"]) == 2
