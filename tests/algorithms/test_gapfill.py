"""Gap filling, filtering, spikes and swaps on synthetic trajectories with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from carapost.algorithms.cleanup import (
    FilterParameters,
    ProblemParameters,
    find_spikes,
    find_swaps,
    lowpass,
)
from carapost.algorithms.gapfill import GapFillParameters, fill_gaps, runs


def face_take(frames=1200, points=40, seed=0, noise=0.03):
    """A face-sized cloud with smooth expression modes, head rotation and translation."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / 100.0
    base = rng.normal(size=(points, 3)) * [30.0, 40.0, 15.0]
    # expression modes vary smoothly over the face (nearby points move alike)
    centres = rng.normal(size=(4, 3)) * [30.0, 40.0, 15.0]
    amp = np.exp(-np.linalg.norm(base[None] - centres[:, None], axis=-1) ** 2 / (2 * 40.0**2))
    direc = rng.normal(size=(4, 3))
    modes = amp[..., None] * direc[:, None] * 4.0
    w = np.sin(2 * np.pi * rng.uniform(0.2, 1.0, 4)[None] * t[:, None] + rng.uniform(0, 6, 4))
    X = base[None] + np.einsum("fm,mpi->fpi", w, modes)
    a = 0.3 * np.sin(0.5 * t)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((frames, 3, 3))
    R[:, 0, 0], R[:, 0, 2], R[:, 1, 1], R[:, 2, 0], R[:, 2, 2] = c, s, 1, -s, c
    X = np.einsum("fij,fpj->fpi", R, X) + np.stack([50 * np.sin(0.3 * t), 10 * t, 0 * t],
                                                   -1)[:, None]
    return X + rng.normal(scale=noise, size=X.shape)


def with_gaps(X, spec):
    fill = np.zeros(X.shape[:2], bool)
    for p, s, L in spec:
        fill[s:s + L, p] = True
    Xg = X.copy()
    Xg[fill] = np.nan
    return Xg, fill


GAPS = [(3, 100, 5), (7, 300, 30), (12, 500, 60), (20, 700, 120), (25, 900, 10)]


@pytest.mark.parametrize("method", ["guide", "lowrank", "auto"])
def test_fills_every_gap_close_to_the_truth(method):
    X = face_take()
    Xg, fill = with_gaps(X, GAPS)
    out = fill_gaps(Xg, fill, params=GapFillParameters(method=method))
    assert out.filled.sum() == fill.sum() and not out.messages
    err = np.linalg.norm(out.positions[fill] - X[fill], axis=-1)
    # linear interpolation over the same gaps, for scale
    lin = []
    for p, s, L in GAPS:
        q = np.arange(s, s + L)
        lin.append(np.stack([np.interp(q, [s - 1, s + L], X[[s - 1, s + L], p, i])
                             for i in range(3)], -1) - X[s:s + L, p])
    lin_rms = np.sqrt(np.mean(np.concatenate(lin) ** 2) * 3)
    assert np.sqrt(np.mean(err**2)) < 0.5 * lin_rms
    # untouched elsewhere, and the fill meets the data at the gap ends
    assert np.isnan(out.positions[~fill]).all()
    p, s, L = GAPS[1]
    step_in = np.linalg.norm(out.positions[s, p] - X[s - 1, p])
    assert step_in < 3 * np.nanmedian(np.linalg.norm(np.diff(X[:, p], axis=0), axis=-1)) + 0.5


def test_auto_estimate_follows_the_real_error():
    X = face_take(frames=2000, points=30, seed=3)
    rng = np.random.default_rng(1)
    spec = [(int(rng.integers(30)), int(s), int(L)) for s, L in
            zip(rng.integers(150, 1800, 40), rng.choice([5, 15, 40, 90], 40), strict=True)]
    Xg, fill = with_gaps(X, spec)
    out = fill_gaps(Xg, fill, params=GapFillParameters(method="auto"))
    g = out.gaps
    est, real = [], []
    for i in range(len(g)):
        sl = slice(g.start[i], g.end[i] + 1)
        e = np.linalg.norm(out.positions[sl, g.point[i]] - X[sl, g.point[i]], axis=-1)
        if np.isfinite(g.estimate_mm[i]):
            est.append(g.estimate_mm[i])
            real.append(np.sqrt(np.mean(e**2)))
    from scipy.stats import spearmanr

    assert len(est) >= 0.8 * len(g)
    assert spearmanr(est, real).statistic > 0.6
    assert np.isfinite(out.sigma[out.filled]).mean() > 0.8
    assert set(g.method) <= {"guide", "lowrank", "spline", "mix", "cubic"}


def test_bad_input_leaves_those_gaps_and_fills_the_rest():
    X = face_take(frames=400, points=10)
    Xg, fill = with_gaps(X, [(2, 100, 20), (4, 50, 30)])
    Xg[:, 6] = np.nan                         # a point never known
    fill[:, 6] = True
    Xg[:, 8] = np.nan                         # a point known in one frame only
    Xg[200, 8] = X[200, 8]
    fill[:, 8] = np.isnan(Xg[:, 8, 0])
    out = fill_gaps(Xg, fill, params=GapFillParameters(method="guide", min_known_frames=2),
                    labels=[f"M{i}" for i in range(10)])
    assert out.filled[100:120, 2].all() and out.filled[50:80, 4].all()
    assert not out.filled[:, 6].any() and not out.filled[:, 8].any()
    text = " ".join(out.messages)
    assert "M6" in text and "M8" in text and "fewer than 2 known samples" in text
    left = [s for s in out.gaps.status if s]
    assert any("known" in s for s in left)


def test_max_gap_and_one_sided_options():
    X = face_take(frames=600, points=10)
    Xg, fill = with_gaps(X, [(1, 100, 20), (2, 200, 80), (3, 0, 40), (5, 560, 40)])
    out = fill_gaps(Xg, fill, params=GapFillParameters(method="guide", max_gap_frames=50,
                                                       fill_ends=False))
    assert out.filled[100:120, 1].all()
    assert not out.filled[:, 2].any() and not out.filled[:, 3].any()
    assert not out.filled[:, 5].any()
    assert any("Max Gap Length" in m for m in out.messages)
    ends = fill_gaps(Xg, fill, params=GapFillParameters(method="guide"))
    assert ends.filled[0:40, 3].all() and ends.filled[560:, 5].all()
    err = np.linalg.norm(ends.positions[0:40, 3] - X[0:40, 3], axis=-1)
    assert err.max() < 10.0
    # forwards only: the gap is filled from its start, drifting towards the end
    fwd = fill_gaps(Xg, fill, params=GapFillParameters(method="guide",
                                                       use_backwards_prediction=False))
    assert fwd.filled[100:120, 1].all() and not fwd.filled[0:40, 3].any()
    off = fill_gaps(Xg, fill, params=GapFillParameters(use_forwards_prediction=False,
                                                       use_backwards_prediction=False))
    assert not off.filled.any() and "both off" in " ".join(off.messages)


def test_single_sensor_fill_lies_on_the_ray():
    X = face_take(frames=300, points=10)
    Xg, fill = with_gaps(X, [(4, 100, 30)])
    cam = np.array([0.0, -50.0, 300.0])
    origins = np.full(X.shape, np.nan)
    dirs = np.full(X.shape, np.nan)
    origins[100:130, 4] = cam
    d = X[100:130, 4] - cam
    dirs[100:130, 4] = d / np.linalg.norm(d, axis=-1, keepdims=True)
    out = fill_gaps(Xg, fill, params=GapFillParameters(method="guide"), rays=(origins, dirs))
    P = out.positions[100:130, 4]
    v = P - cam
    cross = np.linalg.norm(np.cross(v, dirs[100:130, 4]), axis=-1)
    assert cross.max() < 1e-9
    free = fill_gaps(Xg, fill, params=GapFillParameters(
        method="guide", allow_single_sensor_gap_filling=False), rays=(origins, dirs))
    e_ray = np.linalg.norm(P - X[100:130, 4], axis=-1)
    e_free = np.linalg.norm(free.positions[100:130, 4] - X[100:130, 4], axis=-1)
    assert e_ray.mean() <= e_free.mean() + 1e-9


def test_runs_table():
    m = np.zeros((10, 2), bool)
    m[2:4, 0] = m[0, 1] = m[9, 1] = True
    assert [a.tolist() for a in runs(m)] == [[0, 1, 1], [2, 0, 9], [3, 0, 9]]


def test_lowpass_never_crosses_a_gap_and_removes_noise():
    X = face_take(frames=600, points=4, noise=0.0)
    rng = np.random.default_rng(2)
    noisy = X + rng.normal(scale=0.3, size=X.shape)
    noisy[300:320, 1] = np.nan
    out, changed = lowpass(noisy, 100.0, FilterParameters(filter_cutoff_hz=6.0))
    assert not changed[300:320, 1].any() and np.isnan(out[300:320, 1]).all()
    # each side is filtered on its own: equal to filtering the run alone
    alone, _ = lowpass(noisy[:300, 1:2], 100.0, FilterParameters(filter_cutoff_hz=6.0))
    np.testing.assert_array_equal(out[:300, 1], alone[:, 0])
    e_in = np.sqrt(np.nanmean((noisy - X) ** 2))
    e_out = np.sqrt(np.nanmean((out - X)[50:-50] ** 2))
    assert e_out < 0.4 * e_in
    with pytest.raises(ValueError, match="half the frame rate"):
        lowpass(noisy, 100.0, FilterParameters(filter_cutoff_hz=60.0))


def test_spikes_and_swaps_found_without_false_reports():
    X = face_take(frames=3000, points=30, seed=5)
    assert find_spikes(X) == [] and find_swaps(X) == []
    rng = np.random.default_rng(7)
    Y = X.copy()
    spikes = set()
    for f in rng.choice(np.arange(50, 2950, 60), 20, replace=False):
        p = int(rng.integers(30))
        v = rng.normal(size=3)
        Y[f, p] += 5.0 * v / np.linalg.norm(v)
        spikes.add((p, int(f)))
    found = {(s.point, s.start) for s in find_spikes(Y)}
    assert len(found & spikes) >= 0.95 * len(spikes)
    assert len(found - spikes) <= 3
    # swaps of neighbouring points
    Z = X.copy()
    ref = X[0]
    d = np.linalg.norm(ref[:, None] - ref[None], axis=-1) + np.eye(30) * 1e9
    swaps = set()
    for f in (400, 1100, 1900, 2600):
        i = int(rng.integers(30))
        j = int(np.argmin(d[i]))
        Z[f:, [i, j]] = Z[f:, [j, i]]
        swaps.add((min(i, j), max(i, j), f))
    got = {(min(s.points), max(s.points), s.frame) for s in find_swaps(Z)}
    assert swaps <= got and len(got - swaps) <= 1
    assert ProblemParameters().spike_threshold_mm == 2.0
