"""Find Problems' spike test against fast but consistent motion (blinks) and against
spikes of a neighbour, on synthetic trajectories with known problems."""

from __future__ import annotations

import numpy as np

from carapost.algorithms.cleanup import find_spikes


def _face(frames: int = 1200, seed: int = 0) -> np.ndarray:
    """Eight points on a slowly moving, slowly deforming patch, 0.05 mm noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 60.0
    base = rng.normal(size=(8, 3)) * [15.0, 15.0, 5.0]
    head = np.stack([5 * np.sin(0.7 * t), 3 * np.cos(0.5 * t), np.sin(0.3 * t)], -1)
    X = base[None] + head[:, None] + 0.5 * np.sin(1.3 * t)[:, None, None] * base[None] / 15
    return X + rng.normal(scale=0.05, size=X.shape)


def _blinks(X: np.ndarray, point: int, every: int = 67, size: float = 4.5) -> np.ndarray:
    """Very fast blinks: a Gaussian bump of ``size`` mm, sigma 0.9 frame, always along
    the same direction, at irregular intervals around ``every`` frames."""
    F = X.shape[0]
    rng = np.random.default_rng(1)
    centres = np.cumsum(rng.uniform(0.7, 1.3, F // every + 2) * every)
    centres = centres[centres < F - 5] + rng.uniform(-0.5, 0.5, len(centres[centres < F - 5]))
    f = np.arange(F)[:, None]
    act = np.minimum(np.exp(-0.5 * ((f - centres[None]) / 0.9) ** 2).sum(1), 1.0)
    Y = X.copy()
    Y[:, point] += act[:, None] * size * np.array([0.0, -0.96, 0.28])
    return Y


def test_repeated_fast_blinks_are_not_spikes_but_a_spike_on_the_lid_is() -> None:
    X = _blinks(_face(), point=2)
    assert find_spikes(X) == []
    Y = X.copy()
    Y[500, 2] += [4.0, 2.0, -3.0]                       # a spike in another direction
    got = [(s.point, s.start) for s in find_spikes(Y)]
    assert got == [(2, 500)]


def test_a_jump_that_repeats_without_intermediate_samples_stays_a_spike() -> None:
    # the same displacement at many frames, but as a one-frame jump away and back (a
    # tracker flicking to another blob): each one is reported
    X = _face()
    frames = np.arange(60, 1100, 97)
    X[frames, 3] += [0.0, -4.3, 1.2]
    got = [(s.point, s.start) for s in find_spikes(X)]
    assert got == [(3, int(f)) for f in frames]


def test_a_neighbours_spike_is_reported_on_that_neighbour_only() -> None:
    X = _face()
    X[700, 5] += [8.0, 0.0, 0.0]
    assert [(s.point, s.start) for s in find_spikes(X)] == [(5, 700)]
