"""Target tracking through a fade (carapost.algorithms.target_fade).

Synthetic images with known truth: a dark disc painted on a textured skin that moves
with it; its ink fades to 20 % over three frames, holds, and comes back. The artist keys
it as painted before the fade, once on a faded frame, and as painted after it.
"""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.target_fade import contrasts_differ, disc_depth, fade_step
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

YY, XX = np.mgrid[0:80, 0:96].astype(float)
#: ink strength per frame: painted, a 3-frame fade to 20 %, held, a 3-frame return
STRENGTH = np.r_[1.0, 0.88, 0.6, 0.32, np.full(16, 0.2), 0.32, 0.6, 0.88, 1.0, 1.0]


def _skin(dx: float, dy: float) -> np.ndarray:
    """A skin texture (grey 100-140) carried along by (dx, dy), with a fixed shading
    ramp and a static dark line (a lip line that does not move with the marker)."""
    x, y = XX - dx, YY - dy
    tex = 120 + 9 * np.sin(x / 2.1 + y / 3.3) + 6 * np.cos(x / 1.3 - y / 2.7) \
        + 4 * np.sin(x / 4.9 - y / 1.7)
    return tex * (1 + 0.002 * (XX - 48)) - 25 * np.exp(-0.5 * ((YY - 58) / 1.2) ** 2)


def _frame(f: int, rng: np.random.Generator) -> tuple[np.ndarray, tuple[float, float]]:
    cx, cy = 40.0 + 0.43 * f, 36.0 + 0.17 * f + 0.6 * np.sin(f / 4)
    cover = 1 / (1 + np.exp((np.hypot(XX - cx, YY - cy) - 3.5) * 2.5))
    img = _skin(cx - 40, cy - 36) * (1 - 0.84 * STRENGTH[f] * cover)
    return np.clip(img + rng.normal(0, 0.7, img.shape), 0, 255).astype(np.uint8), (cx, cy)


@pytest.fixture(scope="module")
def fade():
    rng = np.random.default_rng(5)
    imgs, truth = zip(*(_frame(f, rng) for f in range(len(STRENGTH))), strict=True)
    return list(imgs), np.array(truth)


def _keyed(imgs, truth, keys, start, stop):
    return track_target(lambda f: imgs[f], {k: truth[k] for k in keys}, start=start,
                        stop=stop, direction=1,
                        params=TargetTrackerParameters(search_size=41))


def test_a_fade_keyed_as_painted_and_as_faded_is_tracked_through(fade):
    imgs, truth = fade
    last = len(STRENGTH) - 1
    keys = (0, 4, last)
    errs = []
    for start, stop in ((0, 4), (4, last)):
        r = _keyed(imgs, truth, keys, start, stop)
        assert r.reason == "keyframe"     # every frame in between tracked
        ok = r.tracked
        assert ok[1:].all()
        errs.extend(np.hypot(*(r.xy[ok] - truth[r.frames[ok]]).T))
    assert len(errs) == last - 2
    assert max(errs) < 0.12


def test_the_distance_blend_alone_is_off_on_the_faded_frames(fade, monkeypatch):
    """What the mixture is for: with the tracker's blend of the keyframes by distance in
    frames, the faded frames next to the painted keyframe are matched off the disc (or
    not at all)."""
    import carapost.algorithms.target_fade as tf

    imgs, truth = fade
    last = len(STRENGTH) - 1
    monkeypatch.setattr(tf, "fade_step", lambda img, k1, k2, f, pred, found, *a: found)
    r = _keyed(imgs, truth, (0, 4, last), 4, last)
    err = np.hypot(*(r.xy[1:] - truth[r.frames[1:]]).T)
    assert not (np.nan_to_num(err, nan=9.0) < 0.12).all()


def test_disc_depth_ignores_the_structure_around_the_marker(fade):
    imgs, truth = fade
    from carapost.algorithms.target_track import sample_patch

    painted = sample_patch(imgs[0], truth[0], 21)
    faded = sample_patch(imgs[8], truth[8], 21)
    assert contrasts_differ(painted, faded)
    # the skin's texture is in the top-hat too: the faded disc is 20 % of the painted
    # one, its depth with the texture under it well under half
    assert disc_depth(painted) > 2 * disc_depth(faded)
    # the same disc beside a different skin: one look, not a fade
    other = sample_patch(imgs[1], truth[1], 21)
    assert not contrasts_differ(painted, other)


def test_keyframes_of_one_look_leave_the_step_alone(fade):
    imgs, truth = fade
    from carapost.algorithms.target_track import sample_patch

    t1, t2 = sample_patch(imgs[0], truth[0], 21), sample_patch(imgs[last := 24], truth[last], 21)
    found = (truth[2] + 0.3, 0.95)
    cache: dict = {}
    xy, score = fade_step(imgs[2], (0, t1), (last, t2), 2, truth[2], found,
                          TargetTrackerParameters(search_size=41), cache)
    assert xy is found[0] and score == found[1]
    assert cache == {(0, last): None}
