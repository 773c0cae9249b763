"""Calibration brim: models, SVG import, manual/automatic solves, per-frame re-solve."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from carapost.algorithms.brim import (
    BrimSolveParameters,
    brim_exclusion_mask,
    match_by_projection,
    rotation_error_deg,
    solve_brim_auto,
    solve_brim_manual,
)
from carapost.algorithms.camera import camera_centres, rodrigues_to_matrix
from carapost.io.brim_svg import DEFAULT_BRIM_VERSIONS, default_brim, read_brim_svg
from carapost.io.errors import CaraFileError
from carapost.synth.scene import SynthConfig, build_scene

#: Detection noise of the synthetic "detections" (px): the blob detector's measured
#: centre error on synthetic images (median 0.022 px, see docs/benchmarks.md).
NOISE_PX = 0.03


@lru_cache(maxsize=8)
def _scene(markers: str = "standard", seed: int = 0, frames: int = 2):
    return build_scene(SynthConfig(markers=markers, frames=frames, seed=seed))


def synthetic_detections(scene, frame: int, rng: np.random.Generator, noise: float = NOISE_PX):
    """Truth projections of the visible brim dots and markers, noisy and shuffled.

    Returns detections per camera and, per camera, the identity of each detection:
    marker index ``m >= 0`` or ``-1 - b`` for brim dot ``b``.
    """
    dets, ident = [], []
    for c in range(scene.n_cameras):
        bv = np.flatnonzero(scene.brim_visible[frame, :, c])
        mv = np.flatnonzero(scene.visible[frame, :, c])
        pts = np.concatenate([scene.brim_uv[frame, bv, c], scene.uv[frame, mv, c]])
        pts = pts + rng.normal(0.0, noise, pts.shape)
        idn = np.concatenate([-1 - bv, mv])
        perm = rng.permutation(len(pts))
        dets.append(pts[perm])
        ident.append(idn[perm])
    return dets, ident


def brim_index(ident, n_brim: int) -> np.ndarray:
    """Detection index of each brim dot per camera, -1 if not detected: (B, C)."""
    out = np.full((n_brim, len(ident)), -1)
    for c, idn in enumerate(ident):
        k = np.flatnonzero(idn < 0)
        out[-1 - idn[k], c] = k
    return out


def four_correspondences(bidx: np.ndarray) -> dict[int, list[tuple[int, int]]]:
    """Four brim dots spread over the visible part of the brim, per camera."""
    corr = {}
    for c in range(bidx.shape[1]):
        vis = np.flatnonzero(bidx[:, c] >= 0)
        pick = vis[[0, len(vis) // 3, 2 * len(vis) // 3, len(vis) - 1]]
        corr[c] = [(int(b), int(bidx[b, c])) for b in pick]
    return corr


def camera_errors(R, t, R_true, t_true):
    pos = np.linalg.norm(camera_centres(R, t) - camera_centres(R_true, t_true), axis=-1)
    return pos, rotation_error_deg(R, R_true)


def test_default_brims_are_distinct_plausible_bands():
    models = {v: default_brim(v) for v in DEFAULT_BRIM_VERSIONS}
    for v, (labels, xyz) in models.items():
        assert len(labels) == len(set(labels)) == len(xyz) >= 20, v
        # above the forehead, in front of the head centre, spread across the brow
        assert np.all(xyz[:, 1] > 60) and np.all(xyz[:, 2] > 60)
        assert np.ptp(xyz[:, 0]) > 150
        d = np.linalg.norm(xyz[:, None] - xyz[None], axis=-1) + np.eye(len(xyz)) * 1e9
        assert d.min() > 8.0  # dots do not touch
    assert len({len(m[1]) for m in models.values()}) == 3
    with pytest.raises(ValueError, match="unknown default brim"):
        default_brim("v3.0")


@pytest.mark.parametrize("seed", [0, 1, 4])
def test_manual_solve_meets_accuracy_with_four_correspondences(seed):
    scene = _scene(seed=seed)
    rng = np.random.default_rng(seed)
    dets, ident = synthetic_detections(scene, 0, rng)
    bidx = brim_index(ident, len(scene.brim3d))
    res = solve_brim_manual(dets, four_correspondences(bidx), scene.brim3d, scene.intrinsics)
    assert res.success, res.message
    pos, rot = camera_errors(res.R, res.t, scene.cam_R[0], scene.cam_t[0])
    assert pos.max() <= 0.2 and rot.max() <= 0.05, (pos, rot)
    # every matched brim dot is the right detection and nearly all visible dots are found
    m = res.matches >= 0
    assert np.array_equal(res.matches[m], bidx[m])
    assert m.sum() >= 0.95 * (bidx >= 0).sum()


@pytest.mark.parametrize("seed", [0, 2])
def test_auto_solve_from_rig_geometry_in_another_world_frame(seed):
    scene = _scene(seed=seed)
    rng = np.random.default_rng(100 + seed)
    dets, ident = synthetic_detections(scene, 1, rng)
    # the XCP rig: nominal (unflexed) cameras expressed in an arbitrary world frame
    Rw = rodrigues_to_matrix(np.array([0.3, -0.2, 1.0]))
    tw = np.array([100.0, -50.0, 30.0])
    rig_R = scene.nominal_R @ Rw.T
    rig_t = scene.nominal_t - np.einsum("cij,j->ci", rig_R, tw)
    res = solve_brim_auto(dets, scene.brim3d, scene.intrinsics, rig_R, rig_t)
    assert res.success, res.message
    pos, rot = camera_errors(res.R, res.t, scene.cam_R[1], scene.cam_t[1])
    assert pos.max() <= 0.2 and rot.max() <= 0.05, (pos, rot)
    bidx = brim_index(ident, len(scene.brim3d))
    m = res.matches >= 0
    assert np.array_equal(res.matches[m], bidx[m])


def test_auto_solve_ignores_a_false_detection_beside_a_hidden_dot():
    # one camera sees only 8 dots; a clutter blob (a cut dot, a marker) sits 2 px from
    # where a hidden dot projects, inside the match radius: it must not pull the camera
    scene = _scene(seed=1)
    dets, ident = synthetic_detections(scene, 1, np.random.default_rng(7))
    c = 2
    brim = np.flatnonzero(ident[c] < 0)
    keep = np.ones(len(dets[c]), dtype=bool)
    keep[brim[8:]] = False
    hidden = -1 - ident[c][brim[8]]
    false = scene.brim_uv[1, hidden, c] + np.array([1.6, -1.2])
    dets[c] = np.vstack([dets[c][keep], false])
    ident[c] = np.append(ident[c][keep], 10**6)
    res = solve_brim_auto(dets, scene.brim3d, scene.intrinsics, scene.nominal_R,
                          scene.nominal_t)
    assert res.success, res.message
    assert not np.any(res.matches[:, c] == len(dets[c]) - 1)
    pos, rot = camera_errors(res.R, res.t, scene.cam_R[1], scene.cam_t[1])
    assert pos.max() <= 0.2 and rot.max() <= 0.05, (pos, rot)


def test_auto_solve_with_a_wrong_calibration_fails_cleanly():
    scene = _scene()
    dets, _ = synthetic_detections(scene, 0, np.random.default_rng(3))
    rig_R = scene.nominal_R.copy()
    rig_t = scene.nominal_t.copy()
    rig_t[2] += np.array([40.0, 0.0, 0.0])  # one camera 40 mm off
    rig_R[3] = rodrigues_to_matrix(np.array([0.0, 0.3, 0.0])) @ rig_R[3]
    res = solve_brim_auto(dets, scene.brim3d, scene.intrinsics, rig_R, rig_t)
    # with two cameras far off the nominal rig, almost nothing triangulates: the brim is
    # not found, and the solve says so instead of returning wrong cameras
    assert not res.success
    assert res.message.startswith("Solve Calibration Brim [Automatic]: the brim model "
                                  "was not found"), res.message


def test_manual_solve_bad_input_gives_messages():
    scene = _scene()
    dets, ident = synthetic_detections(scene, 0, np.random.default_rng(1))
    bidx = brim_index(ident, len(scene.brim3d))
    corr = four_correspondences(bidx)
    few = dict(corr)
    few[2] = corr[2][:3]
    res = solve_brim_manual(dets, few, scene.brim3d, scene.intrinsics)
    assert not res.success and "cam2 has 3 brim correspondence" in res.message
    empty = list(dets)
    empty[1] = np.zeros((0, 2))
    res = solve_brim_manual(empty, corr, scene.brim3d, scene.intrinsics)
    assert not res.success and "no detections in camera(s) cam1" in res.message
    bad = dict(corr)
    bad[0] = corr[0][:3] + [(corr[0][3][0], 10_000)]
    res = solve_brim_manual(dets, bad, scene.brim3d, scene.intrinsics)
    assert not res.success and "no detection 10000" in res.message
    # four collinear (same-row, consecutive) dots cannot fix a pose
    row = [b for b in range(13) if bidx[b, 0] >= 0][:4]
    line = dict(corr)
    line[0] = [(b, int(bidx[b, 0])) for b in row]
    res = solve_brim_manual(dets, line, scene.brim3d, scene.intrinsics)
    if not res.success:
        assert "cam0" in res.message


def test_manual_solve_wrong_correspondence_is_not_accepted_silently():
    scene = _scene()
    dets, ident = synthetic_detections(scene, 0, np.random.default_rng(2))
    bidx = brim_index(ident, len(scene.brim3d))
    corr = four_correspondences(bidx)
    # swap two detections of camera 3: the four matches no longer fit one pose
    (b0, k0), (b1, k1) = corr[3][0], corr[3][3]
    corr[3][0], corr[3][3] = (b0, k1), (b1, k0)
    res = solve_brim_manual(dets, corr, scene.brim3d, scene.intrinsics)
    assert not res.success
    assert "cam3" in res.message


def test_match_by_projection_refuses_ambiguous():
    proj = np.array([[10.0, 10.0], [50.0, 50.0], [90.0, 90.0]])
    dets = np.array([[10.5, 10.0], [50.0, 51.0], [50.0, 49.2], [300, 300]])
    m = match_by_projection(proj, dets, max_distance=5.0, ambiguity_ratio=1.5)
    assert m.tolist() == [0, -1, -1]


def test_brim_exclusion_mask_covers_unmatched_brim_dots_only():
    scene = _scene()
    dets, ident = synthetic_detections(scene, 0, np.random.default_rng(7))
    mask = brim_exclusion_mask(dets, scene.brim3d, scene.cam_R[0], scene.cam_t[0],
                               scene.intrinsics)
    for c in range(4):
        assert mask[c][ident[c] < 0].all()
        assert mask[c][ident[c] >= 0].mean() < 0.03


def test_parameters_are_validated():
    with pytest.raises(ValueError, match="min_correspondences"):
        BrimSolveParameters(min_correspondences=3)
    with pytest.raises(ValueError, match="match_distance_px"):
        BrimSolveParameters(match_distance_px=-1.0)


# ------------------------------------------------------------------------------- SVG
def _svg(body: str, root: str = 'width="200mm" height="100mm" viewBox="0 0 400 200"') -> str:
    return (f'<?xml version="1.0"?>\n<svg xmlns="http://www.w3.org/2000/svg" {root}>'
            f"{body}</svg>")


def test_svg_brim_units_transforms_and_labels(tmp_path):
    body = ('<circle id="A" cx="0" cy="0" r="4"/>'
            '<g transform="translate(100, 20)"><circle cx="0" cy="0" r="4"/>'
            '<ellipse id="E" cx="10" cy="0" rx="4" ry="3" transform="scale(2)"/></g>'
            '<circle cx="400" cy="200" r="4"/>')
    p = tmp_path / "brim.svg"
    p.write_text(_svg(body))
    labels, xyz = read_brim_svg(p)
    assert labels == ["A", "Brim02", "E", "Brim04"]
    # 400 user units = 200 mm: 0.5 mm per unit, y flipped
    np.testing.assert_allclose(xyz, [[0, 0, 0], [50, -10, 0], [60, -10, 0], [200, -100, 0]])


def test_svg_brim_without_physical_size_uses_css_pixels(tmp_path):
    p = tmp_path / "px.svg"
    p.write_text(_svg("".join(f'<circle cx="{96 * i}" cy="0" r="5"/>' for i in range(4)),
                      root=""))
    _, xyz = read_brim_svg(p)
    np.testing.assert_allclose(xyz[:, 0], [0, 25.4, 50.8, 76.2])


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("<svg><circle", "not a well-formed SVG"),
        ('<?xml version="1.0"?><html/>', "is not an SVG file"),
        (_svg('<circle cx="1" cy="1" r="2"/>'), "holds 1 dot"),
        (_svg("".join(f'<circle id="x" cx="{i}" cy="0" r="1"/>' for i in range(4))),
         "repeat: x"),
        (_svg('<circle cx="a" cy="0" r="1"/>' * 4), "cx='a' is not a number"),
        (_svg('<circle cx="1" cy="0"/>' * 4), "has no r"),
        (_svg('<circle cx="1" cy="0" r="1" transform="wobble(3)"/>' * 4), "transform"),
        (_svg("", root='width="20furlong" viewBox="0 0 1 1"'), "unknown unit"),
    ],
)
def test_svg_brim_malformed_files_give_clear_errors(tmp_path, content, message):
    p = tmp_path / "bad.svg"
    p.write_text(content)
    with pytest.raises(CaraFileError, match=message) as exc:
        read_brim_svg(p)
    assert "bad.svg" in str(exc.value)


def test_svg_brim_missing_file(tmp_path):
    with pytest.raises(CaraFileError, match="cannot be read"):
        read_brim_svg(tmp_path / "nope.svg")


@pytest.mark.slow
def test_end_to_end_rendered_images_blob_detector_manual_and_auto():
    """Render the frame, detect blobs, solve from 4 hand matches and automatically."""
    from carapost.algorithms.blobs import BlobParameters, detect_blobs
    from carapost.synth.render import render_frame

    scene = build_scene(SynthConfig(markers="standard", frames=1, seed=11))
    dets = []
    for c in range(4):
        img = render_frame(scene, 0, c)
        dets.append(detect_blobs(img, BlobParameters()).centre.astype(np.float64))
    # hand matches: the detection nearest each chosen dot's true projection
    corr = {}
    w, h = scene.size
    for c in range(4):
        # dots well inside the image (the detector drops dots cut by its border)
        uv = scene.brim_uv[0, :, c]
        inside = (uv[:, 0] > 12) & (uv[:, 0] < w - 12) & (uv[:, 1] > 12) & (uv[:, 1] < h - 12)
        vis = np.flatnonzero(scene.brim_visible[0, :, c] & inside)
        pick = vis[[0, len(vis) // 3, 2 * len(vis) // 3, len(vis) - 1]]
        pairs = []
        for b in pick:
            d = np.linalg.norm(dets[c] - scene.brim_uv[0, b, c], axis=1)
            assert d.min() < 1.0
            pairs.append((int(b), int(np.argmin(d))))
        corr[c] = pairs
    res = solve_brim_manual(dets, corr, scene.brim3d, scene.intrinsics)
    assert res.success, res.message
    pos, rot = camera_errors(res.R, res.t, scene.cam_R[0], scene.cam_t[0])
    assert pos.max() <= 0.2 and rot.max() <= 0.05, (pos, rot)
    res2 = solve_brim_auto(dets, scene.brim3d, scene.intrinsics, scene.nominal_R,
                           scene.nominal_t)
    assert res2.success, res2.message
    pos, rot = camera_errors(res2.R, res2.t, scene.cam_R[0], scene.cam_t[0])
    assert pos.max() <= 0.2 and rot.max() <= 0.05, (pos, rot)
