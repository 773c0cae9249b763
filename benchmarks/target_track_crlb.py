"""How close the Target Tracker can get on the ``noisy`` case: the Cramér-Rao bound.

    python benchmarks/target_track_crlb.py [--step 10] [--trials 16] [--cache DIR]
        [--cases noisy,speech,fast] [--skip-temporal] [--scratch DIR] [--skip-decompose]

The ``noisy`` case of ``benchmarks/target_track.py`` is the speech take with noise 5
and motion blur, one keyframe from the truth at frame 0. This script asks what *any*
unbiased estimator could reach on it, and how far ours is from that:

- **The bound per frame.** For every marker visible throughout, in every camera, at
  every ``--step``-th frame, the Fisher information of the marker's 2D position in the
  21 x 21 pattern box, from the noiseless render of the same frame (``noise=0``, the
  same scene and blur) and the render's own noise model (sigma = 2.5 + 2.5 sqrt(grey /
  128) grey levels, white, per pixel), with the refinement's nuisance terms (gain,
  bias, two shading ramps). Two versions: ``full`` takes the derivative of the whole
  box (as if the skin moved with the marker), ``ink`` the derivative of the markers' ink
  alone (the render without markers subtracted: on these renders the skin does not
  move with the markers, so only the ink carries the position). ``crlb_*_p95_px`` is the
  95th percentile of the error norm of an estimator that reaches the bound at every
  sample (2D Gaussians sampled), ``crlb_*_rms_median_px`` the median RMS radius.
- **Ours against it.** ``ours_mc_*``: our refinement (``target_track._Refiner``, the
  noiseless pattern of the same frame at the truth, i.e. a perfect keyframe), refined
  from the truth on ``--trials`` noisy copies of the noiseless frame; the ratio of its
  RMS radius to the ``ink`` bound, per sample.
- **The keyframe anchor.** The keyframe says where the marker is in frame 0, but the
  pattern is that frame's image: where the pattern's content lies relative to the
  keyframe position is known only to that frame's noise. Every frame of the track is
  measured against the pattern, so this is a constant offset per track with (at least)
  the bound's covariance at frame 0, which no use of later frames can remove (they all
  see the marker relative to the same pattern; only a prior on the marker's shape
  could). ``crlb_anchor_p95_px`` is that offset's bound; ``crlb_case_*`` the bound on
  the benchmark's own figures (over every sample: the offset of its track plus the
  frame's own error; ``temporal``: the offset alone, what a perfect use of every frame
  of the track would leave), over all samples and over those the benchmark's runs
  tracked (``samples``: the benchmark's figures are over the latter; a run whose first
  step is refused tracks none).
- **Temporal estimation** (unless ``--skip-temporal``): the cases' tracks as the
  benchmark runs them (Break Threshold 0), their errors smoothed *ideally* (the signed
  error itself averaged over a centred window: zero lag, the motion known), and the
  tracked positions smoothed by a constant-velocity Rauch-Tung-Striebel smoother whose
  measurement noise is the refinement's predicted variance (the image's noise,
  Immerkaer's estimate, through the refinement's normal equations at the keyframe) and
  whose process noise follows the track's own local second differences.

- **The error, source by source** (unless ``--skip-decompose``): the noisy case's
  tracks with its frames' and its keyframe's noise switched off in turn (the noiseless
  render of the same take, kept in ``--scratch``), on the samples all runs track, and
  the offset the keyframe's noise alone gives each track against the bound at frame 0
  (:func:`bench_decompose`).

Prints JSON lines like ``benchmarks/target_track.py``. ``--cache`` is where that
benchmark keeps its renders (read only).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
from scipy.ndimage import uniform_filter1d

import target_track as tt
from carapost.algorithms import target_track as T
from carapost.algorithms.target_refine import cubic6_weights, noise_sigma
from carapost.synth import SynthConfig, build_scene, render_frame

P = 21           # the default Pattern Size
NOISE = 5.0      # the noisy case's noise (grey levels at grey 128)


def _sigma(img: np.ndarray) -> np.ndarray:
    """The render's noise standard deviation at each pixel (``synth.render``)."""
    return 0.5 * NOISE + 0.5 * NOISE * np.sqrt(np.maximum(img, 0.0) / 128.0)


def _grad(img: np.ndarray, ix: int, iy: int) -> tuple[np.ndarray, np.ndarray]:
    """d/dx, d/dy of ``img`` at the P x P pixels around (ix, iy), by +-0.25 px samples."""
    def s(dx: float, dy: float) -> np.ndarray:
        return T.sample_patch(img, (ix + dx, iy + dy), P).astype(np.float64)
    return (s(0.25, 0) - s(-0.25, 0)) / 0.5, (s(0, 0.25) - s(0, -0.25)) / 0.5


def _bounds(I0: np.ndarray, ink: np.ndarray, x: float, y: float) -> dict[str, np.ndarray]:
    """2 x 2 CRLB covariances (px^2) of the position at (x, y): ``full`` and ``ink``."""
    ix, iy, h = int(round(x)), int(round(y)), P // 2
    pix = I0[iy - h:iy + h + 1, ix - h:ix + h + 1]
    g = (np.arange(P) - h) / h
    nuis = [pix.ravel(), np.ones(P * P), np.tile(g, P), np.repeat(g, P)]
    iv = 1.0 / _sigma(pix).ravel() ** 2
    out = {}
    for name, src in (("full", I0), ("ink", ink)):
        gx, gy = _grad(src, ix, iy)
        J = np.stack([gx.ravel(), gy.ravel(), *nuis])
        out[name] = np.linalg.pinv((J * iv) @ J.T)[:2, :2]
    return out


def _ours_mc(I0: np.ndarray, x: float, y: float, trials: int,
             rng: np.random.Generator) -> np.ndarray:
    """(trials, 2) errors (px) of our refinement of a perfect pattern on noisy copies."""
    ref = T._Refiner(T._normalise(T.sample_patch(I0, (x, y), P)), 0.18 * P)
    fx, fy = math.floor(x), math.floor(y)
    crop0 = I0[fy - 40:fy + 41, fx - 40:fx + 41]
    sc = _sigma(crop0)
    d = []
    for _ in range(trials):
        cr = np.clip(np.round(crop0 + sc * rng.standard_normal(crop0.shape)), 0, 255)
        p, _, _ = ref.refine(cr, (fx - 40, fy - 40), np.array([x, y]), 12, 2e-4)
        d.append(p - (x, y))
    return np.array(d)


def _p95(covs: list[np.ndarray], rng: np.random.Generator, n: int = 200) -> float:
    e = np.concatenate([rng.multivariate_normal([0.0, 0.0], C, n) for C in covs])
    return float(np.percentile(np.linalg.norm(e, axis=1), 95))


def _rms(C: np.ndarray) -> float:
    return float(math.sqrt(max(np.trace(C), 0.0)))


def bench_bound(frames: int, step: int, trials: int,
                tracked: np.ndarray | None = None) -> None:
    """The bound per frame, ours against it, the keyframe anchor (see the module).

    ``tracked`` (tracks, frames - 1) bool, tracks in marker-major order as the benchmark
    runs them: the samples the benchmark's figures are over (its runs track a sample
    or not); the case's bound is given over those too."""
    rng = np.random.default_rng(0)
    cfg = SynthConfig(frames=frames, size=(1280, 720), preset="speech", noise=0.0,
                      motion_blur=True)
    scene = build_scene(cfg)
    uv, vis = scene.uv, scene.visible
    markers = np.flatnonzero(vis.all(axis=(0, 2)))
    keys = [(m, c) for m in markers for c in range(scene.n_cameras)]
    rows: dict[tuple[int, int], list[dict]] = {k: [] for k in keys}
    anchor: dict[tuple[int, int], dict] = {}
    t0 = time.process_time()
    for f in [0, *range(1, frames, step)]:
        for c in range(scene.n_cameras):
            I0 = render_frame(scene, f, c).astype(np.float64)
            shown = scene.visible
            scene.visible = np.zeros_like(shown)   # the render without markers
            bare = render_frame(scene, f, c).astype(np.float64)
            scene.visible = shown
            ink = bare - I0
            for m in markers:
                x, y = (float(v) for v in uv[f, m, c])
                row = _bounds(I0, ink, x, y)
                row["mc"] = _ours_mc(I0, x, y, trials, rng)
                row["f"] = f
                (anchor.__setitem__((m, c), row) if f == 0 else rows[(m, c)].append(row))
    cpu = time.process_time() - t0
    flat = [r for v in rows.values() for r in v]
    for kind in ("full", "ink"):
        tt.emit(f"crlb_{kind}_p95_px", round(_p95([r[kind] for r in flat], rng), 4), "px",
                rms_median_px=round(float(np.median([_rms(r[kind]) for r in flat])), 4),
                samples=len(flat), frames=f"1-{frames - 1} step {step}")
    mc = np.concatenate([r["mc"] for r in flat])
    ratio = np.array([_rms(np.cov(r["mc"].T)) / _rms(r["ink"]) for r in flat])
    tt.emit("ours_mc_p95_px", round(float(np.percentile(np.linalg.norm(mc, axis=1), 95)), 4),
            "px", rms_median_px=round(float(np.median([_rms(np.cov(r["mc"].T))
                                                       for r in flat])), 4),
            ratio_to_ink_bound_median=round(float(np.median(ratio)), 3),
            ratio_p5=round(float(np.percentile(ratio, 5)), 3),
            ratio_p95=round(float(np.percentile(ratio, 95)), 3), trials=trials)
    a = list(anchor.values())
    ratio0 = np.array([_rms(np.cov(r["mc"].T)) / _rms(r["ink"]) for r in a])
    tt.emit("crlb_anchor_p95_px", round(_p95([r["ink"] for r in a], rng), 4), "px",
            full_p95_px=round(_p95([r["full"] for r in a], rng), 4),
            rms_median_px=round(float(np.median([_rms(r["ink"]) for r in a])), 4),
            ours_to_ink_bound_median=round(float(np.median(ratio0)), 3), tracks=len(a))
    masks = {"all": None} if tracked is None else {"all": None, "tracked": tracked}
    for samples, mask in masks.items():
        for kind in ("ink", "full"):   # the benchmark's figures: offset per track + the frame's
            per, temporal = [], []
            for _ in range(50):
                for i, key in enumerate(keys):
                    rs = [r for r in rows[key] if mask is None or mask[i, r["f"] - 1]]
                    if not rs:
                        continue
                    off = rng.multivariate_normal([0.0, 0.0], anchor[key][kind])
                    for r in rs:
                        e = off + rng.multivariate_normal([0.0, 0.0], r[kind])
                        per.append(np.hypot(*e))
                        temporal.append(np.hypot(*off))
            tt.emit(f"crlb_case_{kind}_p95_px", round(float(np.percentile(per, 95)), 4), "px",
                    median_px=round(float(np.median(per)), 4),
                    temporal_p95_px=round(float(np.percentile(temporal, 95)), 4),
                    temporal_median_px=round(float(np.median(temporal)), 4),
                    samples=samples, n=len(per) // 50)
    tt.emit("crlb_cpu_s", round(cpu, 1), "s")


def _rts(z: np.ndarray, r: float, q: np.ndarray) -> np.ndarray:
    """Constant-velocity Rauch-Tung-Striebel smoother of one coordinate.

    ``z`` (F,) measurements, ``r`` their variance, ``q`` (F,) the white-acceleration
    variance entering before each frame (px^2)."""
    A = np.array([[1.0, 1.0], [0.0, 1.0]])
    Q0 = np.array([[0.25, 0.5], [0.5, 1.0]])
    x, Pm = np.array([z[0], 0.0]), np.diag([r, 1e4])
    xs, Ps, xp, Pp = [], [], [], []
    for k in range(len(z)):
        if k:
            x, Pm = A @ x, A @ Pm @ A.T + q[k] * Q0
        xp.append(x)
        Pp.append(Pm)
        gain = Pm[:, 0] / (Pm[0, 0] + r)
        x = x + gain * (z[k] - x[0])
        Pm = Pm - np.outer(gain, Pm[0])
        xs.append(x)
        Ps.append(Pm)
    out = [xs[-1]]
    for k in range(len(z) - 2, -1, -1):
        C = Ps[k] @ A.T @ np.linalg.inv(Pp[k + 1])
        out.append(xs[k] + C @ (out[-1] - xp[k + 1]))
    return np.array(out[::-1])[:, 0]


def _predicted_var(img: np.ndarray, xy: np.ndarray) -> float:
    """The refinement's predicted variance per axis (px^2) at the keyframe: the image's
    noise (Immerkaer) through the normal equations of the keyframe pattern."""
    raw = T.sample_patch(img, xy, P)
    ref = T._Refiner(T._normalise(raw), 0.18 * P)
    ix, iy = int(round(xy[0])), int(round(xy[1]))
    s = noise_sigma(np.asarray(img[iy - P:iy + P + 1, ix - P:ix + P + 1], np.float64))
    x, y = float(xy[0]), float(xy[1])
    gain = float((cubic6_weights(x - math.floor(x)) ** 2).sum()
                 * (cubic6_weights(y - math.floor(y)) ** 2).sum())
    L = (ref.Hinv @ ref.J)[:2]
    return float(s * s * gain * (L * L).sum() / 2.0 / max(float(raw.std()) ** 2, 1e-12))


def _tracks(imgs, uv: np.ndarray, markers: np.ndarray, n_cameras: int,
            frames: int) -> np.ndarray:
    """The benchmark's runs: each marker in each camera (marker-major) keyed at frame 0
    from the truth, Break Threshold 0; (tracks, frames, 2) positions, NaN where not
    tracked."""
    params = T.TargetTrackerParameters(break_threshold=0.0)
    out = []
    for m in markers:
        for c in range(n_cameras):
            r = T.track_target(lambda f, c=c: imgs[f, c], {0: uv[0, m, c]}, start=0,
                               stop=frames - 1, direction=1, params=params)
            xy = np.full((frames, 2), np.nan)
            xy[:len(r.frames)] = r.xy
            out.append(xy)
    return np.array(out)


def bench_temporal(case: str, frames: int) -> np.ndarray:
    """Ideal and constant-velocity smoothing of the case's tracks (see the module).

    Returns the samples tracked, (tracks, frames - 1) bool."""
    scene, imgs = tt.render(SynthConfig(frames=frames, size=(1280, 720), **tt.CASES[case]))
    uv, vis = scene.uv, scene.visible
    markers = np.flatnonzero(vis.all(axis=(0, 2)))
    XY = _tracks(imgs, uv, markers, scene.n_cameras, frames)
    err, smooth = [], []
    pairs = [(m, c) for m in markers for c in range(scene.n_cameras)]
    for xy, (m, c) in zip(XY, pairs, strict=True):
        err.append(xy[1:] - uv[1:, m, c])
        z = xy[1:]
        if not np.all(np.isfinite(z)):
            smooth.append(np.full_like(z, np.nan))
            continue
        rv = _predicted_var(imgs[0, c], uv[0, m, c])
        out = np.empty_like(z)
        for ax in range(2):
            d2 = np.zeros(len(z))
            d2[1:-1] = np.diff(z[:, ax], 2) ** 2
            # the acceleration seen nearby, less what the measurement noise explains
            loc = np.max([np.roll(d2, s) for s in (-2, -1, 0, 1, 2)], axis=0)
            out[:, ax] = _rts(z[:, ax], rv, np.maximum(loc - 6.0 * rv, 1e-3 * rv))
        smooth.append(out - uv[1:, m, c])
    E = np.array(err)

    def stats(e: np.ndarray) -> tuple[float, float]:
        n = np.linalg.norm(e, axis=-1)
        return round(float(np.nanmedian(n)), 4), round(float(np.nanpercentile(n, 95)), 4)

    tt.emit("temporal_raw_p95_px", stats(E)[1], "px", case=case, median_px=stats(E)[0],
            tracks=len(E))
    for k in (5, 9, frames - 1):
        med, p95 = stats(uniform_filter1d(E, k, axis=1, mode="nearest"))
        tt.emit("temporal_ideal_p95_px", p95, "px", case=case, window=k, median_px=med)
    med, p95 = stats(np.array(smooth))
    tt.emit("temporal_rts_p95_px", p95, "px", case=case, median_px=med)
    return np.isfinite(E[..., 0])


def bench_decompose(frames: int, scratch: str | None) -> None:
    """The noisy case's error with its noise switched off in turn, on common samples.

    The noisy case's frames and keyframe image against the noiseless render of the same
    take (``noise=0``, the same motion blur; kept in ``scratch``): noisy frames with the
    noisy keyframe (the benchmark), with the noiseless keyframe, and noiseless frames
    with the noiseless keyframe (the tracker's systematic error alone). The figures are
    over each run's own samples and over the samples all three runs track. Also the
    offset the keyframe's noise alone gives each track (the mean over the track of the
    first run's positions less the second's), against the bound at frame 0: the mean of
    ``offset' Sigma0^-1 offset`` is 2 for an estimator at the bound."""
    from target_track_noisy_tail import _Keyed

    base = {"frames": frames, "size": (1280, 720)}
    scene, noisy = tt.render(SynthConfig(**base, **tt.CASES["noisy"]))
    cache, tt.CACHE_DIR = tt.CACHE_DIR, scratch
    _, clean = tt.render(SynthConfig(**base, preset="speech", noise=0.0, motion_blur=True))
    tt.CACHE_DIR = cache
    uv, vis = scene.uv, scene.visible
    markers = np.flatnonzero(vis.all(axis=(0, 2)))

    def run(imgs) -> np.ndarray:   # (tracks, frames, 2) positions, NaN where not tracked
        return _tracks(imgs, uv, markers, scene.n_cameras, frames)

    runs = {"noisy frames, noisy key (the benchmark)": (noisy, lambda c: noisy[0, c]),
            "noisy frames, noiseless key": (noisy, lambda c: clean[0, c]),
            "noiseless frames, noiseless key": (clean, lambda c: clean[0, c])}
    truth = np.array([uv[:, m, c] for m in markers for c in range(scene.n_cameras)])
    XY = {k: run(_Keyed(imgs, key)) for k, (imgs, key) in runs.items()}
    E = {k: np.linalg.norm(xy[:, 1:] - truth[:, 1:], axis=-1) for k, xy in XY.items()}
    common = np.all([np.isfinite(e) for e in E.values()], axis=0)
    for k, e in E.items():
        own = e[np.isfinite(e)]
        tt.emit("decompose_p95_px", round(float(np.percentile(own, 95)), 4), "px", run=k,
                median_px=round(float(np.median(own)), 4), samples=int(own.size),
                common_p95_px=round(float(np.percentile(e[common], 95)), 4),
                common_median_px=round(float(np.median(e[common])), 4),
                common_samples=int(common.sum()))
    a, b = XY["noisy frames, noisy key (the benchmark)"], XY["noisy frames, noiseless key"]
    d = a[:, 1:] - b[:, 1:]
    ok = np.isfinite(d[..., 0]).any(axis=1)
    off = np.array([np.nanmean(t, axis=0) for t in d[ok]])
    cfg = SynthConfig(**base, preset="speech", noise=0.0, motion_blur=True)
    bscene = build_scene(cfg)
    I0 = [render_frame(bscene, 0, c).astype(np.float64) for c in range(scene.n_cameras)]
    shown = bscene.visible
    bscene.visible = np.zeros_like(shown)
    bare = [render_frame(bscene, 0, c).astype(np.float64) for c in range(scene.n_cameras)]
    kept = [(m, c) for i, (m, c) in enumerate((m, c) for m in markers
                                               for c in range(scene.n_cameras)) if ok[i]]
    chi = [float(o @ np.linalg.inv(_bounds(I0[c], bare[c] - I0[c], *uv[0, m, c])["ink"]) @ o)
           for o, (m, c) in zip(off, kept, strict=True)]
    tt.emit("keyframe_noise_offset_chi2_mean", round(float(np.mean(chi)), 2), "",
            tracks=int(ok.sum()), median=round(float(np.median(chi)), 2),
            offset_p95_px=round(float(np.percentile(np.linalg.norm(off, axis=1), 95)), 4))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--step", type=int, default=10)
    ap.add_argument("--trials", type=int, default=16)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--cases", default="noisy,speech,fast")
    ap.add_argument("--skip-temporal", action="store_true")
    ap.add_argument("--scratch", default=None,
                    help="keeps the noiseless render of the noisy take between runs")
    ap.add_argument("--skip-decompose", action="store_true")
    args = ap.parse_args(argv)
    tt.CACHE_DIR = args.cache
    tracked = None
    if not args.skip_temporal:
        for case in args.cases.split(","):
            t = bench_temporal(case, args.frames)
            tracked = t if case == "noisy" else tracked
    bench_bound(args.frames, args.step, args.trials, tracked)
    if not args.skip_decompose:
        bench_decompose(args.frames, args.scratch)
    return 0


if __name__ == "__main__":
    sys.exit(main())
