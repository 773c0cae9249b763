"""Sub-pixel refinement of the Target Tracker: resampling and the marker weight.

The images are drawn analytically (area-sampled discs, exact sub-pixel truth); the
tests compare the tracker's error with the error of the simpler choice each piece
replaces, on the same images.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

import carapost.algorithms.target_track as tt
from carapost.algorithms.target_refine import cubic6_weights, marker_weight, shift_patch
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

H, W = 96, 128


def _disc(cx: float, cy: float, r: float, rx: float = 1.0, ss: int = 8) -> np.ndarray:
    """Coverage (0-1) of an ellipse (semi-axes r * rx, r) area-sampled ss x ss per px."""
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    x = xx[..., None, None] + sub[None, None, None, :]
    y = yy[..., None, None] + sub[None, None, :, None]
    return (((x - cx) / rx) ** 2 + (y - cy) ** 2 < r * r).mean(axis=(2, 3))


def test_cubic6_is_exact_on_cubics_and_sums_to_one():
    x = np.arange(-2, 4, dtype=float)
    for t in (0.0, 0.13, 0.5, 0.87):
        w = cubic6_weights(t)
        assert w.sum() == pytest.approx(1.0, abs=1e-12)
        for k in (1, 2, 3):
            assert w @ x ** k == pytest.approx(t ** k, abs=1e-12)


def test_shift_patch_repeats_the_border_outside_the_crop():
    crop = np.arange(64, dtype=np.float64).reshape(8, 8)
    p = shift_patch(crop, 1.0, 1.0, 5)   # the patch starts one pixel outside the crop
    assert p.shape == (5, 5)
    assert p[0, 0] == pytest.approx(crop[0, 0]) and p[2, 2] == pytest.approx(crop[1, 1])


def _phase_bias(shift) -> float:
    """Largest error of the position of a sharp disc found by Lucas-Kanade, over
    sub-pixel phases, when ``shift`` resamples both the pattern and the image."""
    saved = tt.shift_patch   # the sampler the tracker's refinement calls
    tt.shift_patch = shift
    try:
        worst = 0.0
        x0, y0 = 60.0, 48.0
        # optical blur as in the renders (sigma 0.6 px)
        key = 255.0 - 200.0 * ndimage.gaussian_filter(_disc(x0, y0, 2.2), 0.6)
        tpl = tt._normalise(tt.sample_patch(key, (x0, y0), 21))
        ref = tt._Refiner(tpl, 0.18 * 21, marker=False)
        for d in np.linspace(0.05, 0.95, 7):
            img = 255.0 - 200.0 * ndimage.gaussian_filter(
                _disc(x0 + 3 + d, y0 - 2 + 0.6 * d, 2.2), 0.6)
            truth = np.array([x0 + 3 + d, y0 - 2 + 0.6 * d])
            xy, _, _ = ref.refine(img, (0, 0), np.round(truth), 20, 1e-6)
            worst = max(worst, float(np.hypot(*(xy - truth))))
        return worst
    finally:
        tt.shift_patch = saved


def _keys4_shift(crop, x, y, size):
    """The 4-point Keys cubic (a = -0.5) the 6-point kernel replaced."""
    def w4(t):
        t2, t3 = t * t, t * t * t
        return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0,
                -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)
    h = size // 2
    ix, iy = int(np.floor(x)), int(np.floor(y))
    wx, wy = w4(x - ix), w4(y - iy)
    rows = crop[iy - h - 1:iy - h + size + 2]
    tmp = sum(wy[k] * rows[k:k + size] for k in range(4))
    c0 = ix - h - 1
    return sum(wx[k] * tmp[:, c0 + k:c0 + k + size] for k in range(4))


def test_six_point_resampling_biases_a_sharp_disc_less_than_four_point():
    ours, keys4 = _phase_bias(shift_patch), _phase_bias(_keys4_shift)
    # measured: 0.017 px against 0.027 px
    assert ours < 0.7 * keys4
    assert ours < 0.02


def test_marker_weight_keeps_the_blob_and_drops_a_nearby_edge():
    yy, xx = np.mgrid[0:21, 0:21]
    img = np.where(xx > 16, 220.0, 90.0) - 50.0 * (np.hypot(xx - 10, yy - 10) < 1.6)
    tpl = (img - img.mean()) / img.std()
    w = marker_weight(tpl, 3.8)
    assert w[10, 10] == w.max()
    assert w[10, 18:].max() < 0.01 * w.max()
    # no blob at the centre: the Gaussian window unchanged
    flat = np.where(xx > 16, 1.0, -1.0).astype(float)
    g = marker_weight(flat, 3.8)
    assert g[10, 10] == pytest.approx(1.0) and g[10, 0] == pytest.approx(np.exp(-50 / 3.8 ** 2))


def test_small_marker_beside_a_static_edge_is_tracked_to_its_centre():
    """A small, faint, oblique marker 8 px from the rim of a dark region that does not
    move with it (a lower-lid marker under the eye): the marker weight follows the
    marker, the Gaussian window alone is pulled by the rim."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    eye = np.hypot(xx - 51.0, yy - (47.6 - 12.0 - 8.0)) - 12.0    # px outside the eye
    skin = 60.0 + 120.0 / (1.0 + np.exp(-eye * 1.2))
    rng = np.random.default_rng(3)
    n = 30
    path = np.array([50.2, 47.6]) + np.cumsum(
        np.vstack([[0, 0], rng.normal(0, 0.35, (n - 1, 2))]), axis=0)
    imgs = [np.clip(skin * (1.0 - 0.35 * _disc(*path[f], 1.6, rx=0.6)) + 0.5, 0, 255
                    ).astype(np.uint8) for f in range(n)]
    params = TargetTrackerParameters(break_threshold=0.0, search_size=41)

    def err() -> float:
        r = track_target(lambda f: imgs[f], {0: path[0]}, start=0, stop=n - 1, direction=1,
                         params=params)
        assert r.reason == "end"
        return float(np.median(np.linalg.norm(r.xy[1:] - path[1:], axis=1)))

    ours = err()
    saved = tt.marker_weight
    tt.marker_weight = lambda tpl, sigma: saved(tpl, sigma, min_contrast=np.inf)  # window
    try:
        window_only = err()
    finally:
        tt.marker_weight = saved
    # measured: 0.039 px against 0.110 px
    assert ours < 0.06
    assert ours < 0.5 * window_only
