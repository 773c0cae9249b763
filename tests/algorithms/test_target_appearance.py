"""Target tracking through a changing appearance (carapost.algorithms.target_appearance).

Synthetic images with known truth: a dark disc on a textured background moving towards
a static dark band (an eye's lash line) and hidden at the band, as an upper-lid marker
in a blink; a disc whose ink fades.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carapost.algorithms.target_appearance import robust_refine, robust_score
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

YY, XX = np.mgrid[0:80, 0:96].astype(float)


def _disc(x: float, y: float, depth: float = 110.0, radius: float = 3.2) -> np.ndarray:
    return depth / (1 + np.exp((np.hypot(XX - x, YY - y) - radius) * 3))


@pytest.fixture(scope="module")
def lid():
    """A disc accelerating down onto a lash line, hidden from frame ``hide`` on."""
    rng = np.random.default_rng(3)
    bg = cv2.GaussianBlur(rng.normal(150, 12, (80, 96)), (0, 0), 1.5)
    band = 70 * np.exp(-0.5 * ((YY - 46) / 1.5) ** 2)
    ys = 20 + np.cumsum(np.r_[0, np.linspace(0.3, 3.5, 11)])
    hide = len(ys) - 1
    imgs = []
    for f in range(len(ys)):
        img = bg - band - (_disc(48.3, ys[f]) if f < hide else 0.0)
        imgs.append(np.clip(img + rng.normal(0, 1.5, img.shape), 0, 255).astype(np.uint8))
    return imgs, ys, hide


def _run(imgs, ys, **kw):
    return track_target(lambda f: imgs[f], {0: (48.3, ys[0])}, start=0, stop=len(ys) - 1,
                        direction=1, params=TargetTrackerParameters(search_size=41, **kw))


def test_follows_the_marker_up_to_the_occlusion_and_stops_at_it(lid):
    imgs, ys, hide = lid
    without = _run(imgs, ys, follow_appearance=False)
    r = _run(imgs, ys)
    # the keyframe pattern alone loses the marker a frame before it disappears ...
    assert without.reason == "threshold" and without.frames[-1] < hide
    # ... following the appearance keeps it to the last visible frame, accurately
    assert r.reason == "threshold" and r.frames[-1] == hide
    ok = r.tracked
    assert ok[1:hide].all() and not ok[hide]
    err = np.hypot(r.xy[ok, 0] - 48.3, r.xy[ok, 1] - ys[r.frames[ok]])
    assert err.max() < 0.3
    assert r.score[-1] < 0.9
    # frames the keyframe match tracked are untouched
    n = int(without.tracked.sum())
    np.testing.assert_array_equal(r.xy[1:n + 1], without.xy[1:n + 1])


def test_a_marker_vanishing_from_open_skin_still_stops_at_once():
    rng = np.random.default_rng(4)
    bg = cv2.GaussianBlur(rng.normal(150, 12, (80, 96)), (0, 0), 1.5)
    xs = 30 + 1.3 * np.arange(10)
    imgs = [np.clip(bg - (_disc(x, 40.2) if f < 6 else 0) + rng.normal(0, 1.5, bg.shape),
                    0, 255).astype(np.uint8) for f, x in enumerate(xs)]
    r = track_target(lambda f: imgs[f], {0: (xs[0], 40.2)}, start=0, stop=9, direction=1,
                     params=TargetTrackerParameters(search_size=41))
    assert r.reason == "threshold" and r.frames[-1] == 6 and not r.tracked[-1]


def test_robust_refinement_ignores_the_part_of_the_pattern_that_changed():
    rng = np.random.default_rng(5)
    bg = cv2.GaussianBlur(rng.normal(150, 10, (80, 96)), (0, 0), 1.5)
    tpl = (bg - _disc(48.0, 40.0))[30:51, 38:59]
    # the marker moved by (0.35, -0.25); a dark band now covers the pattern's lower rows
    img = bg - _disc(48.35, 39.75) - 60 * (YY > 46)
    xy, wt, ncc = robust_refine(img, (0, 0), tpl, (48.0, 40.0), weight_sigma=3.8)
    assert np.hypot(xy[0] - 48.35, xy[1] - 39.75) < 0.05
    assert ncc > 0.98
    assert wt.sum() == pytest.approx(1.0)
    # the plain (non-robust) NCC of the same patch is pulled down by the band
    patch = cv2.getRectSubPix(img.astype(np.float32), (21, 21), (48.35, 39.75))
    plain = np.corrcoef(patch.ravel(), tpl.ravel())[0, 1]
    assert plain < 0.9
    assert robust_score(patch.ravel().astype(float), tpl.ravel(),
                        np.full(441, 1 / 441)) > 0.95


def test_a_fading_marker_is_left_to_the_keyframe_match():
    """The appearance step follows changing surroundings, not a marker losing its ink:
    a faint marker would be matched less accurately than the keyframe match needs."""
    rng = np.random.default_rng(6)
    bg = cv2.GaussianBlur(rng.normal(150, 12, (80, 96)), (0, 0), 1.5)
    xs = 40 + 0.6 * np.arange(14)
    fade = np.clip(1.0 - 0.2 * np.arange(14), 0.2, 1.0)
    imgs = [np.clip(bg - fade[f] * _disc(x, 40.4) + rng.normal(0, 1.5, bg.shape),
                    0, 255).astype(np.uint8) for f, x in enumerate(xs)]
    runs = [track_target(lambda f: imgs[f], {0: (xs[0], 40.4)}, start=0, stop=13,
                         direction=1, params=TargetTrackerParameters(
                             search_size=41, follow_appearance=fa)) for fa in (False, True)]
    assert runs[0].reason == "threshold" and runs[0].frames[-1] < 13
    np.testing.assert_array_equal(runs[0].frames, runs[1].frames)
    np.testing.assert_array_equal(runs[0].xy, runs[1].xy)
    np.testing.assert_array_equal(runs[0].score, runs[1].score)
