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


def test_a_blob_much_larger_than_the_markers_is_not_a_marker(fast_truth):
    """A nostril or an eye corner tracked like a marker: moves with the face, but its blob
    is twice the size of the take's markers at that depth."""
    from carapost.algorithms.spurious import blob_sizes_mm

    X = fast_truth[:40]
    F, M, _ = X.shape
    recon = np.full((F, M), RECON_TRIANGULATED)
    rng = np.random.default_rng(1)
    radius = rng.uniform(1.2, 2.0, M)  # mm, like the markers of another renderer
    radius[7] = 2.0 * np.median(radius)
    R = np.tile(np.eye(3), (F, 2, 1, 1))
    t = np.tile([0.0, 0.0, 150.0], (F, 2, 1))
    z = X[..., 2] + 150.0
    ax = np.repeat((600.0 * radius / z)[..., None, None], 2, axis=2).repeat(2, axis=3)
    size = blob_sizes_mm(X, ax, R, t, np.full(2, 600.0))
    assert np.allclose(size, radius, rtol=0.01)
    found = find_spurious_points(X, recon, np.zeros(M, int), blob_size_mm=size)
    assert [(s.index, s.reason.split(":")[0]) for s in found] == [(7, "blob unlike a marker")]


def test_misfit_alone_or_with_a_large_blob_marks_a_ghost(fast_truth):
    """A huge ray misfit alone is enough; a moderate one only with a large blob; a marker
    with either sign alone (a clipped blob, a marker near the lens) stays."""
    X = fast_truth
    F, M, _ = X.shape
    recon = np.full((F, M), RECON_TRIANGULATED)
    kind = np.zeros(M, int)
    size = np.full(M, 1.4)
    misfit = np.full(M, 1.0)
    misfit[0], size[0] = 540.0, 1.4     # rays far apart, marker-sized blob: ghost
    misfit[1], size[1] = 57.0, 2.5      # both weaker signs together: ghost
    misfit[2], size[2] = 46.0, 1.0      # a marker whose blobs are off: kept
    misfit[3], size[3] = 5.0, 2.4       # a large marker close to the lens: kept
    found = find_spurious_points(X, recon, kind, blob_size_mm=size, misfit=misfit)
    assert [(s.index, s.reason.split(":")[0]) for s in found] == [
        (0, "rays do not meet"), (1, "blob and rays unlike a marker's")]
