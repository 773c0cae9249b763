"""Remove Spurious Points: points that are not markers go, with their reason; markers stay."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.codes import RECON_NONE, RECON_SINGLE_SENSOR, RECON_TRIANGULATED
from carapost.algorithms.spurious import find_spurious_points
from carapost.synth import SynthConfig, build_scene


@pytest.fixture(scope="module")
def fast_truth():
    """The fast preset's truth (the largest motion between neighbours of any preset)."""
    sc = build_scene(SynthConfig(preset="fast", frames=240, seed=2, size=(640, 360)))
    return sc.points3d


def test_every_marker_of_a_fast_take_is_kept(fast_truth):
    X = fast_truth
    recon = np.full(X.shape[:2], RECON_TRIANGULATED)
    assert find_spurious_points(X, recon, np.zeros(X.shape[1], int)) == []


def test_points_that_are_not_markers_are_found_with_their_reason(fast_truth):
    X = fast_truth
    F, M, _ = X.shape
    rng = np.random.default_rng(0)
    # a ghost that drifts over the face against its neighbours (two wrong blobs matched
    # across a caddy slide along each other's epipolar lines)
    ghost = X[:, 10] + np.c_[np.linspace(-20, 20, F), np.zeros(F), np.full(F, 9.5)]
    # a speck tracked for 6 frames only
    speck = np.full((F, 3), np.nan)
    speck[100:106] = X[100:106, 20] + [0.0, 4.0, 0.0]
    # a point seen by one camera nearly all the time
    lone = X[:, 30] + rng.normal(0, 0.05, (F, 3))
    Y = np.concatenate([X, ghost[:, None], speck[:, None], lone[:, None]], axis=1)
    recon = np.where(np.isfinite(Y[..., 0]), RECON_TRIANGULATED, RECON_NONE)
    recon[:, M + 2] = RECON_SINGLE_SENSOR
    recon[:15, M + 2] = RECON_TRIANGULATED  # 15 of 240 frames: enough frames, too few cameras
    found = find_spurious_points(Y, recon, np.zeros(Y.shape[1], int))
    reasons = {s.index: s.reason for s in found}
    assert set(reasons) == {M, M + 1, M + 2}
    assert reasons[M].startswith("moves unlike its neighbours")
    assert reasons[M + 1].startswith("too few frames")
    assert reasons[M + 2].startswith("too few cameras")


def test_brim_points_are_never_judged():
    X = np.zeros((20, 1, 3))
    assert find_spurious_points(X, np.zeros((20, 1), int), np.ones(1, int)) == []
