"""Tests for carapost.algorithms.blobs on synthetic images with exact truth."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.blobs import (
    BlobDetections,
    BlobParameters,
    detect_blobs,
    detect_blobs_batch,
    preview_blobs,
)
from carapost.synth.blob_eval import (
    FaceScore,
    SynthScore,
    circlegrid_files,
    circlegrid_photo,
    projected_ellipses,
    synth_scene,
    synth_view,
)
from carapost.synth.blob_images import ellipse_coverage, paint, render_face


def _scene(rng, n=12, size=(160, 240), bg=180.0, fg=30.0, radius=(4.5, 9.0), ratio=(0.5, 1.0),
           noise=1.5):
    """Flat-ish background with anti-aliased ellipses on a grid; returns image and truth."""
    h, w = size
    img = np.full(size, bg, np.float64) + np.linspace(-10, 10, w)[None, :]
    centres, axes, angles = [], [], []
    cols = 6
    for i in range(n):
        cx = (i % cols + 0.5) * w / cols + rng.uniform(-2, 2)
        cy = (i // cols + 0.5) * h / ((n + cols - 1) // cols) + rng.uniform(-2, 2)
        a = rng.uniform(*radius)
        b = a * rng.uniform(*ratio)
        th = rng.uniform(-np.pi / 2, np.pi / 2)
        x0, y0, cov = ellipse_coverage(cx, cy, a, b, th)
        paint(img, x0, y0, cov, fg)
        centres.append((cx, cy))
        axes.append((a, b))
        angles.append(th)
    img += rng.standard_normal(size) * noise
    return (np.clip(np.rint(img), 0, 255).astype(np.uint8), np.array(centres), np.array(axes),
            np.array(angles))


def _match(det_centre, truth):
    d = np.linalg.norm(det_centre[:, None, :] - truth[None, :, :], axis=2)
    return d.argmin(axis=0), d.min(axis=0)


# ------------------------------------------------------------------ parameters


def test_parameter_defaults_follow_the_guide():
    p = BlobParameters()
    assert p.find_black_blobs and not p.find_white_blobs
    assert (p.black_min_radius, p.black_max_radius, p.black_threshold) == (4.0, 50.0, 0.4)
    assert (p.white_min_radius, p.white_max_radius, p.white_threshold) == (4.0, 50.0, 0.4)


@pytest.mark.parametrize(
    "kwargs, name",
    [({"black_threshold": 1.5}, "black_threshold"),
     ({"white_threshold": -0.1}, "white_threshold"),
     ({"black_min_radius": 0.0}, "black_min_radius"),
     ({"white_max_radius": float("nan")}, "white_max_radius"),
     ({"black_min_radius": 20.0, "black_max_radius": 10.0}, "black_min_radius"),
     ({"find_black_blobs": "yes"}, "find_black_blobs")],
)
def test_invalid_parameters_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        BlobParameters(**kwargs)


def test_bad_inputs_raise_clear_errors():
    p = BlobParameters()
    with pytest.raises(TypeError, match="uint8 or uint16"):
        detect_blobs(np.zeros((50, 50), np.float32), p)
    with pytest.raises(ValueError, match="2-D"):
        detect_blobs(np.zeros((50, 50, 3), np.uint8), p)
    with pytest.raises(ValueError, match="mask shape"):
        detect_blobs(np.zeros((50, 50), np.uint8), p, mask=np.ones((10, 10), bool))
    with pytest.raises(TypeError, match="BlobParameters"):
        detect_blobs(np.zeros((50, 50), np.uint8), {"black_threshold": 0.4})


# ------------------------------------------------------------------ geometry


def test_subpixel_centres_axes_and_angles(rng):
    img, centres, axes, angles = _scene(rng, n=18, size=(240, 300))
    det = detect_blobs(img, BlobParameters())
    assert len(det) == len(centres)
    idx, dist = _match(det.centre, centres)
    assert np.median(dist) < 0.05 and dist.max() < 0.15
    assert np.allclose(det.axes[idx], axes, atol=0.35)
    # Angle of the major axis, compared modulo pi, only where the ellipse is elongated.
    elong = axes[:, 1] / axes[:, 0] < 0.8
    dang = np.angle(np.exp(2j * (det.angle[idx] - angles)))[elong] / 2
    assert np.abs(dang).max() < 0.1
    assert det.centre.dtype == np.float32 and det.axes.dtype == np.float32
    assert np.all(det.colour == 0) and np.all((det.score >= 0.4) & (det.score <= 1))


def test_pixel_centre_convention():
    img = np.full((40, 40), 200, np.uint8)
    img[10:17, 20:27] = 20  # a 7x7 square: pixel centres 20..26 and 10..16
    det = detect_blobs(img, BlobParameters(black_min_radius=2.0))
    assert len(det) == 1
    np.testing.assert_allclose(det.centre[0], (23.0, 13.0), atol=0.02)


def test_radius_range_is_the_major_axis_length(rng):
    # Min / Max Radius bound the full length of the longest ellipse axis (2 a), as the
    # guide's measuring tool gives it across a blob.
    img, centres, axes, _ = _scene(rng, n=12, radius=(4.5, 9.0), ratio=(0.6, 1.0))
    det = detect_blobs(img, BlobParameters(black_min_radius=13.0, black_max_radius=50.0))
    _, dist = _match(det.centre, centres)
    found = dist < 1.0
    assert np.all(found[2 * axes[:, 0] > 13.6])
    # The lower bound has a documented 1 px tolerance on the measured length.
    assert not np.any(found[2 * axes[:, 0] < 11.4])
    assert np.all(2 * det.axes[:, 0] >= 12.0)
    # Max Radius: blobs longer than it are dropped.
    det = detect_blobs(img, BlobParameters(black_min_radius=4.0, black_max_radius=12.0))
    _, dist = _match(det.centre, centres)
    assert not np.any((dist < 1.0)[2 * axes[:, 0] > 12.6])
    assert np.all(2 * det.axes[:, 0] <= 12.0)


def test_small_markers_are_found_with_the_default_radius_range(rng):
    # Markers 5.5-7.5 px across (semi-major axis 2.8-3.7 px): inside the default
    # 4-50 px range of the longest axis, so every one of them is a detection.
    img, centres, axes, _ = _scene(rng, n=12, radius=(2.8, 3.7), ratio=(0.7, 1.0),
                                   fg=40.0)
    det = detect_blobs(img, BlobParameters())
    assert len(det) == len(centres)
    _, dist = _match(det.centre, centres)
    assert dist.max() < 0.15
    np.testing.assert_allclose(np.sort(2 * det.axes[:, 0]), np.sort(2 * axes[:, 0]), atol=0.6)


def test_white_blobs_only_when_asked(rng):
    img, centres, _, _ = _scene(rng, n=12, bg=60.0, fg=230.0)
    assert len(detect_blobs(img, BlobParameters())) == 0
    det = detect_blobs(img, BlobParameters(find_black_blobs=False, find_white_blobs=True))
    assert len(det) == len(centres) and np.all(det.colour == 1)
    _, dist = _match(det.centre, centres)
    assert dist.max() < 0.15


def test_threshold_is_monotonic(rng):
    s = render_face(rng, preset="standard", noise=4.0)
    counts = [len(detect_blobs(s.image, BlobParameters(black_threshold=t)))
              for t in (0.0, 0.4, 0.8, 1.0)]
    assert counts[0] >= counts[1] >= counts[2] >= counts[3]
    assert counts[0] > counts[1] and counts[3] < counts[1]


# ------------------------------------------------------------------ lighting


def test_saturated_regions_give_no_detections(rng):
    # A skin image with large saturated highlights whose gaps look like dark islands.
    img = np.full((200, 300), 190, np.uint8)
    img[20:80, 20:140] = 255
    img[90:180, 20:140] = 255
    img[20:180, 150:290] = 255
    img[40:60, 60:80] = 255
    noisy = np.clip(img + rng.normal(0, 1.5, img.shape), 0, 255).astype(np.uint8)
    noisy[img == 255] = 255
    both = BlobParameters(find_white_blobs=True)
    assert len(detect_blobs(noisy, both)) == 0
    all_white = np.full((100, 100), 255, np.uint8)
    assert len(detect_blobs(all_white, both)) == 0


def test_very_dark_image_still_works(rng):
    img, centres, _, _ = _scene(rng, n=12, bg=26.0, fg=4.0, noise=0.7)  # skin ~16-36
    det = detect_blobs(img, BlobParameters())
    assert len(det) == len(centres)
    _, dist = _match(det.centre, centres)
    assert dist.max() < 0.3


def test_uint16_gives_the_same_result_as_uint8(rng):
    img, _, _, _ = _scene(rng)
    a = detect_blobs(img, BlobParameters())
    b = detect_blobs(img.astype(np.uint16) << 4, BlobParameters())  # 12-bit image
    np.testing.assert_array_equal(a.centre, b.centre)


def test_mask_limits_the_region(rng):
    img, centres, _, _ = _scene(rng)
    mask = np.zeros(img.shape, bool)
    mask[:, : img.shape[1] // 2] = True
    det = detect_blobs(img, BlobParameters(), mask=mask)
    assert len(det) == np.sum(centres[:, 0] < img.shape[1] / 2 - 1)
    assert np.all(det.centre[:, 0] < img.shape[1] / 2)


# ------------------------------------------------------------------ face images


@pytest.mark.parametrize("preset", ["standard", "fast"])
def test_synthetic_face_recall_precision_and_centres(preset):
    rng = np.random.default_rng(2024)
    params = BlobParameters()
    score = FaceScore()
    for _ in range(2):
        s = render_face(rng, preset=preset, noise=2.0)
        score.add(s, detect_blobs(s.image, params), params)
    assert score.recall >= 0.98
    assert score.precision >= 0.97
    if preset == "standard":
        e = np.asarray(score.centre_err)
        assert np.median(e) <= 0.08 and np.percentile(e, 95) <= 0.25


# ------------------------------------------------------------------ carapost.synth takes


def test_projected_ellipse_of_a_frontal_disc():
    # A disc facing a distortion-free pinhole camera projects to a circle of radius f r / z.
    from carapost.algorithms.camera import CameraIntrinsics

    intr = CameraIntrinsics(focal=np.array([600.0]), principal_point=np.array([[320.0, 240.0]]),
                            aspect=np.ones(1), skew=np.zeros(1), radial=np.zeros((1, 3)),
                            distortion_centre=np.array([[320.0, 240.0]]),
                            image_size=np.array([[640.0, 480.0]]),
                            radial_model=["VICON_RADIAL2"], names=["c"])
    axes, centroid, ok = projected_ellipses(
        np.array([[0.0, 0.0, 150.0], [20.0, 0, 150.0]]),
        np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]]), np.array([2.0, 2.0]),
        np.eye(3), np.zeros(3), intr)
    assert ok.all()
    np.testing.assert_allclose(axes, 600 * 2.0 / 150.0, rtol=2e-3)
    np.testing.assert_allclose(centroid[1], (320 + 600 * 20 / 150.0, 240.0), atol=1e-6)


# The acceptance targets (recall, precision, centre median / p95 in px) ...
RECALL_TARGET, PRECISION_TARGET, MEDIAN_TARGET, P95_TARGET = 0.99, 0.98, 0.08, 0.25
# ... and what the detector reaches on carapost.synth today (regression guard; see
# docs/benchmarks.md for the gap).
RECALL_NOW, PRECISION_NOW, MEDIAN_NOW, P95_NOW = 0.985, 0.99, 0.08, 0.22


def _synth_score(markers, preset, frames, **options):
    params = BlobParameters()
    score = SynthScore()
    scene = synth_scene(markers, preset, seed=5, frames=max(frames) + 1, **options)
    for f in frames:
        for cam in range(scene.n_cameras):
            v = synth_view(scene, f, cam)
            score.add(v, detect_blobs(v.image, params), params)
    return score


def test_carapost_synth_take_regression():
    # One frame, four cameras of a standard-set speech take: face markers and brim dots.
    score = _synth_score("standard", "speech", [30])
    s = score.summary()
    assert score.expected > 250
    assert s["recall"] >= RECALL_NOW
    assert s["precision"] >= PRECISION_NOW
    assert s["centre_median_px"] <= MEDIAN_NOW and s["centre_p95_px"] <= P95_NOW
    assert s["false_per_image_background"] <= 0.25


def test_carapost_synth_take_meets_the_recall_target():
    s = _synth_score("standard", "speech", [30]).summary()
    assert s["recall"] >= RECALL_TARGET


def test_carapost_synth_take_meets_the_precision_and_centre_targets():
    s = _synth_score("standard", "speech", [30]).summary()
    assert s["precision"] >= PRECISION_TARGET
    assert s["centre_median_px"] <= MEDIAN_TARGET and s["centre_p95_px"] <= P95_TARGET


def test_shading_gradient_does_not_bias_the_centre(rng):
    # Dots on a steep linear shading ramp (1.5 grey levels per px, as strong as the
    # marker's own contrast over a few px): the ring plane removes the gradient.

    h, w = 80, 120
    xx = np.mgrid[0:h, 0:w][1]
    img = 40.0 + 1.5 * xx  # dark left, bright right
    truth = []
    for k, cx in enumerate((42.3, 61.7, 80.2)):
        cy = 20.4 + 20 * k
        x0, y0, cov = ellipse_coverage(cx, cy, 5.0, 4.0, 0.3)
        paint(img, x0, y0, cov, 20.0)
        truth.append((cx, cy))
    img = np.clip(np.rint(img + rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    det = detect_blobs(img, BlobParameters())
    assert len(det) == 3
    idx, dist = _match(det.centre, np.array(truth))
    assert dist.max() < 0.1


# The cells that miss a target today (one run of the whole matrix): three noise 5 cells
# miss the recall (0.985-0.989) or the centre p95 (0.25-0.26 px), the fast motion-blur
# cells the recall (0.984). Strict: a cell that starts passing fails the run until its
# mark is removed.
_MISSING_CELLS = {("noise", "speech", "dense156"), ("noise", "fast", "standard"),
                  ("noise", "fast", "dense156"), ("motion_blur", "fast", "standard"),
                  ("motion_blur", "fast", "dense156")}


def _matrix_cells() -> list:
    cells = []
    for option in ["none", "noise", "motion_blur", "merge_pair", "highlights"]:
        for preset in ["speech", "fast"]:
            for markers in ["standard", "dense156"]:
                marks = ([pytest.mark.xfail(reason="below a target today (see docs/benchmarks.md)")]
                         if (option, preset, markers) in _MISSING_CELLS else [])
                cells.append(pytest.param(markers, preset, option, marks=marks,
                                          id=f"{option}-{preset}-{markers}"))
    return cells


@pytest.mark.slow
@pytest.mark.parametrize(("markers", "preset", "option"), _matrix_cells())
def test_carapost_synth_takes_all_options(markers, preset, option):
    kw = {"none": {}, "noise": {"noise": 5.0}, "motion_blur": {"motion_blur": True},
          "merge_pair": {"merge_pair": True}, "highlights": {"highlights": True}}[option]
    s = _synth_score(markers, preset, [10, 70], **kw).summary()
    assert s["recall"] >= RECALL_TARGET
    assert s["precision"] >= PRECISION_TARGET
    if option != "motion_blur":
        assert s["centre_median_px"] <= MEDIAN_TARGET and s["centre_p95_px"] <= P95_TARGET


@pytest.mark.slow
def test_acceptance_targets_over_the_benchmark_views():
    # The acceptance figures as benchmarks/blobs.py measures them: noise 2,
    # noise 5 and motion blur, each over the standard and dense156 sets with the speech
    # and fast presets, frames 20 and 80, four cameras (96 views, ~9,500 markers).
    params = BlobParameters()
    score = SynthScore()
    sets = (("standard", "speech"), ("standard", "fast"), ("dense156", "speech"),
            ("dense156", "fast"))
    for k, options in enumerate(({}, {"noise": 5.0}, {"motion_blur": True})):
        for i, (markers, preset) in enumerate(sets):
            scene = synth_scene(markers, preset, seed=100 * k + i, frames=81, **options)
            for f in (20, 80):
                for cam in range(scene.n_cameras):
                    v = synth_view(scene, f, cam)
                    score.add(v, detect_blobs(v.image, params), params)
    s = score.summary()
    assert score.expected > 9000
    assert s["recall"] >= RECALL_TARGET
    assert s["precision"] >= PRECISION_TARGET
    assert s["centre_median_px"] <= MEDIAN_TARGET and s["centre_p95_px"] <= P95_TARGET


def test_blob_cut_by_the_image_corner_keeps_its_centre(rng):
    # Seeds near the border are refined on patches that reach outside the image; the
    # pixels outside must not count as background.
    img = np.full((60, 80), 180.0)
    truth = np.array([(7.3, 6.6), (72.6, 53.2), (40.2, 30.4)])
    for cx, cy in truth:
        x0, y0, cov = ellipse_coverage(cx, cy, 5.0, 4.5, 0.2)
        paint(img, x0, y0, cov, 30.0)
    img = np.clip(np.rint(img + rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    det = detect_blobs(img, BlobParameters())
    assert len(det) == 3
    _, dist = _match(det.centre, truth)
    assert dist.max() < 0.1


def test_blob_touching_the_image_border_is_kept(rng):
    # A large dot whose edge reaches into the outermost row but not past it (a brim dot
    # at the top of a view) is whole: it is detected with an unbiased centre. One cut
    # by the border beside it is not.
    img = np.full((100, 160), 170.0)
    truth = (50.3, 11.2)  # its top is 0.26 px above the centre of row 0
    for cx, cy, th in ((*truth, 1.45), (120.0, 6.0, 1.45)):
        x0, y0, cov = ellipse_coverage(cx, cy, 11.5, 8.5, th)
        paint(img, x0, y0, cov, 30.0)
    img = np.clip(np.rint(img + rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    det = detect_blobs(img, BlobParameters())
    assert len(det) == 1
    np.testing.assert_allclose(det.centre[0], truth, atol=0.1)


def test_compiled_refinement_matches_the_numpy_reference(rng, monkeypatch):
    # The compiled kernel and the numpy implementation of the refinement give the same
    # candidates (to float rounding), including seeds whose patch leaves the image and
    # seeds refined on reduced levels.
    from carapost.algorithms import blobs
    from carapost.algorithms.blobs import refine

    s = render_face(rng, preset="speech", noise=3.0)
    img = s.image.astype(np.float64)
    x0, y0, cov = ellipse_coverage(3.2, 40.4, 4.0, 3.0, 0.3)  # its ring leaves the image
    paint(img, x0, y0, cov, 20.0)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    got = blobs.blob_candidates(img, 0, 4.0, 80.0)
    monkeypatch.setattr(refine, "USE_JIT", False)
    ref = blobs.blob_candidates(img, 0, 4.0, 80.0)
    assert len(got.centre) == len(ref.centre) > 50
    assert ref.axes[:, 0].max() > 12  # some seeds were refined on a reduced level
    for x, y in zip(got, ref, strict=True):
        np.testing.assert_allclose(x, y, atol=2e-3)


def test_appearance_features_do_not_depend_on_mirroring(rng):
    # The appearance grids are folded about both ellipse axes, so a scene and its mirror
    # image (transposed: every angle mirrored) give each blob the same appearance
    # features, up to the bilinear sampling.
    from carapost.algorithms import blobs

    img, centres, _axes, _angles = _scene(rng, n=12, noise=0.5)
    names = blobs.FEATURE_NAMES
    look = slice(names.index("patch_0_0"), names.index("split"))
    got = blobs.blob_candidates(img, blobs.BLACK, 4.0, 50.0)
    mir = blobs.blob_candidates(np.ascontiguousarray(img.T), blobs.BLACK, 4.0, 50.0)
    i, d = _match(got.centre, centres)
    j, e = _match(mir.centre[:, ::-1], centres)
    assert d.max() < 0.2 and e.max() < 0.2
    np.testing.assert_allclose(got.features[i, look], mir.features[j, look], atol=0.06)


def test_context_features_see_a_dark_patch_beside_a_blob(rng):
    # A dark patch a few px beside a blob (not touching it) leaves the blob's centre
    # alone but shows in the asymmetry of its context grid.
    from carapost.algorithms import blobs

    img = np.full((80, 80), 170.0)
    x0, y0, cov = ellipse_coverage(40.3, 40.6, 6.0, 4.0, 0.0)
    paint(img, x0, y0, cov, 30.0)
    shadow = img.copy()
    shadow[36:46, 52:58] = 60.0  # 6 px beyond the blob's major axis end
    k = blobs.FEATURE_NAMES.index("context_asym_major")
    out = []
    for im in (img, shadow):
        im = np.clip(np.rint(im + rng.standard_normal(im.shape)), 0, 255).astype(np.uint8)
        c = blobs.blob_candidates(im, blobs.BLACK, 4.0, 50.0)
        i, d = _match(c.centre, np.array([(40.3, 40.6)]))
        assert d[0] < 0.1
        out.append(c.features[i[0], k])
    assert out[1] > out[0] + 0.1


def test_blob_cut_by_the_image_border_is_dropped(rng):
    # A dark blob cut in half by the bottom border (its centroid would be biased and its
    # shape is not its own) gives no detection; a whole one beside it does.
    img = np.full((100, 160), 170.0)
    for cx, cy in ((50.0, 99.0), (110.3, 60.2)):
        x0, y0, cov = ellipse_coverage(cx, cy, 9.0, 6.0, 0.0)
        paint(img, x0, y0, cov, 30.0)
    img = np.clip(np.rint(img + rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    det = detect_blobs(img, BlobParameters())
    assert len(det) == 1
    np.testing.assert_allclose(det.centre[0], (110.3, 60.2), atol=0.1)


def _markers_by_a_nostril(rng):
    """Images of two markers touching a nostril-sized dark ellipse (gap 0-1 px)."""
    out = []
    for gap in (0.0, 0.5, 1.0):
        img = np.full((120, 160), 170.0)
        x0, y0, cov = ellipse_coverage(70.0, 60.0, 22.0, 12.0, 0.0)
        paint(img, x0, y0, cov, 45.0)
        truth = np.array([(70.0 + 22 + 5.0 + gap, 60.3), (70.4, 60 - 12 - 4.5 - gap)])
        for cx, cy in truth:
            x0, y0, cov = ellipse_coverage(cx, cy, 5.0, 4.2, 0.4)
            paint(img, x0, y0, cov, 25.0)
        img = np.clip(np.rint(img + rng.standard_normal(img.shape) * 1.5), 0, 255)
        out.append((img.astype(np.uint8), truth))
    return out


def test_markers_by_a_nostril_need_the_split_seeds(rng, monkeypatch):
    # Without cutting over-size regions again, the joined region gives no candidate.
    from carapost.algorithms.blobs import seeds

    monkeypatch.setattr(seeds, "SPLIT_SEEDS", False)
    found = 0
    for img, truth in _markers_by_a_nostril(rng):
        det = detect_blobs(img, BlobParameters())
        if len(det):
            _, dist = _match(det.centre, truth)
            found += int(np.sum(dist < 0.5))
    assert found <= 2


def test_marker_on_a_dark_crease_is_found(rng):
    # A marker lying on a dark crease line (less contrast than the paint): their joined
    # region is an elongated band too long for the marker's level.
    img = np.full((100, 160), 150.0)
    cv2 = pytest.importorskip("cv2")
    line = np.zeros_like(img)
    cv2.line(line, (5, 40), (155, 62), 1.0, 3, cv2.LINE_AA)
    line = cv2.GaussianBlur(line, (5, 5), 1.0)
    img -= 70.0 * line
    truth = np.array([(80.3, 51.6)])
    x0, y0, cov = ellipse_coverage(*truth[0], 5.5, 4.0, 0.3)
    paint(img, x0, y0, cov, 20.0)
    img = np.clip(np.rint(img + rng.standard_normal(img.shape)), 0, 255).astype(np.uint8)
    det = detect_blobs(img, BlobParameters())
    assert len(det) >= 1
    _, dist = _match(det.centre, truth)
    assert dist[0] < 1.0


def test_marker_touching_a_large_dark_feature_is_found(rng):
    # A marker whose half-contrast region joins a nostril-sized dark ellipse: the joined
    # region is too large for the marker's level; cutting it again at a stricter
    # contrast separates the marker (a split seed).
    found = 0
    for img, truth in _markers_by_a_nostril(rng):
        det = detect_blobs(img, BlobParameters())
        _, dist = _match(det.centre, truth)
        found += int(np.sum(dist < 0.5))
    assert found >= 5


def test_preview_matches_detection(rng):
    s = render_face(rng, preset="speech")
    a, b = detect_blobs(s.image, BlobParameters()), preview_blobs(s.image, BlobParameters())
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


# ------------------------------------------------------------------ batch


@pytest.mark.parametrize("processes", [False, True])
def test_batch_matches_single_images_and_reports_progress(processes):
    # 10 images: two full tasks of the worker processes (PROCESS_CHUNK 4) and a part.
    images = {k: _scene(np.random.default_rng(k))[0] for k in (*range(6), 8, 9)}
    # A 12-bit image and one of another size (it does not fit the shared-memory slots).
    images[6] = images[0].astype(np.uint16) << 4
    images[7] = _scene(np.random.default_rng(7), size=(200, 300))[0]
    seen = []

    def progress(done, total):
        seen.append((done, total))
        return True

    out = detect_blobs_batch(images.__getitem__, list(images), BlobParameters(),
                             workers=2, progress=progress, processes=processes)
    assert set(out) == set(images)
    for k, img in images.items():
        ref = detect_blobs(img, BlobParameters())
        assert len(ref) >= 12
        for x, y in zip(out[k], ref, strict=True):
            np.testing.assert_array_equal(x, y)
    # after each finished image (and, with the count unchanged, before each read)
    done = [d for d, _ in seen]
    assert done == sorted(done) and sorted(set(done)) == list(range(11))
    assert all(t == 10 for _, t in seen)


def test_batch_in_processes_applies_the_mask_and_reports_errors():
    img = _scene(np.random.default_rng(3))[0]
    mask = np.zeros(img.shape, bool)
    mask[:, : img.shape[1] // 2] = True
    out = detect_blobs_batch(lambda k: img, range(3), BlobParameters(), mask=mask,
                             processes=True)
    ref = detect_blobs(img, BlobParameters(), mask=mask)
    assert 0 < len(ref) < 12
    assert all(np.array_equal(v.centre, ref.centre) for v in out.values())
    with pytest.raises(ValueError, match="2-D"):
        detect_blobs_batch(lambda k: np.zeros((20, 20, 3), np.uint8), range(3),
                           BlobParameters(), processes=True)
    with pytest.raises(TypeError, match="uint8 or uint16"):
        detect_blobs_batch(lambda k: img.astype(np.float32), range(3), BlobParameters(),
                           processes=True)


def test_batch_cancel_keeps_finished_frames():
    img = _scene(np.random.default_rng(1))[0]
    fetched = []

    def get(k):
        fetched.append(k)
        return img

    out = detect_blobs_batch(get, range(100), BlobParameters(), workers=2,
                             progress=lambda done, total: done < 3)
    assert 3 <= len(out) < 100
    assert set(out) <= set(fetched) and len(fetched) < 100
    assert all(isinstance(v, BlobDetections) and len(v) == 12 for v in out.values())


def test_batch_empty_and_bad_workers():
    assert detect_blobs_batch(lambda k: None, [], BlobParameters()) == {}
    with pytest.raises(ValueError, match="workers"):
        detect_blobs_batch(lambda k: None, [1], BlobParameters(), workers=0)


def test_shutdown_workers_stops_the_processes_and_a_later_batch_restarts_them():
    from carapost.algorithms.blobs import shutdown_workers

    img = _scene(np.random.default_rng(2))[0]
    assert len(detect_blobs_batch(lambda k: img, range(2), BlobParameters(),
                                  processes=True)) == 2
    shutdown_workers()
    shutdown_workers()  # a second call is a no-op
    out = detect_blobs_batch(lambda k: img, range(2), BlobParameters(), processes=True)
    assert all(len(v) == 12 for v in out.values())


# ------------------------------------------------------------------ packaging


def test_detector_imports_no_harness_and_loads_its_model_from_package_data():
    # The product detector never imports the synthetic-image harnesses (carapost.synth),
    # and its weights come from the package resources.
    import subprocess
    import sys

    code = ("import sys; import carapost.algorithms.blobs as b; "
            "from carapost.algorithms.blobs.score import load_model; "
            "assert len(load_model()) == len(b.MODEL_KINDS); "
            "print(sorted(m for m in sys.modules if m.startswith('carapost.synth')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]"



@pytest.mark.parametrize("module", ["carapost.synth.blob_images", "carapost.synth.blob_eval"])
def test_examples_of_the_harness_docstrings(module):
    # carapost.synth is outside the doctest paths of the pytest configuration.
    import doctest
    import importlib

    res = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert res.attempted > 0 and res.failed == 0

# ------------------------------------------------------------------ real photos


def test_real_circlegrid_photos_every_dot_found(fixtures_dir):
    files = circlegrid_files(fixtures_dir / "circlegrid")
    if not files:
        pytest.skip("no circlegrid photos in the fixtures")
    ours, theirs = [], []
    for path, pattern, flags in files:
        r = circlegrid_photo(path, pattern, flags)
        assert r["matched"] == r["expected"], path.name
        ours.append(r["rms_ours"])
        theirs.append(r["rms_opencv"])
    # Our centres fit the grid at least as well as OpenCV's overall.
    assert np.sqrt(np.mean(np.square(ours))) <= np.sqrt(np.mean(np.square(theirs))) * 1.02


def test_thin_blurred_oblique_markers_are_centred_without_bias():
    # A marker seen at a grazing angle is a thin ellipse (semi-axes 3.5 x 1.2 px); the
    # optics blur it (sigma 0.7 px) so its tail reaches the edge of the refinement
    # support, and which tail pixels fall inside depends on the sub-pixel position.
    # The centre ignores the lowest coverage (CENTRE_DEAD_ZONE), so the error stays a
    # small fraction of a pixel wherever the marker lies (0.024 px RMS when every
    # support pixel counted).
    import cv2

    rng = np.random.default_rng(7)
    err = []
    for _ in range(30):
        img = np.full((48, 48), 150.0)
        cx, cy = 24 + rng.random(), 24 + rng.random()
        x0, y0, cov = ellipse_coverage(cx, cy, 3.5, 1.2, rng.uniform(0, np.pi))
        paint(img, x0, y0, cov, 40.0)
        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.7)
        det = detect_blobs(np.clip(img + 0.5, 0, 255).astype(np.uint8), BlobParameters())
        assert len(det) <= 1
        if len(det):  # a few so thin and noise-free ones score below the threshold
            err.append(det.centre[0] - (cx, cy))
    assert len(err) >= 25
    assert np.sqrt(np.mean(np.square(err))) < 0.016
