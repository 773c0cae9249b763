"""Target tracking on the disc alone (carapost.algorithms.target_disc).

Synthetic images with known truth, made the way a painted marker looks: a skin texture
with a dark crease, moved with the head, and a disc of ink that darkens whatever skin is
under it by a factor, sliding over the skin onto the crease (an upper-lid marker closing
into a blink) and hidden from frame ``hide`` on.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carapost.algorithms import target_appearance, target_disc
from carapost.algorithms.target_disc import disc_model, disc_step, fit_disc
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

H, W = 96, 112
YY, XX = np.mgrid[0:H, 0:W].astype(float)


def _skin(dx: float, dy: float, rng_seed: int = 5) -> np.ndarray:
    """The skin moved by (dx, dy) px: texture times a dark crease along y = 52."""
    rng = np.random.default_rng(rng_seed)
    tex = cv2.GaussianBlur(rng.normal(130, 14, (H + 40, W + 40)), (0, 0), 1.6)
    crease = 1 - 0.55 * np.exp(-0.5 * ((YY + 20 - 52) / 2.0) ** 2)   # in the big frame
    big = np.zeros_like(tex)
    big[20:20 + H] = 1
    tex = tex * np.pad(crease[:H], ((20, 20), (20, 20)), mode="edge")
    M = np.float32([[1, 0, dx - 20], [0, 1, dy - 20]])
    return cv2.warpAffine(tex.astype(np.float32), M, (W, H), flags=cv2.INTER_CUBIC,
                          borderMode=cv2.BORDER_REFLECT).astype(np.float64)


def _frame(f: int, xs, ys, head, hide: int, rng) -> np.ndarray:
    img = _skin(*head[f])
    if f < hide:   # an elongated disc (a lid marker seen obliquely), 84 % ink
        r = np.hypot((XX - xs[f]) / 1.2, (YY - ys[f]) / 2.0)
        img = img * (1 - 0.84 / (1 + np.exp((r - 1.0) * 4)))
    img = cv2.GaussianBlur(img, (0, 0), 0.6) + rng.normal(0, 2.0, img.shape)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def lid():
    rng = np.random.default_rng(11)
    steps = np.r_[0, 0.1, 0.1, 0.15, 0.2, 0.4, 0.8, 1.4, 2.2, 3.0]
    ys = 40 + np.cumsum(steps)
    xs = 55.3 + 0.1 * np.arange(len(ys))
    head = np.stack([0.08 * np.arange(len(ys)), -0.12 * np.arange(len(ys))], axis=1)
    hide = len(ys) - 1
    imgs = [_frame(f, xs, ys, head, hide, rng) for f in range(len(ys))]
    return imgs, xs, ys, hide


def test_the_disc_is_found_on_the_crease_and_not_where_it_is_hidden(lid):
    imgs, xs, ys, hide = lid
    model = disc_model(imgs[0], (xs[0], ys[0]), 21)
    assert model is not None
    # the marker has slid 7 px over its skin, onto the crease: found within 0.15 px
    f = hide - 1
    xy, shift, amp, ncc = fit_disc(imgs[f], model, (xs[f] + 0.8, ys[f] - 0.9))
    assert np.hypot(xy[0] - xs[f], xy[1] - ys[f]) < 0.15
    assert 0.8 < amp < 1.25 and ncc > 0.95
    # the skin's own motion (the head) is found too: keyframe place of a frame's pixel
    np.testing.assert_allclose(shift, [-0.08 * f, 0.12 * f], atol=0.15)
    # the marker gone: the step fails (or scores below the Break Threshold)
    xy_h, score_h, _ = disc_step(imgs[hide], model, (xs[hide - 1], ys[hide - 1] + 3.0))
    assert not np.all(np.isfinite(xy_h)) or score_h < 0.9


def test_tracking_keeps_the_marker_to_its_last_visible_frame(lid, monkeypatch):
    imgs, xs, ys, hide = lid

    def run():
        return track_target(lambda f: imgs[f], {0: (xs[0], ys[0])}, start=0,
                            stop=len(ys) - 1, direction=1,
                            params=TargetTrackerParameters(search_size=41))

    def check(r):
        assert r.reason == "threshold" and r.frames[-1] == hide
        ok = r.tracked
        assert ok[1:hide].all() and not ok[hide] and r.score[-1] < 0.9
        err = np.hypot(r.xy[ok, 0] - xs[r.frames[ok]], r.xy[ok, 1] - ys[r.frames[ok]])
        assert err.max() < 0.3

    check(run())
    # where the appearance step fails too, the disc step alone keeps the marker ...
    monkeypatch.setattr(target_appearance, "appearance_step",
                        lambda *a, **k: a[7] if len(a) > 7 else k["failed"])
    check(run())
    # ... without it the track stops before the marker disappears
    monkeypatch.setattr(target_disc, "disc_step",
                        lambda *a, **k: (np.array([np.nan, np.nan]), 0.0, np.zeros(2)))
    without = run()
    assert without.reason == "threshold" and without.frames[-1] < hide


def test_no_disc_at_the_keyframe_gives_no_model():
    rng = np.random.default_rng(2)
    flat = np.clip(rng.normal(120, 2, (H, W)), 0, 255).astype(np.uint8)
    assert disc_model(flat, (56.0, 48.0), 21) is None
    # too near the border for the fit's window
    assert disc_model(flat, (5.0, 48.0), 21) is None


def test_the_disc_step_does_not_confirm_a_first_step(lid, monkeypatch):
    """A first step taken with the motion unknown is confirmed by the keyframe match
    alone: where the disc step would be needed inside the confirmation frames, the run
    loses the marker there and is cut back to its keyframe (the first step may have
    found the wrong place); once the first step is confirmed, the disc step carries the
    track on as before."""
    imgs, xs, ys, hide = lid
    monkeypatch.setattr(target_appearance, "appearance_step",
                        lambda *a, **k: a[7] if len(a) > 7 else k["failed"])
    used = []
    disc_step_ = target_disc.disc_step

    def recording(img, *a, **k):
        used.append(next(i for i, im in enumerate(imgs) if im is img))
        return disc_step_(img, *a, **k)

    monkeypatch.setattr(target_disc, "disc_step", recording)

    def run(confirm_frames):
        used.clear()
        # Confirm Score 1: the first step (frame 1) always needs confirming
        params = TargetTrackerParameters(search_size=41, confirm_score=1.0,
                                         confirm_frames=confirm_frames)
        return track_target(lambda f: imgs[f], {0: (xs[0], ys[0])}, start=0,
                            stop=len(ys) - 1, direction=1, params=params)

    # the keyframe match fails at frame 6 (the disc slid onto the crease)
    confirmed = run(confirm_frames=3)       # frames 2-4 confirmed the first step
    assert confirmed.tracked[1:hide].all() and min(used) == 6
    unconfirmed = run(confirm_frames=5)     # frame 6 is still confirming it
    assert not unconfirmed.tracked.any() and used == []
