"""The first step of a Target Tracker run on a fast expression: the marker, not the
neighbour that moved into its place."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from carapost.algorithms.target_identity import assign_first_step, best_assignments
from carapost.algorithms.target_track import TargetTrackerParameters, track_target

H, W = 200, 160


def _disc(cx: float, cy: float, r: float = 3.0) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return 1.0 / (1.0 + np.exp((np.hypot(xx - cx, yy - cy) - r) * 2.5))


def _lips(n: int = 12, step=(-7.7, 33.6), offset=(20.5, -30.9), other_step=(-4.4, 24.0)):
    """Two lip markers (the tracked one and a neighbour ``offset`` px from it) moving
    ``step`` and ``other_step`` px on the first frame and slowing down after it (the
    mouth opening, as a lower-lip marker and the mouth corner of the fast take), on
    skin texture that stays (as in the renders)."""
    rng = np.random.default_rng(4)
    skin = 150.0 + ndimage.gaussian_filter(rng.normal(0, 1, (H, W)), 2.0) * 15.0
    decay = np.r_[0.0, np.cumsum(0.6 ** np.arange(n - 1))][:, None]
    own = np.array([90.3, 70.6]) + decay * np.asarray(step)
    other = own[0] + np.asarray(offset) + decay * np.asarray(other_step)
    imgs = [np.clip(skin - 90 * _disc(*own[f]) - 90 * _disc(*other[f]), 0, 255
                    ).astype(np.uint8) for f in range(n)]
    return imgs, own, other


def _track(imgs, start_xy, **kw):
    params = TargetTrackerParameters(**kw)
    return track_target(lambda f: imgs[f], {0: start_xy}, start=0, stop=len(imgs) - 1,
                        direction=1, params=params)


def _nearer_other(r, own, other) -> int:
    ok = np.isfinite(r.xy[:, 0]) & ~r.keyframe
    f = r.frames[ok]
    return int((np.linalg.norm(r.xy[ok] - other[f], axis=1)
                < np.linalg.norm(r.xy[ok] - own[f], axis=1)).sum())


def test_joint_assignment_prefers_the_coherent_move():
    prev = np.array([[0.0, 0.0], [0.0, -25.0], [40.0, 0.0]])
    new = np.array([[0.0, 5.0], [0.0, 30.0], [40.0, 30.0]])
    ranked = best_assignments(prev, new, 0, np.zeros(2), 40.0 ** 2)
    assert ranked[0][1] == 1          # the tracked disc went 30 px, not 5
    assert [c for _, c in ranked].count(-1) == 1 and len(ranked) == 4


def test_ambiguous_first_step_gives_no_position():
    prev = [(np.array([0.0, 0.0]), 1.0), (np.array([0.0, -20.0]), 0.9)]
    # one disc only in the new frame, 10 px from each: either could be it
    new = [(np.array([0.0, -10.0]), 0.9)]
    assert assign_first_step(prev, new, np.zeros(2), np.zeros(2), 40.0, 1.5) is None
    # two places equally far: a disc that matches the pattern clearly worse is no rival
    new = [(np.array([0.0, 10.0]), 0.95), (np.array([0.0, -10.0]), 0.8)]
    hit = assign_first_step(prev[:1], new, np.zeros(2), np.zeros(2), 40.0, 1.5)
    assert hit is not None and hit.tolist() == [0.0, 10.0]
    new = [(np.array([0.0, 10.0]), 0.95), (np.array([0.0, -10.0]), 0.9)]
    assert assign_first_step(prev[:1], new, np.zeros(2), np.zeros(2), 40.0, 1.5) is None
    # unlike discs (low NCC) are not candidates
    assert assign_first_step(prev, [(np.array([0.0, 1.0]), 0.5)], np.zeros(2),
                             np.zeros(2), 40.0, 1.5) is None


def test_first_step_never_takes_the_neighbour_in_its_place():
    # the marker moves 34.5 px; the neighbour arrives 17.5 px from where it was
    imgs, own, other = _lips()
    for bt in (0.9, 0.0):
        r = _track(imgs, own[0], break_threshold=bt)
        assert _nearer_other(r, own, other) == 0
        tracked = np.isfinite(r.xy[:, 0]) & ~r.keyframe
        if tracked.any():
            assert np.linalg.norm(r.xy[tracked] - own[r.frames[tracked]], axis=1).max() < 0.3


def test_first_step_that_cannot_be_told_from_the_neighbour_stops():
    # 45 px, the neighbour 30 px behind arriving 15 px from the marker's place: the
    # nearest moves prefer a 15 px move of the marker to two 45 px moves; the common
    # shift of the two discs does not (and the texture spots of the static skin, which
    # match the pattern's shape at a fraction of its contrast, do not hold it back)
    imgs, own, other = _lips(step=(0.0, 45.0), offset=(0.0, -30.0), other_step=(0.0, 45.0))
    for bt in (0.9, 0.0):
        r = _track(imgs, own[0], break_threshold=bt)
        assert _nearer_other(r, own, other) == 0


def test_first_step_with_the_lips_and_chin_moving_together():
    # noise 5 + blur, Chin_Crease camera 3: chin and lower lip move 30 px down together
    # on the first frame and the lip arrives 6 px from the chin's old place; the chin is
    # followed, not the lip (before the common shift the first step took the lip)
    imgs, own, other = _lips(step=(-8.4, 29.5), offset=(9.6, -38.2), other_step=(-7.4, 31.9))
    for bt in (0.9, 0.0):
        r = _track(imgs, own[0], break_threshold=bt)
        assert _nearer_other(r, own, other) == 0
        tracked = np.isfinite(r.xy[:, 0]) & ~r.keyframe
        assert tracked.sum() >= len(imgs) - 2
        assert np.linalg.norm(r.xy[tracked] - own[r.frames[tracked]], axis=1).max() < 0.15


def test_common_shift_prefers_the_group_move():
    # the chin (0) and two lip discs move about 30 px down; the middle lip disc arrives
    # 6 px from the chin's old place. Nearest moves: the chin goes to the lip's arrival
    prev = np.array([[622.5, 611.6], [632.6, 570.9], [582.4, 562.4]])
    new = np.array([[613.9, 642.0], [575.2, 593.3], [624.5, 605.6]])
    assert best_assignments(prev, new, 0, np.zeros(2), 820.0)[0][1] == 2
    assert best_assignments(prev, new, 0, np.zeros(2), 820.0, prior_weight=0.5)[0][1] == 0
