"""Tracking benchmark: speed of the tracker and accuracy of the headless pipeline.

    python benchmarks/tracking.py [--frames 600] [--runs 3] [--skip-accuracy]
        [--accuracy-frames 300] [--accuracy-seeds 1,2] [--takes speech,fast,...] [--rom]

Prints JSON lines:

- ``tracking_fps``: frames per second of :func:`carapost.algorithms.tracking.track` over a
  synthetic speech take (4 cameras, 89 face markers + 23 brim dots, detections present:
  the truth projections plus noise, clutter and dropouts), median of ``--runs`` runs,
  with ``reference_ratio`` = our fps / 0.7 fps (the reference guide's own log),
  ``cpu_fps`` (the same over CPU time, for comparisons on a loaded machine) and the
  ``load_average`` at the end.
- ``tracking_coverage``, ``tracking_swaps``, ``tracking_rmse_mm``: a rendered speech take
  (standard markers) processed end to end by ``carapost.pipeline.process_take`` (blob
  detection, automatic brim solve, automatic Initialize 3D at frame 0, tracking) and
  scored with ``carapost.api.evaluate`` against its truth (one take per seed of
  ``--accuracy-seeds``).
- with ``--rom``: ``rom_recovered``, ``rom_mismatches``, ``rom_track_coverage`` and
  ``rom_track_swaps`` of Initialize from ROM end to end on rendered takes (see
  :func:`bench_rom`).
- with ``--takes speech,fast,...``: ``take_coverage``, ``take_swaps``, ``take_rmse_mm``,
  ``take_spurious`` and ``take_fps`` of :func:`carapost.algorithms.tracking.track_take`
  (with :func:`make_spawner`) on truth-derived detections of each named case
  (``speech``, ``fast``, ``blink``, ``dense156``, ``sparse35``, ``back`` = speech
  initialised at its last frame), scored like ``evaluate`` (points matched one-to-one to
  markers by mean distance); ``take_fps`` also gives ``cpu_fps``. One 600-frame case
  takes 0.5-2 minutes.
- with ``--variety``: takes unlike the standard ones
  (:func:`carapost.synth.variety.other_rig_config`: Poisson-disk markers of radius
  1.2-2.0 mm and grey ~20-50, other head shapes, portrait cameras, 40 mm caddies 180 mm
  apart, more flex and slip) rendered, processed end to end by ``process_take`` and
  scored per sample group (seen by one caddy only, by both, all):
  ``variety_rmse_mm``, ``variety_p99_mm``, ``variety_max_mm``, ``variety_coverage``,
  ``variety_over_0_5mm``, ``variety_swaps``, ``variety_spurious``,
  ``uncertainty_within_1sigma`` and ``uncertainty_within_2sigma`` (fraction of samples
  whose error is within their 1 / 2 sigma), one line per take and group, then the same
  pooled over the takes (``take: "pooled"``); the calibration also per number of
  cameras that observed the sample (groups ``cameras_2``, ``cameras_3``, ``cameras_4``).
  ``--variety-set heldout`` (the default) scores the held-out takes, never used to tune;
  ``heldout2`` to ``heldout7`` the second to seventh held-out sets; ``tuning`` the development ones.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from carapost.synth.scoring import track_quality

REFERENCE_FPS = 0.7


def emit(metric: str, value: float | int | None, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def _load_average() -> float | None:
    """1-minute load average (None where the platform has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def synthetic_detections(scene, rng, noise: float = 0.15):
    F, M, C = scene.visible.shape
    W, H = scene.size
    out = []
    for f in range(F):
        per = []
        for c in range(C):
            v = scene.visible[f, :, c] & (rng.random(M) > 0.01)
            cen = np.concatenate([scene.uv[f, v, c],
                                  scene.brim_uv[f, scene.brim_visible[f, :, c], c],
                                  rng.random((10, 2)) * [W, H]])
            cen += rng.normal(0, noise, cen.shape)
            per.append((cen[rng.permutation(len(cen))], np.full((len(cen), 2), 5.0)))
        out.append(per)
    return out


def bench_takes(frames: int, cases: list[str]) -> None:
    from carapost.algorithms.codes import KIND_BRIM
    from carapost.algorithms.tracking import (
        InitialState,
        TrackingParameters,
        make_spawner,
        track_take,
    )
    from carapost.synth import SynthConfig, build_scene

    for case in cases:
        preset = case if case in ("speech", "fast", "blink") else "speech"
        markers = case if case in ("dense156", "sparse35") else "standard"
        # the truth-derived centres are the projections of the dots' centres, with none
        # of a tilted dot's image offset to remove
        params = TrackingParameters(brim_dot_offsets=False)
        if markers == "sparse35":  # the reference guide's settings for sparse marker sets
            params = TrackingParameters(face_point_max_elastic_prediction_distance=25.0,
                                        max_3d_point_error=10.0,
                                        allow_single_sensor_tracking=False,
                                        brim_dot_offsets=False)
        scene = build_scene(SynthConfig(preset=preset, markers=markers, frames=frames,
                                        seed=1))
        dets = synthetic_detections(scene, np.random.default_rng(0), noise=0.05)
        M, B = len(scene.labels), len(scene.brim3d)
        start = frames - 1 if case == "back" else 0
        X0 = np.concatenate([scene.points3d[start], scene.brim3d])
        X0[:M][scene.visible[start].sum(-1) < 2] = np.nan
        kind = np.r_[np.zeros(M, np.int8), np.full(B, KIND_BRIM, np.int8)]
        init = InitialState(X0, kind, axes=np.full((M + B, scene.n_cameras, 2), 5.0))
        t0, c0 = time.perf_counter(), time.process_time()
        res = track_take(dets.__getitem__, init, scene.cam_R[start], scene.cam_t[start],
                         scene.intrinsics, params, start=start, n_frames=frames,
                         spawn=make_spawner(scene.intrinsics, ((0, 1), (2, 3)),
                                            brim_model=scene.brim3d))
        seconds = time.perf_counter() - t0
        cpu = time.process_time() - c0
        pos = np.concatenate([res.positions[:, :M], res.positions[:, M + B:]], axis=1)
        cov, swaps, rmse, spurious = track_quality(scene.points3d, scene.visible, pos)
        common = {"case": case, "frames": frames, "found_points": res.n_new}
        emit("take_coverage", round(cov, 4), "fraction", **common)
        emit("take_swaps", swaps, "count", **common)
        emit("take_rmse_mm", None if rmse is None else round(rmse, 3), "mm", **common)
        emit("take_spurious", spurious, "count", **common)
        emit("take_fps", round(2 * (frames - 1) / seconds, 1), "frames/s", **common,
             cpu_fps=round(2 * (frames - 1) / cpu, 1), note="both passes counted")


def bench_speed(frames: int, runs: int) -> None:
    from carapost.algorithms.tracking import InitialState, TrackingParameters, track
    from carapost.synth import SynthConfig, build_scene

    scene = build_scene(SynthConfig(preset="speech", frames=frames, seed=1))
    dets = synthetic_detections(scene, np.random.default_rng(0))
    M, B = len(scene.labels), len(scene.brim3d)
    X0 = np.concatenate([scene.points3d[0], scene.brim3d])
    kind = np.r_[np.zeros(M, np.int8), np.ones(B, np.int8)]
    rates, cpu_rates = [], []
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        res = track(lambda f: dets[f], InitialState(X0, kind), scene.cam_R[0], scene.cam_t[0],
                    scene.intrinsics, TrackingParameters(), start=0, stop=frames - 1)
        rates.append(res.frames_done / (time.perf_counter() - t0))
        cpu_rates.append(res.frames_done / (time.process_time() - c0))
    fps = statistics.median(rates)
    # CPU-time rate: comparable between variants when other jobs load the machine
    emit("tracking_fps", round(fps, 1), "frames/s", cameras=scene.n_cameras, markers=M,
         brim=B, frames=frames - 1, runs=[round(r, 1) for r in rates],
         cpu_fps=round(statistics.median(cpu_rates), 1),
         load_average=_load_average(), reference_ratio=round(fps / REFERENCE_FPS, 1))


def bench_accuracy(frames: int, folder: Path, seed: int = 1) -> None:
    from carapost.api import evaluate
    from carapost.pipeline import process_take
    from carapost.synth import SynthConfig, generate_take

    take = folder / (f"speech{frames}" if seed == 1 else f"speech{frames}s{seed}")
    if not (take / "truth.npz").is_file():
        generate_take(take, SynthConfig(preset="speech", frames=frames, seed=seed,
                                        take_name="speech"))
    out = take.with_suffix(".cara")
    t0 = time.perf_counter()
    info = process_take(take, output=out)
    seconds = time.perf_counter() - t0
    ev = evaluate(out, take / "truth.npz")
    common = {"preset": "speech", "seed": seed, "frames": frames,
              "pipeline_seconds": round(seconds, 1), "stage_seconds": info["seconds"],
              "initialised": info["initialised"]}
    emit("tracking_coverage", round(ev["coverage"], 4), "fraction", **common)
    emit("tracking_swaps", ev["swaps"], "count", seed=seed,
         spurious_points=ev["spurious_points"])
    emit("tracking_rmse_mm", None if ev["rmse_mm"] is None else round(ev["rmse_mm"], 3), "mm",
         seed=seed)


def bench_rom(folder: Path) -> None:
    """Initialize from ROM end to end on rendered takes.

    A rom take (rom preset, seed 5, 120 frames) is processed and its points are labelled
    from its truth (what the artist does once per actor); a speech take of the same
    actor and marker set (seed 1, 150 frames) is then processed with ``rom=``. Reported:
    of the markers seen by >= 2 cameras at frame 0, the fraction with a point carrying
    their label within 2 mm (``rom_recovered``), labelled points further than 2 mm from
    their marker (``rom_mismatches``), and the tracked take's coverage and swaps.
    """
    from carapost.api import evaluate, open_project, save_project
    from carapost.model.project import KIND_FACE
    from carapost.pipeline import process_take
    from carapost.synth import SynthConfig, generate_take
    from carapost.synth.scoring import score_tracks

    rom = folder / "rom120"
    take = folder / "speech150"
    for path, cfg in ((rom, SynthConfig(preset="rom", frames=120, seed=5, take_name="rom")),
                      (take, SynthConfig(preset="speech", frames=150, seed=1,
                                         take_name="speech"))):
        if not (path / "truth.npz").is_file():
            generate_take(path, cfg)
    rom_cara = folder / "rom120.cara"
    process_take(rom, output=rom_cara)
    project = open_project(rom_cara)
    truth = np.load(rom / "truth.npz")
    face = np.flatnonzero(project.points.kind == KIND_FACE)
    match = score_tracks(project.points.positions[:, face].astype(np.float64),
                         truth["points3d"], truth["visible"].astype(bool)).match
    for col, m in zip(face, match, strict=True):
        if m >= 0:
            project.points.labels[col] = str(truth["labels"][m])
    save_project(project, rom_cara)
    out = folder / "speech150_from_rom.cara"
    t0 = time.perf_counter()
    info = process_take(take, output=out, rom=rom_cara)
    seconds = time.perf_counter() - t0
    result = open_project(out)
    truth = np.load(take / "truth.npz")
    labels = [str(x) for x in truth["labels"]]
    seen = truth["visible"][0].sum(-1) >= 2
    right, wrong = set(), 0
    for col in np.flatnonzero(result.points.kind == KIND_FACE):
        lab, X = result.points.labels[col], result.points.positions[0, col]
        if lab in labels and np.isfinite(X).all():
            m = labels.index(lab)
            if np.linalg.norm(X - truth["points3d"][0, m]) <= 2.0:
                right.add(m)
            else:
                wrong += 1
    ev = evaluate(out, take / "truth.npz")
    common = {"rom": "rom preset seed 5, 120 frames", "take": "speech seed 1, 150 frames",
              "rom_labelled": int((match >= 0).sum()), "pipeline_seconds": round(seconds, 1),
              "initialised": info["initialised"]}
    emit("rom_recovered", round(len(right & set(np.flatnonzero(seen))) / int(seen.sum()), 4),
         "fraction", **common)
    emit("rom_mismatches", wrong, "count")
    emit("rom_track_coverage", round(ev["coverage"], 4), "fraction")
    emit("rom_track_swaps", ev["swaps"], "count", spurious_points=ev["spurious_points"])


def bench_variety(frames: int, folder: Path, which: str = "heldout") -> None:
    """Render, process and score the takes of another renderer (see the module doc)."""
    from carapost.api import open_project
    from carapost.model.project import KIND_FACE
    from carapost.pipeline import process_take
    from carapost.synth import generate_take
    from carapost.synth.scoring import GROUPS, group_quality
    from carapost.synth.variety import (
        HELD_OUT_VARIANTS,
        HELD_OUT_VARIANTS_2,
        HELD_OUT_VARIANTS_3,
        HELD_OUT_VARIANTS_4,
        HELD_OUT_VARIANTS_5,
        HELD_OUT_VARIANTS_6,
        HELD_OUT_VARIANTS_7,
        TUNING_VARIANTS,
        other_rig_config,
    )

    indices = {"heldout": HELD_OUT_VARIANTS, "heldout2": HELD_OUT_VARIANTS_2,
               "heldout3": HELD_OUT_VARIANTS_3, "heldout4": HELD_OUT_VARIANTS_4,
               "heldout5": HELD_OUT_VARIANTS_5, "heldout6": HELD_OUT_VARIANTS_6,
               "heldout7": HELD_OUT_VARIANTS_7,
               "tuning": TUNING_VARIANTS}[which]
    pooled: dict[str, list] = {g: [] for g in GROUPS}
    by_cams: dict[int, list] = {}
    totals = {"swaps": 0, "spurious": 0}
    for index in indices:
        cfg = other_rig_config(index, frames=frames, take_name="take")
        take = folder / f"variety{index}_{frames}"
        if not (take / "truth.npz").is_file():
            generate_take(take, cfg)
        out = take.with_suffix(".cara")
        t0 = time.perf_counter()
        info = process_take(take, output=out)
        seconds = time.perf_counter() - t0
        project = open_project(out)
        truth = np.load(take / "truth.npz")
        face = project.points.kind == KIND_FACE
        pos = project.points.positions[:, face]
        sig = project.points.arrays["sigma"][:, face]
        C = project.n_cameras
        caddies = [list(range((C + 1) // 2)), list(range((C + 1) // 2, C))]
        q = group_quality(truth["points3d"], truth["visible"], pos, caddies, sig)
        common = {"set": which, "take": index, "preset": cfg.preset, "frames": frames,
                  "markers": cfg.poisson_markers, "size": list(cfg.size),
                  "pipeline_seconds": round(seconds, 1), "stage_seconds": info["seconds"]}
        _emit_groups(q, common)
        totals["swaps"] += int(q["all"]["swaps"])
        totals["spurious"] += int(q["all"]["spurious"])
        # pooled over takes: keep each take's errors and sigmas by group
        errs = _group_errors(truth["points3d"], truth["visible"], pos, sig, caddies)
        for g in GROUPS:
            pooled[g].append(errs[g])
        n_obs = np.isfinite(project.points.obs[:, face][..., 0]).sum(-1)
        for n, (e, sg) in _camera_count_errors(truth["points3d"], truth["visible"], pos, sig,
                                               n_obs).items():
            by_cams.setdefault(n, []).append((e, sg))
            _emit_calibration(e, sg, {**common, "group": f"cameras_{n}"})
    pooled_q = {}
    for g in GROUPS:
        e = np.concatenate([x[0] for x in pooled[g]]) if pooled[g] else np.zeros(0)
        sg = np.concatenate([x[1] for x in pooled[g]]) if pooled[g] else np.zeros(0)
        cov = [x[2] for x in pooled[g] if x[2] is not None]
        ok = np.isfinite(sg) & (sg > 0)
        pooled_q[g] = {
            "samples": int(e.size),
            "rmse_mm": float(np.sqrt(np.mean(e ** 2))) if e.size else None,
            "p99_mm": float(np.percentile(e, 99)) if e.size else None,
            "max_mm": float(e.max()) if e.size else None,
            "over_0_5mm": float(np.mean(e > 0.5)) if e.size else None,
            "coverage": float(np.mean(cov)) if cov else None,
            "within_1sigma": float(np.mean(e[ok] <= sg[ok])) if ok.any() else None,
            "within_2sigma": float(np.mean(e[ok] <= 2 * sg[ok])) if ok.any() else None,
        }
    pooled_q["all"].update(totals)
    _emit_groups(pooled_q, {"set": which, "take": "pooled", "frames": frames,
                            "takes": list(indices), "load_average": _load_average()})
    for n in sorted(by_cams):
        _emit_calibration(np.concatenate([x[0] for x in by_cams[n]]),
                          np.concatenate([x[1] for x in by_cams[n]]),
                          {"set": which, "take": "pooled", "frames": frames,
                           "group": f"cameras_{n}"})


def _camera_count_errors(truth, visible, pos, sig, n_obs):
    """Errors and sigmas of the matched samples with a sigma, by the number of cameras
    that observed the sample (2, 3, 4): the calibration per observation geometry."""
    from carapost.synth.scoring import score_tracks

    Y = np.asarray(pos, dtype=np.float64)
    present = np.isfinite(Y[..., 0]).any(0)
    Y, sg_p, n_p = Y[:, present], np.asarray(sig, np.float64)[:, present], n_obs[:, present]
    s = score_tracks(Y, truth, np.asarray(visible).astype(bool))
    out = {}
    for i in np.flatnonzero(s.match >= 0):
        e = np.linalg.norm(Y[:, i] - truth[:, s.match[i]], axis=-1)
        ok = np.isfinite(e) & np.isfinite(sg_p[:, i]) & (sg_p[:, i] > 0)
        for n in np.unique(n_p[ok, i]):
            m = ok & (n_p[:, i] == n)
            a = out.setdefault(int(n), ([], []))
            a[0].append(e[m])
            a[1].append(sg_p[m, i])
    return {n: (np.concatenate(a[0]), np.concatenate(a[1])) for n, a in out.items()}


def _emit_calibration(e, sg, extra: dict) -> None:
    """uncertainty_within_1sigma / 2sigma of one group of samples."""
    if e.size == 0:
        return
    extra = {**extra, "samples": int(e.size)}
    emit("uncertainty_within_1sigma", round(float(np.mean(e <= sg)), 4), "fraction", **extra)
    emit("uncertainty_within_2sigma", round(float(np.mean(e <= 2 * sg)), 4), "fraction",
         **extra)


def _group_errors(truth, visible, pos, sig, caddies):
    """Per group: (errors, sigmas, coverage) of the matched samples (for pooling)."""
    from carapost.synth.scoring import GROUPS, score_tracks

    Y = np.asarray(pos, dtype=np.float64)
    present = np.isfinite(Y[..., 0]).any(0)
    Y, sg_p = Y[:, present], np.asarray(sig, dtype=np.float64)[:, present]
    vis = np.asarray(visible).astype(bool)
    s = score_tracks(Y, truth, vis)
    F, M = truth.shape[:2]
    err = np.full((F, M), np.nan)
    sg = np.full((F, M), np.nan)
    for i in np.flatnonzero(s.match >= 0):
        err[:, s.match[i]] = np.linalg.norm(Y[:, i] - truth[:, s.match[i]], axis=-1)
        sg[:, s.match[i]] = sg_p[:, i]
    n_cad = np.stack([vis[..., cams].any(-1) for cams in caddies], axis=-1).sum(-1)
    seen = vis.sum(-1) >= 2
    masks = {"all": np.isfinite(truth[..., 0]), "one_caddy": seen & (n_cad == 1),
             "two_caddies": seen & (n_cad >= 2)}
    out = {}
    for g in GROUPS:
        m = masks[g] & np.isfinite(err)
        grp_seen = seen & masks[g]
        hit = np.nan_to_num(err, nan=np.inf) <= 2.0
        out[g] = (err[m], sg[m], float(hit[grp_seen].mean()) if grp_seen.any() else None)
    return out


def _emit_groups(q: dict, common: dict) -> None:
    def r(v, n=4):
        return None if v is None else round(float(v), n)

    for g, row in q.items():
        extra = {**common, "group": g, "samples": row["samples"]}
        emit("variety_rmse_mm", r(row["rmse_mm"]), "mm", **extra)
        emit("variety_p99_mm", r(row["p99_mm"]), "mm", **extra)
        emit("variety_max_mm", r(row["max_mm"]), "mm", **extra)
        emit("variety_over_0_5mm", r(row["over_0_5mm"]), "fraction", **extra)
        emit("variety_coverage", r(row["coverage"]), "fraction", **extra)
        emit("uncertainty_within_1sigma", r(row["within_1sigma"]), "fraction", **extra)
        emit("uncertainty_within_2sigma", r(row["within_2sigma"]), "fraction", **extra)
        if g == "all":
            emit("variety_swaps", row["swaps"], "count", **extra)
            emit("variety_spurious", row["spurious"], "count", **extra)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--accuracy-frames", type=int, default=300,
                    help="frames of the rendered take (600 for the full acceptance run)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--accuracy-seeds", default="1",
                    help="comma-separated seeds of the rendered speech takes (default 1)")
    ap.add_argument("--rom", action="store_true",
                    help="also Initialize from ROM end to end on rendered takes")
    ap.add_argument("--takes", default="",
                    help="comma-separated track_take cases: speech,fast,blink,dense156,"
                         "sparse35,back (truth-derived detections, --frames frames)")
    ap.add_argument("--variety", action="store_true",
                    help="render, process and score takes of another renderer")
    ap.add_argument("--variety-set",
                    choices=("heldout", "heldout2", "heldout3", "heldout4", "heldout5",
                             "heldout6", "heldout7", "tuning"),
                    default="heldout")
    ap.add_argument("--variety-frames", type=int, default=120)
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) /
                    "carapost-bench-tracking")
    args = ap.parse_args(argv)
    if not args.skip_speed:
        bench_speed(args.frames, args.runs)
    if args.takes:
        bench_takes(args.frames, [c.strip() for c in args.takes.split(",") if c.strip()])
    if not args.skip_accuracy:
        args.cache.mkdir(parents=True, exist_ok=True)
        for seed in (int(x) for x in args.accuracy_seeds.split(",") if x.strip()):
            bench_accuracy(args.accuracy_frames, args.cache, seed)
    if args.variety:
        args.cache.mkdir(parents=True, exist_ok=True)
        bench_variety(args.variety_frames, args.cache, args.variety_set)
    if args.rom:
        args.cache.mkdir(parents=True, exist_ok=True)
        bench_rom(args.cache)
    return 0


if __name__ == "__main__":
    sys.exit(main())
