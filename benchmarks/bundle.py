"""Benchmark: bundle adjustment (BAL Ladybug 49-7776, per-frame bundle, real 12-camera tracks).

1. BAL problem 49-7776 (31,843 observations) and its 1,800-point subset: our solver
   (analytic Jacobian, Levenberg-Marquardt with the points eliminated by the Schur
   complement) against scipy's plain ``least_squares`` with a finite-difference Jacobian
   and ``jac_sparsity`` (TRF, LSMR, x_scale="jac", ftol=1e-4, as in the scipy cookbook),
   on the same problem in the same run. Also ``least_squares`` with our analytic sparse
   Jacobian, to show where the time goes.
2. Bundle Current Frame on a synthetic head rig: 4 cameras x 120 points, brim fixed.
3. Real 12-camera tracks (aniposelib mouse-outdoor test data): median reprojection error
   of plain and outlier-rejection triangulation before and after bundle adjustment.

BLAS is limited to one thread (set before numpy loads) so that both solvers are timed the
same way on a shared 2-core machine. Prints one JSON object per line.
Run from the repository root: ``python benchmarks/bundle.py [--runs N] [--skip-fd-full]``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import statistics
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from bal import bundle_adjust_bal, read_bal  # benchmarks/bal.py
from carapost.algorithms.bundle import bundle_frame
from carapost.algorithms.camera import (
    CameraIntrinsics,
    project,
    rodrigues_to_matrix,
)
from carapost.algorithms.triangulation import (
    TriangulationParameters,
    triangulate,
)

REPO = Path(__file__).resolve().parents[1]
FIXTURES = Path(os.environ.get("CARAPOST_FIXTURES", REPO.parent / "shared" / "fixtures"))


def _emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(float(value), 5), "unit": unit,
                      **extra}), flush=True)


def bench_bal(runs: int, skip_fd_full: bool) -> None:
    for name, fname in (("bal49", "problem-49-7776-pre.txt"),
                        ("bal49_1800", "bal-ladybug-problem-49-7776-pre-shrink-1800.txt")):
        path = FIXTURES / "bal" / fname
        if not path.exists():
            print(f"# {path} not found, skipped", file=sys.stderr)
            continue
        prob = read_bal(path)
        ours = [bundle_adjust_bal(prob) for _ in range(runs)]
        t_ours = statistics.median(r.seconds for r in ours)
        o = ours[0]
        ls = bundle_adjust_bal(prob, solver="least_squares")
        fd = None if (skip_fd_full and name == "bal49") else bundle_adjust_bal(
            prob, solver="least_squares", jacobian="fd")
        common = {"observations": int(prob.observations.shape[0])}
        _emit(f"{name}_time_s", t_ours, "s", runs=runs, iterations=o.njev - 1,
              cost_initial=round(o.cost_initial, 3), cost_final=round(o.cost_final, 3),
              rms_final_px=round(o.rms_final, 5), **common)
        _emit(f"{name}_least_squares_analytic_time_s", ls.seconds, "s",
              cost_final=round(ls.cost_final, 3), rms_final_px=round(ls.rms_final, 5),
              nfev=ls.nfev)
        if fd is not None:
            _emit(f"{name}_scipy_fd_time_s", fd.seconds, "s", cost_final=round(fd.cost_final, 3),
                  rms_final_px=round(fd.rms_final, 5), nfev=fd.nfev)
            _emit(f"{name}_speedup_vs_scipy_fd", fd.seconds / t_ours, "x")
            _emit(f"{name}_final_cost_ratio", o.cost_final / fd.cost_final, "ratio")


def _head_rig() -> tuple[np.ndarray, np.ndarray, CameraIntrinsics]:
    sys.path.insert(0, str(REPO / "benchmarks"))
    from triangulation import head_rig  # the same synthetic rig as the triangulation bench

    return head_rig()


def bench_frame(runs: int) -> None:
    rng = np.random.default_rng(7)
    R, t, intr = _head_rig()
    times = []
    rms = []
    for _ in range(max(runs, 1) * 7):
        P = 120
        x = rng.uniform(-70, 70, P)
        y = rng.uniform(-90, 90, P)
        X = np.stack([x, y, 40 * (1 - (x / 80) ** 2 - (y / 100) ** 2)], -1)
        uv, _ = project(X, R, t, intr)
        uv += rng.normal(0, 0.1, uv.shape)
        brim = np.arange(P) < 20
        Rp = rodrigues_to_matrix(rng.normal(0, 0.005, (4, 3))) @ R
        tp = t + rng.normal(0, 1.0, t.shape)
        Xp = X + rng.normal(0, 0.5, X.shape)
        Xp[brim] = X[brim]
        t0 = time.perf_counter()
        res = bundle_frame(uv, Xp, Rp, tp, intr, fixed_points_mask=brim)
        times.append(time.perf_counter() - t0)
        rms.append(res.rms_after)
    _emit("frame_bundle_ms", statistics.median(times) * 1e3, "ms", cameras=4, points=120,
          frames=len(times), median_rms_after_px=round(float(np.median(rms)), 4))


def _load_multiview() -> tuple[np.ndarray, np.ndarray, np.ndarray, CameraIntrinsics] | None:
    import cv2

    d = FIXTURES / "multiview"
    cal = d / "aniposelib_mouse-outdoor_calibration_right_4_10_2026_adjusted.toml"
    pts = d / "aniposelib_mouse-outdoor_points_right_4_10_2026_sub.npz"
    if not (cal.exists() and pts.exists()):
        return None
    toml = tomllib.loads(cal.read_text())
    cams = [toml[k] for k in sorted((k for k in toml if k.startswith("cam_")),
                                    key=lambda k: int(k[4:]))]
    p2d = np.load(pts)["p2d"]  # [C, N, 2] raw OpenCV pixels
    C = len(cams)
    K = np.array([c["matrix"] for c in cams], float)
    # OpenCV's k1 k2 p1 p2 k3 model is not a Vicon radial model: undistort to ideal pinhole
    # pixels here and use our model with zero radial terms.
    ideal = np.full_like(p2d, np.nan)
    for c in range(C):
        ok = np.isfinite(p2d[c]).all(-1)
        und = cv2.undistortPoints(p2d[c, ok].reshape(-1, 1, 2), K[c],
                                  np.array(cams[c]["distortions"], float), P=K[c])
        ideal[c, ok] = und.reshape(-1, 2)
    R = rodrigues_to_matrix(np.array([c["rotation"] for c in cams], float))
    t = np.array([c["translation"] for c in cams], float) * 1000.0  # m -> mm
    intr = CameraIntrinsics(focal=K[:, 0, 0], principal_point=K[:, :2, 2],
                            aspect=K[:, 0, 0] / K[:, 1, 1],
                            image_size=[c["size"] for c in cams],
                            names=[str(c["name"]) for c in cams])
    return np.moveaxis(ideal, 0, 1), R, t, intr  # observations [N, C, 2]


def bench_multiview() -> None:
    data = _load_multiview()
    if data is None:
        print("# multiview fixture not found, skipped", file=sys.stderr)
        return
    obs, R, t, intr = data
    n_views = np.isfinite(obs).all(-1).sum(-1)
    obs = obs[n_views >= 3]
    plain = TriangulationParameters()
    robust = TriangulationParameters(use_outlier_rejection=True)

    def medians(R_: np.ndarray, t_: np.ndarray, tag: str) -> dict[str, object]:
        out = {}
        for label, params in (("plain", plain), ("outlier_rejection", robust)):
            t0 = time.perf_counter()
            res = triangulate(obs[None], R_, t_, intr, params)
            dt = time.perf_counter() - t0
            e = res.reprojection_error[0]
            _emit(f"multiview_{label}_median_px_{tag}", float(np.nanmedian(e)), "px",
                  p90_px=round(float(np.nanpercentile(e, 90)), 3), points=int(obs.shape[0]),
                  triangulated=int(np.isfinite(e).sum()), seconds=round(dt, 3))
            out[label] = res
        return out

    before = medians(R, t, "before_bundle")
    # Bundle the cameras on a sample of points from the outlier-rejection triangulation,
    # with a robust loss against mismatched tracks; gauge held by camera 0 and the scale.
    rng = np.random.default_rng(3)
    pts = before["outlier_rejection"].points[0]
    ok = np.flatnonzero(np.isfinite(pts).all(-1))
    sample = rng.choice(ok, size=min(5000, ok.size), replace=False)
    t0 = time.perf_counter()
    ba = bundle_frame(obs[sample], pts[sample], R, t, intr, loss="huber", f_scale=3.0,
                      max_nfev=100)
    _emit("multiview_bundle_time_s", time.perf_counter() - t0, "s", points=int(sample.size),
          cameras=int(R.shape[0]), rms_before_px=round(ba.rms_before, 3),
          rms_after_px=round(ba.rms_after, 3), message=ba.message)
    medians(ba.R, ba.t, "after_bundle")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-fd-full", action="store_true",
                    help="skip the slow finite-difference reference on the full BAL problem")
    ap.add_argument("--only", choices=["bal", "frame", "multiview"], default=None)
    args = ap.parse_args()
    if args.only in (None, "frame"):
        bench_frame(args.runs)
    if args.only in (None, "multiview"):
        bench_multiview()
    if args.only in (None, "bal"):
        bench_bal(args.runs, args.skip_fd_full)


if __name__ == "__main__":
    main()
