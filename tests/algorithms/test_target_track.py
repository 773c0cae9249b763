"""Target tracking of one marker on synthetic images with exact sub-pixel truth.

The images are a band-limited texture translated by exact sub-pixel shifts (Fourier
shift) with dark anti-aliased discs drawn analytically at their true centres, so the
truth of every frame is known to machine precision.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from carapost.algorithms.target_track import (
    STOP_CANCELLED,
    STOP_END,
    STOP_KEYFRAME,
    STOP_LIMIT,
    STOP_THRESHOLD,
    TargetTrackerParameters,
    sample_patch,
    track_target,
)

H, W = 120, 160


def _texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.normal(0.0, 1.0, (H, W)), 2.0) * 60.0


def _shifted(tex: np.ndarray, dx: float, dy: float) -> np.ndarray:
    return np.fft.ifft2(ndimage.fourier_shift(np.fft.fft2(tex), (dy, dx))).real


def _disc(cx: float, cy: float, r: float = 4.5) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    d = np.hypot(xx - cx, yy - cy)
    return 1.0 / (1.0 + np.exp((d - r) * 2.5))   # smooth edge: exact, band-limited enough


class Scene:
    """Discs moving on a texture that moves with them (as skin under a marker)."""

    def __init__(self, n: int = 40, seed: int = 0, hide=(), neighbour: bool = False):
        rng = np.random.default_rng(seed + 10)
        steps = np.cumsum(rng.normal(0.0, 0.6, (n, 2)), axis=0)
        steps[0] = 0
        self.xy = np.array([70.3, 58.7]) + steps
        self.tex = _texture(seed)
        self.hide = set(hide)
        self.neighbour = neighbour
        self.n = n

    def image(self, f: int) -> np.ndarray:
        dx, dy = self.xy[f] - self.xy[0]
        img = 150.0 + _shifted(self.tex, dx, dy)
        if f not in self.hide:
            img -= 100.0 * _disc(*self.xy[f])
        if self.neighbour:
            img -= 100.0 * _disc(self.xy[f, 0] + 14.0, self.xy[f, 1])
        return np.clip(img, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def scene():
    return Scene()


def test_sample_patch_is_exact_on_linear_images():
    yy, xx = np.mgrid[0:30, 0:30].astype(float)
    img = 2.0 * xx + 3.0 * yy
    p = sample_patch(img, (12.37, 15.81), 5)
    assert abs(p[2, 2] - (2 * 12.37 + 3 * 15.81)) < 1e-3
    assert abs(p[2, 3] - p[2, 2] - 2.0) < 1e-4


def test_tracks_sub_pixel_motion_without_drift(scene):
    res = track_target(scene.image, {0: scene.xy[0]}, start=0, stop=scene.n - 1,
                       direction=1, params=TargetTrackerParameters(search_size=41))
    assert res.reason == STOP_END
    assert res.frames.tolist() == list(range(scene.n))
    err = np.linalg.norm(res.xy - scene.xy, axis=1)
    assert np.median(err[1:]) < 0.03 and err.max() < 0.08
    assert np.all(res.score[1:] > 0.95) and np.all(res.score <= 1.0)
    assert res.keyframe.tolist() == [True] + [False] * (scene.n - 1)


def test_tracks_backwards_and_blends_two_keyframes(scene):
    keys = {5: scene.xy[5], 30: scene.xy[30]}
    res = track_target(scene.image, keys, start=30, stop=0, direction=-1,
                       params=TargetTrackerParameters(search_size=41))
    assert res.reason == STOP_KEYFRAME          # Stop On Next Keyframe: stops before 5
    assert res.frames.tolist() == list(range(30, 5, -1))
    err = np.linalg.norm(res.xy - scene.xy[res.frames], axis=1)
    assert err.max() < 0.08


def test_passes_keyframes_when_not_stopping_on_them(scene):
    keys = {0: scene.xy[0], 10: scene.xy[10] + 0.25}   # a keyframe placed a bit off
    p = TargetTrackerParameters(search_size=41, stop_on_next_keyframe=False)
    res = track_target(scene.image, keys, start=0, stop=20, direction=1, params=p)
    assert res.reason == STOP_END and res.frames[-1] == 20
    i = res.frames.tolist().index(10)
    assert res.keyframe[i] and np.allclose(res.xy[i], keys[10]) and res.score[i] == 1.0


def test_stop_after_n_frames_and_at_stop(scene):
    p = TargetTrackerParameters(search_size=41, stop_after_n_frames=True, n_frames=4)
    res = track_target(scene.image, {0: scene.xy[0]}, start=0, stop=30, direction=1,
                       params=p)
    assert res.reason == STOP_LIMIT and res.frames.tolist() == [0, 1, 2, 3, 4]
    res = track_target(scene.image, {0: scene.xy[0]}, start=0, stop=2, direction=1,
                       params=TargetTrackerParameters(search_size=41))
    assert res.reason == STOP_END and res.frames.tolist() == [0, 1, 2]


def test_cancel_keeps_what_was_tracked(scene):
    calls = []

    def progress(done, total):
        calls.append((done, total))
        return done < 3

    res = track_target(scene.image, {0: scene.xy[0]}, start=0, stop=30, direction=1,
                       params=TargetTrackerParameters(search_size=41), progress=progress)
    assert res.reason == STOP_CANCELLED and res.frames.tolist() == [0, 1, 2, 3]
    assert calls[0] == (1, 30) and np.all(np.isfinite(res.xy))


def test_start_from_a_tracked_position(scene):
    res = track_target(scene.image, {0: scene.xy[0]}, start=12, stop=14, direction=1,
                       params=TargetTrackerParameters(search_size=41), start_xy=scene.xy[12])
    assert res.frames.tolist() == [12, 13, 14] and not res.keyframe.any()
    assert np.linalg.norm(res.xy[2] - scene.xy[14]) < 0.08


def test_stops_when_the_marker_disappears_without_jumping_to_a_neighbour():
    sc = Scene(n=30, seed=3, hide=range(15, 30), neighbour=True)
    res = track_target(sc.image, {0: sc.xy[0]}, start=0, stop=29, direction=1,
                       params=TargetTrackerParameters(search_size=41))
    assert res.reason == STOP_THRESHOLD
    assert res.frames[-1] == 15 and np.isnan(res.xy[-1]).all()
    assert res.score[-1] < 0.9
    err = np.linalg.norm(res.xy[:-1] - sc.xy[res.frames[:-1]], axis=1)
    assert err.max() < 0.1


@pytest.mark.parametrize(("keys", "kw", "message"), [
    ({0: (3.0, 60.0)}, {}, "does not fit"),
    ({}, {}, "at least one keyframe"),
    ({0: (70.0, 60.0)}, {"direction": 2}, "direction"),
    ({5: (70.0, 60.0)}, {"start": 0}, "not a keyframe"),
    ({0: (70.0, 60.0)}, {"stop": -3}, "behind"),
])
def test_bad_input_is_refused_with_a_message(scene, keys, kw, message):
    args = {"start": 0, "stop": 10, "direction": 1} | kw
    with pytest.raises(ValueError, match=message):
        track_target(scene.image, keys, params=TargetTrackerParameters(search_size=41),
                     **args)


def test_pattern_larger_than_search_or_image_is_refused(scene):
    with pytest.raises(ValueError, match="at least the Pattern Size"):
        TargetTrackerParameters(pattern_size=41, search_size=31)
    p = TargetTrackerParameters(pattern_size=131, search_size=131)
    with pytest.raises(ValueError, match="larger than the"):
        track_target(scene.image, {0: scene.xy[0]}, start=0, stop=3, direction=1, params=p)


def _static_scene(centres: list[np.ndarray], radii: list[float], ramp: float = 0.0
                  ) -> np.ndarray:
    """Discs on a background that does not move with them (smooth shading, a ramp of
    ``ramp`` grey levels per pixel along x), as when a marker slides over shading."""
    yy, xx = np.mgrid[0:H, 0:W]
    img = 120.0 + ramp * (xx - W / 2) + 15.0 * np.sin(yy / 17.0)
    for c, r in zip(centres, radii, strict=True):
        img -= 90.0 * _disc(*c, r=r)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_a_neighbour_moving_into_the_markers_place_is_never_taken_for_it():
    # marker A jumps 16 px down on the first frame and its neighbour B, a slightly
    # smaller disc 16 px above it, arrives where A was: without a motion history the
    # first step is checked against every candidate, and the track never reports B
    a0, step = np.array([80.3, 50.6]), np.array([0.4, 16.0])
    drift = np.array([0.3, 0.2])

    def centres(f: int) -> tuple[np.ndarray, np.ndarray]:
        a = a0 + (step if f else 0) + f * drift
        return a, a - np.array([0.0, 16.0])

    def image(f: int) -> np.ndarray:
        a, b = centres(f)
        return _static_scene([a, b], [4.0, 3.6])

    res = track_target(image, {0: a0}, start=0, stop=12, direction=1,
                       params=TargetTrackerParameters(search_size=61))
    ok = np.isfinite(res.xy[:, 0])
    for f, xy in zip(res.frames[ok], res.xy[ok], strict=True):
        a, b = centres(int(f))
        assert np.linalg.norm(xy - a) < np.linalg.norm(xy - b), f"frame {f} on the neighbour"
    if res.reason == STOP_END:   # followed: then accurately
        err = np.linalg.norm(res.xy[1:] - [centres(int(f))[0] for f in res.frames[1:]], axis=1)
        assert err.max() < 0.1


def test_a_marker_sliding_over_static_shading_is_tracked_without_bias():
    # a marker moving 0.35 px per frame over shading that stays put (a ramp and a
    # curved band): the refinement's gain, bias and shading terms absorb the change of
    # the background inside the pattern
    xy = np.array([60.2, 58.4]) + np.arange(25)[:, None] * np.array([0.35, 0.1])
    res = track_target(lambda f: _static_scene([xy[f]], [4.0], ramp=1.0), {0: xy[0]},
                       start=0, stop=24, direction=1,
                       params=TargetTrackerParameters(break_threshold=0.0))
    assert res.reason == STOP_END
    err = np.linalg.norm(res.xy - xy[res.frames], axis=1)
    assert err.max() < 0.05
