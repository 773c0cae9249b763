"""The keyframe match polished on log grey levels (carapost.algorithms.target_polish).

Synthetic images with known truth: a marker whose ink darkens the skin under it by a
factor (``skin * (1 - ink)``, as the renderer and real ink do) slides down into a broad
dark crease that does not move with it.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carapost.algorithms.target_polish import log_grey
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

YY, XX = np.mgrid[0:80, 0:96].astype(float)


def _ink(x: float, y: float, radius: float = 2.4, opacity: float = 0.8) -> np.ndarray:
    """A slightly tall disc's ink opacity (0-1)."""
    return opacity / (1 + np.exp((np.hypot(XX - x, (YY - y) / 1.4) - radius) * 3))


@pytest.fixture(scope="module")
def crease():
    """A marker accelerating down towards a broad, static dark crease (centre y = 46)."""
    rng = np.random.default_rng(3)
    skin = cv2.GaussianBlur(rng.normal(150, 12, (80, 96)), (0, 0), 1.5)
    skin = skin - 130 * np.exp(-0.5 * ((YY - 46) / 5.0) ** 2)
    ys = 30 + np.cumsum(np.r_[0, np.linspace(0.2, 1.6, 10)])
    imgs = [np.clip(skin * (1 - _ink(48.3, y)) + rng.normal(0, 1.0, skin.shape), 0, 255
                    ).astype(np.uint8) for y in ys]
    return imgs, ys


def _errors(imgs, ys, log_offset: float) -> np.ndarray:
    r = track_target(lambda f: imgs[f], {0: (48.3, ys[0])}, start=0, stop=len(ys) - 1,
                     direction=1, params=TargetTrackerParameters(
                         search_size=41, log_offset=log_offset, follow_appearance=False,
                         break_threshold=0.0))
    assert r.reason == "end" and r.tracked[1:].all()
    return np.hypot(r.xy[:, 0] - 48.3, r.xy[:, 1] - ys[r.frames])


def test_log_polish_follows_a_marker_into_a_shadow(crease):
    imgs, ys = crease
    grey, log = _errors(imgs, ys, 0.0), _errors(imgs, ys, 16.0)
    # on grey levels the marker's lower half fades into the crease and the fit is
    # pulled up (towards the part still over bright skin); its log look is unchanged
    assert grey[5:].max() > 0.2
    assert log[5:].max() < 0.15
    assert log[5:].max() < 0.6 * grey[5:].max()
    # where the skin is even, the polish changes little
    assert np.abs(log[:4] - grey[:4]).max() < 0.02


def test_log_polish_keeps_the_score_and_the_frames(crease):
    """Only the position is polished: the search and the score stay on grey levels."""
    imgs, ys = crease
    runs = [track_target(lambda f: imgs[f], {0: (48.3, ys[0])}, start=0,
                         stop=len(ys) - 1, direction=1,
                         params=TargetTrackerParameters(search_size=41, log_offset=off,
                                                        follow_appearance=False))
            for off in (0.0, 16.0)]
    np.testing.assert_array_equal(runs[0].frames, runs[1].frames)
    np.testing.assert_allclose(runs[0].score, runs[1].score, atol=1e-12)


def test_log_grey_table_is_the_formula():
    g = np.arange(256)
    table = log_grey(g.astype(np.uint8), 16.0)
    direct = log_grey(g.astype(np.float64), 16.0)
    np.testing.assert_allclose(table, direct, rtol=0, atol=1e-4)
    # grey levels at mid-grey, with slope 1 there; darker levels are stretched
    assert table[128] == pytest.approx(128.0, abs=1e-4)
    assert table[129] - table[127] == pytest.approx(2.0, abs=0.01)
    assert table[21] - table[20] > 3.5
